"""The surface model of a generated city: a height (DSM) and a wall colour (facade) per map pixel.

Three steps, each from its own random stream (``worlds/scene.py`` calls the first two):

* :func:`finish_buildings`: promotes a few flat-roofed buildings to towers, gives pitched roofs a
  pitch (the ridge ``roof_rise_m`` above the eaves) and every building its wall colour;
* :func:`tree_crowns`: the crowns of the garden and park trees the layout drew (their circles) and
  of the forests (a jittered grid of crowns over every forest), each with a height of 8-20 m;
* :func:`surface_model`: rasterises both into ``dsm_m`` (metres above the ground at each pixel
  centre) and ``facade_rgb``, one building (its bounding box) or one crown at a time, so the only
  full-size arrays are the two outputs, even for 8000 x 8000 px maps.

Shapes: flat roofs at ``height_m`` with their roof boxes (HVAC) ``hvac_height_m`` above; gable roofs
with the ridge along the long side, hip roofs with four facets (as ``worlds/rendering.py`` shades
them); tree crowns are half-ellipsoid domes of the crown radius whose rim sits ``crown depth``
below the top. Heights are only written where the material raster shows the surface (roofs over
their footprints, crowns over FOREST pixels), so the DSM, the land cover and the orthophoto agree
pixel for pixel. The ground is at 0 (no terrain relief).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numba
import numpy as np

from worlds.blocks import HEIGHT_RANGE_M, TOWER_SHARE_LARGE, TOWER_SHARE_PERIMETER, Building, BuildingKind, RoofStyle
from worlds.city_config import CityConfig
from worlds.drawing import fill_convex
from worlds.features import Feature, FeatureKind
from worlds.materials import FACADE_PALETTE, TREE_FACADE_RGB, Material

if TYPE_CHECKING:
    from worlds.scene import Scene

#: Tree heights (m): 8-20 m covers the common Central-European city and forest trees (lime, maple,
#: beech, pine: 15-30 m when old, 8-15 m in streets and gardens; Roloff, Baumkronen, 2001).
TREE_HEIGHT_RANGE_M = (8.0, 20.0)
#: Crown depth: the dome's rim is this share of the tree's height below its top (at most
#: CROWN_DEPTH_PER_RADIUS crown radii), so a 15 m tree has its crown from ~6 m up.
CROWN_DEPTH_SHARE = 0.6
CROWN_DEPTH_PER_RADIUS = 1.6
#: Forest crowns: a jittered grid of this spacing, crown radii in this range (m).
FOREST_SPACING_M = 5.0
FOREST_CROWN_RADIUS_M = (2.6, 4.2)
#: FOREST pixels no crown covers (gaps inside a forest) show the understorey at this height.
UNDERSTOREY_M = 3.0
#: Roof pitch of gable and hip roofs (degrees; 30-45 is the common range of tiled roofs, DIN 18338).
ROOF_PITCH_DEG = (30.0, 45.0)
#: The ridge stays at most this share of the building height above the eaves.
MAX_RISE_SHARE = 0.45


#: Wall materials of each building kind and their shares.
FACADE_SHARES: dict[BuildingKind, tuple[tuple[str, ...], tuple[float, ...]]] = {
    BuildingKind.HOUSE: (("plaster", "brick"), (0.7, 0.3)),
    BuildingKind.OUTBUILDING: (("plaster", "brick", "concrete"), (0.4, 0.2, 0.4)),
    BuildingKind.PERIMETER: (("plaster", "brick", "concrete"), (0.75, 0.15, 0.1)),
    BuildingKind.TOWER: (("glass", "concrete"), (0.6, 0.4)),
    BuildingKind.LARGE: (("concrete", "glass", "plaster"), (0.5, 0.3, 0.2)),
    BuildingKind.BOX: (("metal", "concrete"), (0.7, 0.3)),
    BuildingKind.HALL: (("metal", "concrete"), (0.7, 0.3)),
}


def finish_buildings(buildings: list[Building], cfg: CityConfig, rng: np.random.Generator) -> None:
    """Towers, roof pitches and wall colours (in place), from the heights stream."""
    lo, hi = HEIGHT_RANGE_M[BuildingKind.TOWER]
    for b in buildings:
        r_tower, r_height, r_pitch, r_wall, r_tint = rng.random(5)
        if b.style is RoofStyle.FLAT and (
                (b.kind is BuildingKind.LARGE and r_tower < TOWER_SHARE_LARGE)
                or (b.kind is BuildingKind.PERIMETER and r_tower < TOWER_SHARE_PERIMETER)):
            b.kind = BuildingKind.TOWER
            b.height_m = float(lo + (hi - lo) * r_height)
        if b.style in (RoofStyle.GABLE, RoofStyle.HIP):
            half_b_m = 0.5 * float(np.hypot(*(b.corners[3] - b.corners[0]))) * cfg.m_per_px
            pitch = math.radians(ROOF_PITCH_DEG[0] + (ROOF_PITCH_DEG[1] - ROOF_PITCH_DEG[0]) * r_pitch)
            b.roof_rise_m = min(MAX_RISE_SHARE * b.height_m, math.tan(pitch) * half_b_m)
        names, shares = FACADE_SHARES[b.kind]
        cum = np.cumsum(shares) / sum(shares)
        wall = names[min(int(np.searchsorted(cum, r_wall, side="right")), len(names) - 1)]
        tones = FACADE_PALETTE[wall]
        base = np.array(tones[int(r_tint * len(tones)) % len(tones)], dtype=float)
        tint = np.clip(base * (0.92 + 0.16 * r_tint), 0, 255)
        b.facade = (float(tint[0]), float(tint[1]), float(tint[2]))


def tree_crowns(garden: list[tuple[float, float, float]], features: list[Feature], material: np.ndarray,
                cfg: CityConfig, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) float64 crowns: u, v, radius (px), height (m); garden and park trees, then forests."""
    mpp = cfg.m_per_px
    lo, hi = TREE_HEIGHT_RANGE_M
    rows = []
    if garden:
        g = np.array(garden, dtype=float)
        r_m = g[:, 2] * mpp
        # bigger crowns on taller trees, with scatter
        h = lo + (hi - lo) * np.clip((r_m - 1.5) / 3.5, 0.0, 1.0) * 0.8 + rng.normal(0.0, 1.8, len(g))
        rows.append(np.column_stack([g, np.clip(h, lo, hi)]))
    H, W = material.shape
    step = FOREST_SPACING_M / mpp
    for f in features:
        if f.kind is not FeatureKind.FOREST:
            continue
        reach = f.radius_px * 1.6
        u0, u1 = max(0.0, f.centre[0] - reach), min(float(W), f.centre[0] + reach)
        v0, v1 = max(0.0, f.centre[1] - reach), min(float(H), f.centre[1] + reach)
        uu, vv = np.meshgrid(np.arange(u0 + step / 2, u1, step), np.arange(v0 + step / 2, v1, step))
        u = uu.ravel() + rng.uniform(-0.3, 0.3, uu.size) * step
        v = vv.ravel() + rng.uniform(-0.3, 0.3, vv.size) * step
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        u, v = u[ok], v[ok]
        inside = material[v.astype(int), u.astype(int)] == Material.FOREST
        u, v = u[inside], v[inside]
        stand = rng.uniform(13.0, 18.0)                       # the stand's mean height
        r = rng.uniform(*FOREST_CROWN_RADIUS_M, len(u)) / mpp
        h = np.clip(stand + rng.normal(0.0, 1.8, len(u)), lo, hi)
        rows.append(np.column_stack([u, v, r, h]))
    if not rows:
        return np.zeros((0, 4))
    return np.concatenate(rows)


