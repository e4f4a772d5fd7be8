"""Plane geometry shared by guidance, the autopilot bench and evaluation (pure numpy)."""

from __future__ import annotations

import numpy as np


def distance_to_polyline_m(points_xy, polyline_xy) -> np.ndarray:
    """Distance of each point (N, 2) to the polyline (M, 2), in the points' unit; a polyline of
    one point is that point. Returns (N,) (a single (2,) point gives shape (1,))."""
    p = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    line = np.asarray(polyline_xy, dtype=float).reshape(-1, 2)
    if len(line) == 1:
        return np.hypot(*(p - line[0]).T)
    a, b = line[:-1], line[1:]                                  # (S, 2) segments
    ab = b - a
    ap = p[:, None, :] - a[None, :, :]                          # (N, S, 2)
    t = np.clip(np.einsum("nsk,sk->ns", ap, ab) / np.maximum(np.einsum("sk,sk->s", ab, ab), 1e-12),
                0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.min(np.hypot(*(p[:, None, :] - closest).transpose(2, 0, 1)), axis=1)
