"""The reference map the way the seed paper's was taken: one perspective image from high above.

Section 6.1 of the seed paper: the reference "was taken from a height of 500 m in the environment".
:func:`perspective_reference` resamples such an image to the map grid: for each map pixel's ground
point, the colour of the first surface the ray from the eye (``height_m`` above the map centre) to
that point meets (``worlds/raycast.py``). Roofs therefore lean away from the map centre by
``h * d / height_m`` (d: the distance of the pixel where the roof appears from the centre), walls
facing the centre appear, and streets behind tall buildings are hidden. Tops and ground take the
day's true orthophoto, walls its facade colours (with their window pattern and per-face light).
Rays are cast in row strips, so memory stays bounded.

The DSM is a grid of flat-topped columns, so a sloped surface (a pitched roof, a tree crown) is a
staircase whose risers a slanted ray can hit. A "wall" lower than a ``MAX_SURFACE_SLOPE_DEG`` slope
over one pixel is such a riser, not a facade: it takes the colour of the surface it belongs to.
The sides of tree crowns (``canopy`` pixels) are foliage, not walls with windows: they take the
crown's own colour in the shade (``CANOPY_SIDE_FACTOR``).
"""

from __future__ import annotations

import math

import numpy as np

from worlds.raycast import HeightField, RayHits, Surface, first_hits, shade

_STRIP_ROWS = 128
#: Steps of the DSM steeper than this over one pixel are walls; gentler ones are sloped surfaces
#: (roofs are pitched at most 45 degrees, see worlds/surface.py ROOF_PITCH_DEG).
MAX_SURFACE_SLOPE_DEG = 60.0

#: Brightness of the side of a tree crown relative to its top (the lit top vs the crown's flank,
#: about the light of a vertical face against a horizontal one under a 45-60 degree sun).
CANOPY_SIDE_FACTOR = 0.7

# neighbour (d_col, d_row) across each wall face (WallFace values 0..4: none, E, W, N, S)
_FACE_DC = np.array([0, 1, -1, 0, 0])
_FACE_DR = np.array([0, 0, 0, -1, 1])


def _risers(hits: RayHits, dsm_m: np.ndarray, m_per_px: float) -> np.ndarray:
    """Mask of the wall hits that are risers of a sloped surface (see the module docstring)."""
    H, W = dsm_m.shape
    wall = hits.surface == Surface.WALL
    col, row = hits.col_px, hits.row_px
    face = hits.wall_face.astype(np.int64)
    nc, nr = col + _FACE_DC[face], row + _FACE_DR[face]
    inside = wall & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    n_in = inside & (nc >= 0) & (nc < W) & (nr >= 0) & (nr < H)
    out = np.zeros(len(hits), dtype=bool)
    here = dsm_m[row[n_in], col[n_in]]
    there = dsm_m[nr[n_in], nc[n_in]]
    out[n_in] = (here - there) <= m_per_px * math.tan(math.radians(MAX_SURFACE_SLOPE_DEG))
    return out


def perspective_reference(top_rgb: np.ndarray, dsm_m: np.ndarray, facade_rgb: np.ndarray | None,
                          m_per_px: float, height_m: float, canopy: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8: the scene seen from ``height_m`` above the map centre, on the map grid.

    ``canopy``: optional (H, W) bool, the tree-crown pixels (their sides are foliage).
    """
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
        rgb = shade(hits, top_rgb, facade_rgb, m_per_px=m_per_px)
        riser = _risers(hits, field.heights_m, m_per_px)
        rgb[riser] = top_rgb[hits.row_px[riser], hits.col_px[riser]]
        if canopy is not None:
            wall = (hits.surface == Surface.WALL) & ~riser
            side = np.zeros_like(wall)
            side[wall] = canopy[hits.row_px[wall], hits.col_px[wall]]
            rgb[side] = (top_rgb[hits.row_px[side], hits.col_px[side]] * CANOPY_SIDE_FACTOR + 0.5).astype(np.uint8)
        out[r0:r1] = rgb.reshape(r1 - r0, W, 3)
    return out