@numba.njit(cache=True)
def _splat_crowns(dsm, facade, crowns, rgb, mpp, depth_share, depth_per_radius):  # pragma: no cover
    H, W = dsm.shape
    for i in range(crowns.shape[0]):
        cu, cv, r, h = crowns[i, 0], crowns[i, 1], crowns[i, 2], crowns[i, 3]
        depth = min(depth_share * h, depth_per_radius * r * mpp)
        c0 = max(0, int(math.floor(cu - r)))
        c1 = min(W, int(math.ceil(cu + r)) + 1)
        r0 = max(0, int(math.floor(cv - r)))
        r1 = min(H, int(math.ceil(cv + r)) + 1)
        for row in range(r0, r1):
            dv = (row + 0.5 - cv) / r
            for col in range(c0, c1):
                du = (col + 0.5 - cu) / r
                q = 1.0 - du * du - dv * dv
                if q < 0.0:
                    continue
                z = h - depth + depth * math.sqrt(q)
                if z > dsm[row, col]:
                    dsm[row, col] = z
                    facade[row, col, 0] = rgb[0]
                    facade[row, col, 1] = rgb[1]
                    facade[row, col, 2] = rgb[2]


def _roof_heights(b: Building, us: np.ndarray, vs: np.ndarray, mpp: float) -> np.ndarray:
    """Roof height (m) of building ``b`` at the pixel centres (us, vs) inside its footprint."""
    if b.style not in (RoofStyle.GABLE, RoofStyle.HIP) or b.roof_rise_m <= 0.0:
        return np.full(us.shape, b.height_m, dtype=np.float64)
    p0, p1, _, p3 = b.corners
    a = p1 - p0
    la = float(np.hypot(*a))
    bb = p3 - p0
    lb = float(np.hypot(*bb))
    s = np.clip(((us - p0[0]) * a[0] + (vs - p0[1]) * a[1]) / max(la, 1e-9), 0.0, la)
    t = np.clip(((us - p0[0]) * bb[0] + (vs - p0[1]) * bb[1]) / max(lb, 1e-9), 0.0, lb)
    half_b = 0.5 * lb
    frac = np.minimum(t, lb - t) / max(half_b, 1e-9)
    if b.style is RoofStyle.HIP:
        inset = min(half_b, 0.45 * la)
        frac = np.minimum(frac, np.minimum(s, la - s) / max(inset, 1e-9))
    eave = b.height_m - b.roof_rise_m
    return eave + b.roof_rise_m * np.clip(frac, 0.0, 1.0)


