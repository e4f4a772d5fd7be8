"""Test helpers shared by several test kinds (imported as ``support.<module>``)."""

from pathlib import Path

#: The checkout's root folder (scenarios/, docs/ ...).
REPO_ROOT = Path(__file__).resolve().parents[2]
