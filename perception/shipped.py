"""Where the shipped CNN weights lie, without importing torch: the launcher, the preflight checks
and the assistant-map cache name the default weights file from here (``perception.cnn`` loads it)."""

from __future__ import annotations

from pathlib import Path

#: The folder of the weights shipped with the package.
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
#: The CNN weights a run uses when ``perception.weights`` names none.
DEFAULT_WEIGHTS_PATH = WEIGHTS_DIR / "default.pt"
