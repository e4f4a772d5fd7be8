"""Small numeric checks shared by every package."""

from __future__ import annotations

import math


def all_finite(*values: float) -> bool:
    """True when every value is a finite number (no NaN, no infinity)."""
    return all(math.isfinite(float(v)) for v in values)


def largest_sd_2x2(cov) -> float:
    """Square root of the larger eigenvalue of a symmetric 2x2 covariance (its widest 1-sigma, in
    the covariance's unit); NaN when an entry is not finite."""
    a, b, d = float(cov[0][0]), 0.5 * (float(cov[0][1]) + float(cov[1][0])), float(cov[1][1])
    if not all_finite(a, b, d):
        return math.nan
    lam = 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)
    return math.sqrt(max(lam, 0.0))
