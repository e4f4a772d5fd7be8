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


# --------------------------------------------------------------------------- pinhole and lens model
# Pixel coordinates here are continuous (``scenenav/core/frames.py``): pixel (c, r) covers
# [c, c+1) x [r, r+1), so the image centre, the principal point of every scenenav camera, is
# (W/2, H/2). Normalised image coordinates are x = (u - cx) / f (right), y = (v - cy) / f (down).

#: Brown-Conrady coefficients (k1, k2, p1, p2), OpenCV's order and meaning (``cv2.undistort``).
Distortion = tuple[float, float, float, float]
NO_DISTORTION: Distortion = (0.0, 0.0, 0.0, 0.0)

#: Fixed-point iterations of ``undistort_normalized`` (OpenCV's ``cv::undistortPoints`` uses 5 by
#: default; 8 reach 1e-6 px over the whole image for |k1| <= 0.3 at a 60 degree field of view).
UNDISTORT_ITERATIONS = 8


def intrinsics_px(width_px: int, height_px: int, fov_deg: float) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in pixels of a scenenav camera: square pixels, ``fov_deg`` across the width,
    principal point at the image centre (continuous pixel coordinates)."""
    f = focal_length_px(width_px, fov_deg)
    return f, f, 0.5 * width_px, 0.5 * height_px


def distort_normalized(x, y, k: Distortion):
    """Brown-Conrady (radial k1, k2; tangential p1, p2) distortion of normalised coordinates ``x``,
    ``y`` (floats or numpy arrays) -> the distorted (x, y), in OpenCV's convention (Brown, "Decentering
    distortion of lenses", Photogrammetric Engineering 32(3), 1966; Conrady 1919)."""
    k1, k2, p1, p2 = k
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + k2 * r2)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def undistort_normalized(xd, yd, k: Distortion, iterations: int = UNDISTORT_ITERATIONS):
    """The inverse of ``distort_normalized`` by fixed-point iteration (what ``cv::undistortPoints``
    does): x <- (xd - tangential(x)) / radial(x), starting at x = xd."""
    k1, k2, p1, p2 = k
    x, y = xd, yd
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + k2 * r2)
        dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    return x, y


Vec3 = tuple[float, float, float]


def fixed_mount_axes(rows) -> tuple[Vec3, Vec3, Vec3]:
    """World directions (image right, image up, camera back = -optical axis) of a camera fixed to the
    body, from the rows of the body -> world rotation matrix: image right = body -y, image up = body
    +x, back = body +z (FLU body)."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
    return (-r01, -r11, -r21), (r00, r10, r20), (r02, r12, r22)
