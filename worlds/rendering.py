"""Rendering a scene as captured on one day: roofs, textures, nature, cars, shadows, photometry.

:func:`render` works in row strips of ``STRIP_ROWS`` with seamless noise fields, so memory stays
bounded for 8000 x 8000 px maps; ``worlds/reference.py`` finishes each strip (tone map, blur, sensor
noise, JPEG round trip).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from worlds.blocks import Building, RoofStyle
from worlds.city_config import GENERATOR_VERSION, Stream
from worlds.drawing import SHIFT, cv_points, fill_convex, stroke
from worlds.materials import (
    AMP_COARSE,
    AMP_FINE,
    AMP_MED,
    BASE_RGB,
    BRANCH_RGB,
    FOREST_BASE,
    GRASS_DRY,
    GRASS_LUSH,
    SNOW_RGB,
    WATER_BASE,
    Material,
)
from worlds.reference import DayConditions, NoiseField, Season, SmoothNoise, finish_strip
from worlds.scene import Scene
from worlds.shadows import cast_shadows
from worlds.traffic import CAR_HEIGHT_M, Cars, cars_for_day, paint_cars

STRIP_ROWS = 1024      # rendering strip height (multiple of 16 for JPEG block alignment)
STRIP_MARGIN = 32      # extra rows rendered above/below a strip for blurs


def _facets(b: Building) -> list[tuple[np.ndarray, np.ndarray]]:
    """Roof facets (polygon, outward horizontal normal) of pitched roofs."""
    p0, p1, p2, p3 = b.corners
    a = p1 - p0
    a_len = float(np.hypot(*a))
    a_unit = a / max(a_len, 1e-9)
    n_out = p0 - p3
    n_out = n_out / max(float(np.hypot(*n_out)), 1e-9)
    m03, m12 = 0.5 * (p0 + p3), 0.5 * (p1 + p2)
    if b.style is RoofStyle.GABLE:
        return [(np.array([p0, p1, m12, m03]), n_out), (np.array([m03, m12, p2, p3]), -n_out)]
    half_b = 0.5 * float(np.hypot(*(p3 - p0)))
    inset = min(half_b, 0.45 * a_len)
    r0, r1 = m03 + a_unit * inset, m12 - a_unit * inset
    return [(np.array([p0, p1, r1, r0]), n_out), (np.array([r0, r1, p2, p3]), -n_out),
            (np.array([p0, r0, p3]), -a_unit), (np.array([p1, p2, r1]), a_unit)]


def _paint_roofs(canvas: np.ndarray, sc: Scene, idx: np.ndarray, sun: np.ndarray, top: int,
                 snow: bool = False) -> None:
    for i in idx:
        b = sc.buildings[i]
        tone = b.tone
        if snow and b.style in (RoofStyle.FLAT, RoofStyle.UNIFORM):
            # snow stays on flat roofs (pitched ones shed it): a tone from the building's own
            tone = tuple(float(c) for c in SNOW_RGB * (0.95 + 0.04 * ((sum(b.tone) / 3.0) / 255.0)))
        fill_convex(canvas, b.corners, tone, 0, top)
        if b.style in (RoofStyle.GABLE, RoofStyle.HIP):
            for poly, nrm in _facets(b):
                f = 1.0 + 0.22 * float(nrm @ sun)
                fill_convex(canvas, poly, tuple(min(255.0, c * f) for c in tone), 0, top)
            if b.style is RoofStyle.GABLE:
                p0, p1, p2, p3 = b.corners
                ridge = np.array([0.5 * (p0 + p3), 0.5 * (p1 + p2)])
                stroke(canvas, [ridge], tuple(min(255.0, c * 1.12) for c in tone), 1, 0, top)
        elif b.style is RoofStyle.FLAT:
            cv2.polylines(canvas, [cv_points(b.corners, 0, top)], True,
                          tuple(min(255.0, c * 1.15) for c in tone), 1, cv2.LINE_8, SHIFT)


class _StripFields:
    """Rows [a, b) of the day's natural noise fields, drawn once per strip on first use."""

    def __init__(self, fields: dict, a: int, b: int) -> None:
        self._fields, self._a, self._b = fields, a, b
        self._cache: dict[str, np.ndarray] = {}

    def __getitem__(self, key: str) -> np.ndarray:
        if key not in self._cache:
            self._cache[key] = self._fields[key].rows(self._a, self._b)
        return self._cache[key]


#: Weight of the DSM crowns' sunlight in the canopy's brightness (the rest is the day's texture).
CROWN_RELIEF = 0.15


def _crown_light(dsm: np.ndarray, day: DayConditions, mpp: float) -> np.ndarray:
    """Sunlight on the tree crowns of the DSM relative to flat ground (Lambert, clipped 0.35..1.35)."""
    gy, gx = np.gradient(dsm.astype(np.float32), mpp)
    su, sv = day.sun_vector_px()
    el = math.radians(day.sun_elevation_deg)
    # normal (-dz/du, -dz/dv, 1) in image axes (u east, v south, z up), sun (cos el su, cos el sv, sin el)
    lit = (-gx * math.cos(el) * su - gy * math.cos(el) * sv + math.sin(el)) / np.sqrt(1.0 + gx * gx + gy * gy)
    return np.clip(lit / math.sin(el), 0.35, 1.35)


