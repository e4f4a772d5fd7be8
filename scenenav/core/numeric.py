"""Small numeric checks shared by every package."""

from __future__ import annotations

import math


def all_finite(*values: float) -> bool:
    """True when every value is a finite number (no NaN, no infinity)."""
    return all(math.isfinite(float(v)) for v in values)
