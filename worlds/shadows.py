"""Cast shadows from the surface model: which map pixels the day's sun does not reach.

:func:`cast_shadows` marches from every pixel centre towards the sun over the DSM (one pixel per
step, nearest pixel) and reports the opacity of the first occluder: a DSM cell higher than the ray
from the pixel to the sun. Buildings are opaque; tree crowns let light through by the day's
``tree_opacity`` (leaf-off trees in winter cast thin shadows). Pitched roofs shade their own far
facet when it is steeper than the sun is high; a pixel is never shadowed by its own height.
Both days use the same DSM with their own sun, so their shadows come from the same geometry.
The kernel is compiled by numba (``cache=True``), one core, and works on any row range, so the
rendering calls it strip by strip.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from worlds.materials import Material

#: A surface must rise this much (m) above the ray to cast a shadow (no self-shadowing of flat
#: roofs by the centimetre quantisation of the DSM).
SHADOW_EPS_M = 0.05


@numba.njit(cache=True)
def _cast(dsm, material, opacity_of, r0, r1, su, sv, rise_per_px, max_h, eps):  # pragma: no cover
    H, W = dsm.shape
    out = np.zeros((r1 - r0, W), dtype=np.float32)
    for row in range(r0, r1):
        v = row + 0.5
        for col in range(W):
            z0 = dsm[row, col] + eps
            if z0 >= max_h:
                continue
            n = int((max_h - z0) / rise_per_px) + 1
            u = col + 0.5
            best = 0.0
            for t in range(1, n + 1):
                qu = int(math.floor(u + t * su))
                qv = int(math.floor(v + t * sv))
                if qu < 0 or qu >= W or qv < 0 or qv >= H:
                    break
                if dsm[qv, qu] > z0 + t * rise_per_px:
                    o = opacity_of[material[qv, qu]]
                    if o > best:
                        best = o
                        if best >= 1.0:
                            break
            out[row - r0, col] = best
    return out


def cast_shadows(dsm_m: np.ndarray, material: np.ndarray, r0: int, r1: int, sun_uv: np.ndarray,
                 sun_elevation_deg: float, m_per_px: float, tree_opacity: float,
                 max_height_m: float | None = None) -> np.ndarray:
    """Shadow opacity (0 lit .. 1 full shadow), float32 rows [r0, r1) of the map.

    ``sun_uv``: unit horizontal vector towards the sun in image axes (u east, v south);
    ``max_height_m``: the DSM maximum (computed if not given; pass it when calling per strip).
    """
    if max_height_m is None:
        max_height_m = float(dsm_m.max()) if dsm_m.size else 0.0
    H, W = dsm_m.shape
    if max_height_m <= SHADOW_EPS_M or sun_elevation_deg >= 89.9:
        return np.zeros((r1 - r0, W), dtype=np.float32)
    opacity = np.ones(256, dtype=np.float32)
    opacity[int(Material.FOREST)] = float(tree_opacity)
    rise = m_per_px * math.tan(math.radians(sun_elevation_deg))
    return _cast(dsm_m, material, opacity, int(r0), int(r1), float(sun_uv[0]), float(sun_uv[1]),
                 rise, float(max_height_m), SHADOW_EPS_M)