def surface_model(sc: Scene) -> tuple[np.ndarray, np.ndarray]:
    """``dsm_m`` float32 (H, W) metres above the ground and ``facade_rgb`` uint8 (H, W, 3)."""
    H, W = sc.material.shape
    mpp = sc.cfg.m_per_px
    dsm = np.zeros((H, W), dtype=np.float32)
    facade = np.zeros((H, W, 3), dtype=np.uint8)
    if len(sc.crowns):
        _splat_crowns(dsm, facade, np.ascontiguousarray(sc.crowns, dtype=np.float64),
                      np.array(TREE_FACADE_RGB, dtype=np.uint8), mpp, CROWN_DEPTH_SHARE,
                      CROWN_DEPTH_PER_RADIUS)
    # crowns only over canopy; gaps inside a forest show the understorey
    step = 1024
    for r0 in range(0, H, step):
        r1 = min(H, r0 + step)
        forest = sc.material[r0:r1] == Material.FOREST
        d = dsm[r0:r1]
        f = facade[r0:r1]
        d[~forest] = 0.0
        f[~forest] = 0
        gap = forest & (d <= 0.0)
        d[gap] = UNDERSTOREY_M
        f[gap] = TREE_FACADE_RGB
    for b in sc.buildings:
        lo = np.floor(b.corners.min(axis=0)).astype(int) - 1
        hi = np.ceil(b.corners.max(axis=0)).astype(int) + 2
        x0, y0 = max(0, int(lo[0])), max(0, int(lo[1]))
        x1, y1 = min(W, int(hi[0])), min(H, int(hi[1]))
        if x1 <= x0 or y1 <= y0:
            continue
        mask = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
        fill_convex(mask, b.corners, 1, x0, y0)
        vs, us = np.nonzero(mask)
        if len(vs) == 0:
            continue
        z = _roof_heights(b, us + (x0 + 0.5), vs + (y0 + 0.5), mpp)
        dsm[vs + y0, us + x0] = z
        facade[vs + y0, us + x0] = np.array(b.facade, dtype=np.float64).round().astype(np.uint8)
        if b.style is RoofStyle.FLAT and len(b.hvac):
            for box in b.hvac:
                bm = np.zeros_like(mask)
                fill_convex(bm, box, 1, x0, y0)
                sel = (bm > 0) & (mask > 0)
                dsm[y0:y1, x0:x1][sel] = b.height_m + b.hvac_height_m
    return dsm, facade
