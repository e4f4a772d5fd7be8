"""Camera geometry shared by the simulator, perception, guidance and evaluation.

The camera is a pinhole with a square field of view ``fov_deg`` measured across the image width; seen
straight down from ``altitude_m`` above flat ground its footprint is a square of side
``2 h tan(fov / 2)``. This is the one place that formula is written.
"""

from __future__ import annotations

import math


def ground_footprint_m(altitude_m: float, fov_deg: float) -> float:
    """Side of the ground square seen straight down from ``altitude_m`` (m) with ``fov_deg``."""
    return 2.0 * altitude_m * math.tan(math.radians(fov_deg) / 2.0)


def focal_length_px(width_px: int, fov_deg: float) -> float:
    """Pinhole focal length in pixels for a horizontal field of view ``fov_deg`` over ``width_px``."""
    return 0.5 * width_px / math.tan(math.radians(fov_deg) / 2.0)
