"""The reference map's misregistration: a seeded global shift plus a smooth warp, and remapping.

A real reference orthophoto is georeferenced to within a metre or two, with a smooth residual
(orthorectification with an imperfect terrain model, ground control errors). :func:`draw_misregistration`
draws a shift of ``misregistration_shift_m`` x U(0.7, 1) in a random direction and three plane-wave
terms (``WarpTerm``, wavelengths 100-1000 m, random directions) whose amplitudes add up to
``misregistration_warp_m``; :func:`misregister` remaps an image so that the ground point at world
(x, y) appears at (x, y) + offset_m(x, y) (the convention of ``ReferenceInfo``), in row strips.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from scenenav.core.formats.world_manifest import ReferenceInfo, WarpTerm
from worlds.city_config import CityConfig

WARP_TERMS = 3
WARP_WAVELENGTH_M = (100.0, 1000.0)
_STRIP_ROWS = 512
_FIXED_POINT_ITERATIONS = 4   # the warp's slope is < 0.2, so 4 iterations converge to < 1 mm


def draw_misregistration(cfg: CityConfig, rng: np.random.Generator
                         ) -> tuple[float, float, tuple[WarpTerm, ...]]:
    """(shift east m, shift north m, warp terms) for a city of ``cfg``."""
    mag = cfg.misregistration_shift_m * rng.uniform(0.7, 1.0)
    ang = rng.uniform(0.0, 2.0 * math.pi)
    split = rng.dirichlet(np.ones(WARP_TERMS)) * cfg.misregistration_warp_m
    terms = []
    for amp in split:
        lam = math.exp(rng.uniform(math.log(WARP_WAVELENGTH_M[0]), math.log(WARP_WAVELENGTH_M[1])))
        k_dir = rng.uniform(0.0, 2.0 * math.pi)
        a_dir = rng.uniform(0.0, 2.0 * math.pi)
        terms.append(WarpTerm(amp_east_m=float(amp * math.cos(a_dir)), amp_north_m=float(amp * math.sin(a_dir)),
                              k_east_per_m=float(math.cos(k_dir) / lam), k_north_per_m=float(math.sin(k_dir) / lam),
                              phase_rad=float(rng.uniform(0.0, 2.0 * math.pi))))
    return float(mag * math.cos(ang)), float(mag * math.sin(ang)), tuple(terms)


def max_offset_m(info: ReferenceInfo) -> float:
    """An upper bound of |offset_m| over the plane."""
    return math.hypot(info.shift_east_m, info.shift_north_m) + sum(
        math.hypot(t.amp_east_m, t.amp_north_m) for t in info.warp)


def misregister(img: np.ndarray, info: ReferenceInfo, m_per_px: float) -> np.ndarray:
    """``img`` (H, W[, C]) as drawn with the misregistration of ``info`` (bicubic, edges mirrored)."""
    H, W = img.shape[:2]
    if max_offset_m(info) == 0.0:
        return img.copy()
    pad = int(math.ceil(max_offset_m(info) / m_per_px)) + 4
    out = np.empty_like(img)
    cols = np.arange(W, dtype=np.float64) + 0.5
    for r0 in range(0, H, _STRIP_ROWS):
        r1 = min(H, r0 + _STRIP_ROWS)
        uu, vv = np.meshgrid(cols, np.arange(r0, r1, dtype=np.float64) + 0.5)
        xt = (uu - W / 2.0) * m_per_px
        yt = (H / 2.0 - vv) * m_per_px
        x, y = xt.copy(), yt.copy()
        for _ in range(_FIXED_POINT_ITERATIONS):    # solve (x, y) + offset(x, y) = (xt, yt)
            dx, dy = info.offset_m(x, y)
            x, y = xt - dx, yt - dy
        s0, s1 = max(0, r0 - pad), min(H, r1 + pad)
        map_u = (x / m_per_px + W / 2.0 - 0.5).astype(np.float32)
        map_v = (H / 2.0 - y / m_per_px - 0.5 - s0).astype(np.float32)
        out[r0:r1] = cv2.remap(np.ascontiguousarray(img[s0:s1]), map_u, map_v, cv2.INTER_CUBIC,
                               borderMode=cv2.BORDER_REFLECT)
    return out