def _paint_nature(canvas: np.ndarray, mat: np.ndarray, a: int, b: int, sc: Scene,
                  day: DayConditions, nat: dict, dsm_rows: np.ndarray) -> None:
    """Grass, forest canopy and water ripples from the day's own random stream; the crowns are lit
    by the day's sun on their domes in the DSM."""
    mpp = sc.cfg.m_per_px
    f = _StripFields(nat, a, b)
    winter = day.season is Season.WINTER
    grass = mat == Material.GRASS
    if grass.any() and winter:
        # snow cover: bright, faintly blue, drifts at ~14 m and crust at ~1 m
        col = SNOW_RGB[None, :] * (1.0 + 0.025 * f["coarse"][grass])[:, None]
        col += f["medium"][grass][:, None] * 2.5
        col += f["fine"][grass][:, None] * 2.0
        canvas[grass] = col
    elif grass.any():
        base = GRASS_LUSH + (GRASS_DRY - GRASS_LUSH) * day.grass_dryness
        col = base[None, :] * (1.0 + 0.06 * f["coarse"][grass])[:, None]
        col += f["medium"][grass][:, None] * np.array([4.0, 7.0, 3.0], dtype=np.float32)
        col += f["fine"][grass][:, None] * np.array([4.0, 5.0, 3.0], dtype=np.float32)
        canvas[grass] = col
    forest = mat == Material.FOREST
    if forest.any():
        # canopy height field: blurred noise at crown size, lit by the day's sun
        sigma = max(1.0, 2.0 / mpp)
        margin = int(3 * sigma) + 4
        rows = np.nonzero(forest.any(axis=1))[0]
        cols = np.nonzero(forest.any(axis=0))[0]
        y0, y1 = max(0, rows[0] - margin), min(mat.shape[0], rows[-1] + 1 + margin)
        x0, x1 = max(0, cols[0] - margin), min(mat.shape[1], cols[-1] + 1 + margin)
        h: np.ndarray = cv2.GaussianBlur(f["canopy"][y0:y1, x0:x1], (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        h *= 2.0 * sigma * math.sqrt(math.pi)
        gx = cv2.Sobel(h, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(h, cv2.CV_32F, 0, 1, ksize=3)
        sun = day.sun_vector_px()
        shade = gx * float(-sun[0] * sigma / 8.0) + gy * float(-sun[1] * sigma / 8.0)
        sub = forest[y0:y1, x0:x1]
        hf, sf = h[sub], shade[sub]
        # the day's own canopy texture dominates (a forest stays a bad matching area, seed paper
        # section 4.2); the DSM's crowns add a faint relief lit by the day's sun
        crown = _crown_light(dsm_rows[y0:y1, x0:x1], day, mpp)[sub]
        lum = (1.0 + 0.16 * hf + 0.35 * sf + 0.10 * f["coarse"][y0:y1, x0:x1][sub]) \
            * (1.0 - CROWN_RELIEF + CROWN_RELIEF * crown)
        lum = np.where(hf < -1.3, lum * 0.55, lum)
        if winter:
            # leaf-off crowns: brown-grey branches over the snow-covered ground showing through
            cover = np.clip(0.5 + 0.12 * hf + 0.1 * f["fine"][y0:y1, x0:x1][sub], 0.25, 0.8)
            col = (BRANCH_RGB[None, :] * (cover * lum)[:, None]
                   + SNOW_RGB[None, :] * (0.85 * (1.0 - cover))[:, None])
        else:
            col = FOREST_BASE[None, :] * lum[:, None]
        col += f["fine"][y0:y1, x0:x1][sub][:, None] * 3.0
        canvas[y0:y1, x0:x1][sub] = col
    water = mat == Material.WATER
    if water.any():
        ys, xs = np.nonzero(water)
        u = xs.astype(np.float32) + 0.5
        v = ys.astype(np.float32) + (a + 0.5)
        warp = f["warp"][water]
        lam = max(3.0, day.water_wave_m / mpp)
        th = math.radians(day.water_wave_dir_deg)
        k1 = 2.0 * math.pi / lam
        ph1 = k1 * (u * math.cos(th) + v * math.sin(th)) + 2.5 * warp
        k2 = k1 * 0.6
        ph2 = k2 * (u * math.cos(th + 0.9) + v * math.sin(th + 0.9)) + 1.5 * warp
        rip = np.sin(ph1) + 0.6 * np.sin(ph2)
        col = WATER_BASE[None, :] * (1.0 + 0.07 * f["coarse"][water])[:, None]
        col += (rip * 5.0 + np.maximum(rip - 1.2, 0.0) * 60.0)[:, None]
        col += f["fine"][water][:, None] * 2.0
        canvas[water] = col


def _car_shadows(day: DayConditions, cars: Cars, c_idx: np.ndarray, top: int, mpp: float,
                 shape: tuple[int, int]) -> np.ndarray:
    """The cars' shadows (boxes of CAR_HEIGHT_M; cars are not in the DSM, they change by day)."""
    m = np.zeros(shape, dtype=np.uint8)
    dc = day.shadow_offset_px(CAR_HEIGHT_M, mpp)
    for i in c_idx:
        pts = np.vstack([cars.corners[i], cars.corners[i] + dc])
        cv2.fillConvexPoly(m, cv2.convexHull(cv_points(pts, 0, top)), 1, cv2.LINE_8, SHIFT)
    for i in c_idx:
        fill_convex(m, cars.corners[i], 0, 0, top)
    return m.astype(np.float32)


def _shadow_mask(sc: Scene, day: DayConditions, cars: Cars, dsm: np.ndarray, max_h: float,
                 c_idx: np.ndarray, top: int, shape: tuple[int, int]) -> np.ndarray:
    """Soft shadow opacity of rows [top, top + shape[0]): the DSM's (buildings, roof boxes, trees)
    cast with the day's sun, and the cars'."""
    mpp = sc.cfg.m_per_px
    m = cast_shadows(dsm, sc.material, top, top + shape[0], day.sun_vector_px(), day.sun_elevation_deg,
                     mpp, day.tree_opacity, max_h)
    np.maximum(m, _car_shadows(day, cars, c_idx, top, mpp, shape), out=m)
    return cv2.GaussianBlur(m, (0, 0), 0.8)


def _render_strip(sc: Scene, day: DayConditions, cars: Cars, nat: dict, sensor: NoiseField,
                  dsm: np.ndarray, max_h: float, r0: int, r1: int) -> np.ndarray:
    H, W = sc.material.shape
    a, b = max(0, r0 - STRIP_MARGIN), min(H, r1 + STRIP_MARGIN)
    mat = sc.material[a:b]
    canvas = BASE_RGB[mat]
    sun = day.sun_vector_px()
    bb = sc.bld_bbox
    in_rows = np.nonzero((bb[:, 3] >= a - 2) & (bb[:, 1] < b + 2))[0] if len(bb) else np.zeros(0, int)
    _paint_roofs(canvas, sc, in_rows, sun, a, day.season is Season.WINTER)
    tex = AMP_FINE[mat] * sc.fine.rows(a, b)
    tex += AMP_MED[mat] * sc.medium.rows(a, b)
    tex += AMP_COARSE[mat] * sc.coarse.rows(a, b)
    canvas += tex[:, :, None]
    del tex
    _paint_nature(canvas, mat, a, b, sc, day, nat, dsm[a:b])
    car_idx = np.nonzero((cars.centre_v >= a - 8) & (cars.centre_v < b + 8))[0]
    paint_cars(canvas, cars, car_idx, a)
    for i in in_rows:
        for box in sc.buildings[i].hvac:
            fill_convex(canvas, box, (214.0, 214.0, 210.0), 0, a)
    shadow = _shadow_mask(sc, day, cars, dsm, max_h, car_idx, a, mat.shape)
    tint = np.array([1.0, 0.97, 0.86], dtype=np.float32) * day.shadow_strength
    canvas *= 1.0 - shadow[:, :, None] * tint
    del shadow
    return finish_strip(canvas, r0 - a, r1 - r0, r0, day, sensor)


def render(sc: Scene, day: DayConditions, dsm: np.ndarray) -> np.ndarray:
    """Render the scene as captured on ``day``: (H, W, 3) uint8 RGB; ``dsm`` (the scene's surface
    model, ``worlds/surface.py``) casts the shadows."""
    cfg = sc.cfg
    H, W = sc.material.shape
    mpp = cfg.m_per_px
    key = (cfg.seed, GENERATOR_VERSION, day.nature_seed)
    nat = {
        "fine": NoiseField(key + (Stream.NAT_FINE,), W),
        "medium": SmoothNoise(key + (Stream.NAT_MEDIUM,), W, 1.2 / mpp),
        "coarse": SmoothNoise(key + (Stream.NAT_COARSE,), W, 14.0 / mpp),
        "canopy": NoiseField(key + (Stream.NAT_CANOPY,), W),
        "warp": SmoothNoise(key + (Stream.NAT_WARP,), W, 9.0 / mpp),
    }
    sensor = NoiseField((cfg.seed, GENERATOR_VERSION, Stream.SENSOR, day.sensor_seed), 3 * W)
    cars = cars_for_day(sc, day)
    out = np.empty((H, W, 3), dtype=np.uint8)
    max_h = float(dsm.max()) if dsm.size else 0.0
    for r0 in range(0, H, STRIP_ROWS):
        r1 = min(H, r0 + STRIP_ROWS)
        out[r0:r1] = _render_strip(sc, day, cars, nat, sensor, dsm, max_h, r0, r1)
    return out
