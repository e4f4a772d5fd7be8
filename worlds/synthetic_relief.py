"""A synthetic city surface model for renderer tests and ``scenenav bench render``.

Not the world generator's DSM (``worlds/generator.py`` owns that): a seeded stand-in with the same
statistics the issue names, used where a test or benchmark needs relief on any map size. Buildings are
axis-aligned boxes on a jittered block grid covering about 35 % of the map, heights drawn from the
mix of issue 11 (houses 6-12 m, blocks 12-24 m, a few towers 24-40 m); trees are round domes
8-20 m high, 3-6 m in radius, on part of the free ground. Facade colours: one muted colour per
building, black elsewhere (``World.facade_rgb`` convention).
"""

from __future__ import annotations

import numpy as np

# Height mix (share, low m, high m): houses, blocks, towers (issue 11).
_HEIGHT_CLASSES = ((0.55, 6.0, 12.0), (0.38, 12.0, 24.0), (0.07, 24.0, 40.0))
_BUILT_SHARE = 0.35
_TREES_PER_HECTARE = 12.0


def synthetic_dsm(height_px: int, width_px: int, m_per_px: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(dsm_m float32 (H, W), facade_rgb uint8 (H, W, 3)) of a synthetic city (see the module docstring)."""
    rng = np.random.default_rng(seed)
    dsm = np.zeros((height_px, width_px), dtype=np.float32)
    facade = np.zeros((height_px, width_px, 3), dtype=np.uint8)
    cell_m = 40.0                         # block pitch (a building per cell, sized for the built share)
    cell = max(4, int(round(cell_m / m_per_px)))
    side_share = np.sqrt(_BUILT_SHARE)
    shares = np.array([c[0] for c in _HEIGHT_CLASSES])
    for r0 in range(0, height_px, cell):
        for c0 in range(0, width_px, cell):
            w = int(cell * side_share * rng.uniform(0.6, 1.35))
            h = int(cell * side_share * rng.uniform(0.6, 1.35))
            w, h = max(2, min(w, cell - 1)), max(2, min(h, cell - 1))
            dr = int(rng.integers(0, cell - h + 1))
            dc = int(rng.integers(0, cell - w + 1))
            k = int(rng.choice(3, p=shares))
            lo, hi = _HEIGHT_CLASSES[k][1:]
            height = np.float32(round(float(rng.uniform(lo, hi)), 2))
            rs, cs = slice(r0 + dr, min(r0 + dr + h, height_px)), slice(c0 + dc, min(c0 + dc + w, width_px))
            dsm[rs, cs] = height
            facade[rs, cs] = rng.integers(90, 220, 3).astype(np.uint8)
    # Trees: domes on free ground.
    area_ha = height_px * width_px * m_per_px * m_per_px / 1e4
    n_trees = int(area_ha * _TREES_PER_HECTARE)
    for _ in range(n_trees):
        cy, cx = rng.uniform(0, height_px), rng.uniform(0, width_px)
        radius_px = rng.uniform(3.0, 6.0) / m_per_px
        top = rng.uniform(8.0, 20.0)
        r0, r1 = int(max(0, cy - radius_px)), int(min(height_px, cy + radius_px + 1))
        c0, c1 = int(max(0, cx - radius_px)), int(min(width_px, cx + radius_px + 1))
        if r1 <= r0 or c1 <= c0:
            continue
        yy, xx = np.mgrid[r0:r1, c0:c1]
        d2 = ((yy + 0.5 - cy) ** 2 + (xx + 0.5 - cx) ** 2) / (radius_px * radius_px)
        crown = np.where(d2 < 1.0, top * np.sqrt(np.clip(1.0 - d2, 0.0, 1.0)) ** 0.5, 0.0).astype(np.float32)
        patch = dsm[r0:r1, c0:c1]
        free = patch == 0.0
        np.copyto(patch, np.maximum(patch, crown), where=free)
        facade[r0:r1, c0:c1][free & (crown > 0)] = (40, 70, 35)
    return dsm, facade
