"""Subcommands of ``scenenav`` for the domain packages (world, dataset/train/cnn, assistant-map, plan)."""
