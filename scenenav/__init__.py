"""scenenav: the two layers, ``scenenav.core`` (bottom) and ``scenenav.app`` (top); see docs/architecture.md."""
