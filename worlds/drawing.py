"""Drawing and polyline helpers in continuous pixel coordinates (see scenenav/core/frames.py).

OpenCV draws with ``SHIFT`` fractional bits; :func:`cv_points` converts continuous (u, v) points to
its fixed-point integer coordinates. The polyline helpers (arc length, normals, interpolation,
sub-polylines) and the smooth random blobs are shared by the features, the roads and the blocks.
"""

from __future__ import annotations

import cv2
import numpy as np

SHIFT = 4             # fractional bits of OpenCV drawing coordinates
SCALE = float(1 << SHIFT)


def cv_points(pts, dx: float = 0.0, dy: float = 0.0) -> np.ndarray:
    """Continuous (u, v) points -> int32 OpenCV points with SHIFT fractional bits.

    OpenCV puts integer coordinate (c, r) at the centre of pixel (c, r), which is continuous
    (c + 0.5, r + 0.5); ``dx, dy`` (integers) translate into a sub-image.
    """
    q = np.asarray(pts, dtype=np.float64) * SCALE
    q -= ((0.5 + dx) * SCALE, (0.5 + dy) * SCALE)
    return np.rint(q, out=q).astype(np.int32)


def fill_convex(img: np.ndarray, poly, value, dx: int = 0, dy: int = 0) -> None:
    cv2.fillConvexPoly(img, cv_points(poly, dx, dy), value, cv2.LINE_8, SHIFT)


def stroke(img: np.ndarray, polys, value, thickness: int, dx: int = 0, dy: int = 0) -> None:
    if not polys:
        return
    cv2.polylines(img, [cv_points(p, dx, dy) for p in polys], False, value, max(1, int(thickness)),
                  cv2.LINE_8, SHIFT)


def rect(centre, ax, bx, la: float, lb: float) -> np.ndarray:
    """Rectangle corners with corners[0] -> corners[1] along the longer side."""
    c = np.asarray(centre, dtype=float)
    ha = np.asarray(ax) * (la / 2.0)
    hb = np.asarray(bx) * (lb / 2.0)
    pts = np.array([c - ha - hb, c + ha - hb, c + ha + hb, c - ha + hb])
    if la < lb:
        pts = pts[[1, 2, 3, 0]]
    return pts


def arc_lengths(poly: np.ndarray) -> np.ndarray:
    seg = np.hypot(*np.diff(poly, axis=0).T)
    return np.concatenate([[0.0], np.cumsum(seg)])


def polyline_normals(poly: np.ndarray) -> np.ndarray:
    t = np.gradient(poly, axis=0)
    t /= np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-9)[:, None]
    return np.stack([-t[:, 1], t[:, 0]], axis=1)


def interp_polyline(poly: np.ndarray, arc: np.ndarray, s) -> np.ndarray:
    s = np.asarray(s, dtype=float)
    return np.stack([np.interp(s, arc, poly[:, 0]), np.interp(s, arc, poly[:, 1])], axis=-1)


def sub_polyline(poly: np.ndarray, arc: np.ndarray, s0: float, s1: float) -> np.ndarray:
    inner = (arc > s0) & (arc < s1)
    return np.concatenate([interp_polyline(poly, arc, [s0]), poly[inner], interp_polyline(poly, arc, [s1])])


def blob_radii(rng: np.random.Generator, n: int, roughness: float, floor: float) -> np.ndarray:
    """Relative radius r(theta) of a smooth random blob at n angles (mean 1)."""
    theta = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r = np.ones(n)
    for k in range(2, 7):
        r += rng.uniform(0.0, roughness / k) * np.cos(k * theta + rng.uniform(0.0, 2.0 * np.pi))
    return np.maximum(r, floor)


def blob_polygon(centre, radius_px: float, rel: np.ndarray, extra_px: float = 0.0) -> np.ndarray:
    theta = np.linspace(0.0, 2.0 * np.pi, rel.size, endpoint=False)
    r = radius_px * rel + extra_px
    return np.stack([centre[0] + r * np.cos(theta), centre[1] + r * np.sin(theta)], axis=1)


def fill_poly(img: np.ndarray, poly: np.ndarray, value) -> None:
    cv2.fillPoly(img, [cv_points(poly)], int(value), cv2.LINE_8, SHIFT)
