"""The reference map the way the seed paper's was taken: one perspective image from high above.

Section 6.1 of the seed paper: the reference "was taken from a height of 500 m in the environment".
:func:`perspective_reference` resamples such an image to the map grid: for each map pixel's ground
point, the colour of the first surface the ray from the eye (``height_m`` above the map centre) to
that point meets (``worlds/raycast.py``). Roofs therefore lean away from the map centre by
``h * d / height_m`` (d: the distance of the pixel where the roof appears from the centre), walls
facing the centre appear, and streets behind tall buildings are hidden. Tops and ground take the
day's true orthophoto, walls its facade colours (with their window pattern and per-face light).
Rays are cast in row strips, so memory stays bounded.
"""

from __future__ import annotations

import numpy as np

from worlds.raycast import HeightField, first_hits, shade

_STRIP_ROWS = 128


def perspective_reference(top_rgb: np.ndarray, dsm_m: np.ndarray, facade_rgb: np.ndarray | None,
                          m_per_px: float, height_m: float) -> np.ndarray:
    """(H, W, 3) uint8: the scene seen from ``height_m`` above the map centre, on the map grid."""
    H, W = dsm_m.shape
    field = HeightField(dsm_m, m_per_px)
    out = np.empty((H, W, 3), dtype=np.uint8)
    x = (np.arange(W, dtype=np.float64) + 0.5 - W / 2.0) * m_per_px
    for r0 in range(0, H, _STRIP_ROWS):
        r1 = min(H, r0 + _STRIP_ROWS)
        y = (H / 2.0 - (np.arange(r0, r1, dtype=np.float64) + 0.5)) * m_per_px
        xx, yy = np.meshgrid(x, y)
        n = xx.size
        origins = np.zeros((n, 3))
        origins[:, 2] = height_m
        dirs = np.stack([xx.ravel(), yy.ravel(), np.full(n, -float(height_m))], axis=1)
        hits = first_hits(field, origins, dirs)
        out[r0:r1] = shade(hits, top_rgb, facade_rgb, m_per_px=m_per_px).reshape(r1 - r0, W, 3)
    return out
