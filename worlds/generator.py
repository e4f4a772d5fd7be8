"""Procedural city worlds: road graph, districts, buildings, nature, and two renderings.

``generate_world(CityConfig(...))`` builds a city in three stages:

1. **Layout** (vector, deterministic from ``cfg.seed``): large open features (lakes, forests, parks,
   squares, uniform-roof districts, rivers on big maps) are placed first; a jittered, rotated street
   grid with avenues is then turned into a graph with removed edges (tees, corners), corner-cutting
   diagonals (wyes), bends and curved edges; roads that would cross a feature are removed.
2. **Material raster**: features, roads (sidewalks, kerbs, carriageway, lane markings, crossings)
   and the blocks between them (perimeter blocks with courtyards, detached houses, large flat roofs,
   industrial halls with identical roofs, parking lots, small parks, trees) are drawn into an
   internal material raster whose classes map one-to-one onto :class:`LandCover`.
3. **Rendering**, twice: the orthophoto ("capture" day) and the reference map ("other day", see
   ``worlds/reference.py``). Rendering runs in row strips with seamless noise fields, so memory stays
   bounded for 8000 x 8000 px maps.

Junction ground truth comes from the road graph. Everything is vectorised (numpy / OpenCV drawing);
the Python loops run over graph edges, blocks and buildings, never over pixels.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from enum import Enum, IntEnum

import cv2
import numpy as np

from scenenav.core.config import check
from worlds.landcover import Junction, JunctionKind, LandCover, classify_arms
from worlds.reference import (DayConditions, NoiseField, SmoothNoise, capture_day, finish_strip,
                              other_day)
from worlds.world import CONVENTIONS, FORMAT_VERSION, World, WorldManifest, WorldSource

log = logging.getLogger(__name__)

#: Bump when the output of the generator changes for the same config (invalidates caches).
GENERATOR_VERSION = 1

MIN_SIDE_PX = 256
MAX_SIDE_PX = 16384

STRIP_ROWS = 1024      # rendering strip height (multiple of 16 for JPEG block alignment)
STRIP_MARGIN = 32      # extra rows rendered above/below a strip for blurs
_SHIFT = 4             # fractional bits of OpenCV drawing coordinates
_SCALE = float(1 << _SHIFT)
_MAX_BUILDING_HEIGHT_M = 30.0
_CAR_HEIGHT_M = 1.5


class Material(IntEnum):
    """Internal surface materials of the rendering; each maps onto one LandCover class."""

    GROUND = 0         # paved yards, bare ground
    SIDEWALK = 1
    KERB = 2
    ROAD = 3
    MARKING = 4        # lane markings and zebra crossings (on the carriageway)
    SQUARE = 5
    PARKING = 6
    PARKING_LINE = 7
    GRASS = 8
    FOREST = 9
    WATER = 10
    SAND = 11          # beaches, embankments
    ROOF_TEXTURED = 12
    ROOF_UNIFORM = 13


MATERIAL_TO_COVER = np.zeros(256, dtype=np.uint8)
for _m, _c in {
    Material.GROUND: LandCover.UNKNOWN, Material.SIDEWALK: LandCover.UNKNOWN,
    Material.KERB: LandCover.UNKNOWN, Material.ROAD: LandCover.ROAD,
    Material.MARKING: LandCover.ROAD, Material.SQUARE: LandCover.SQUARE,
    Material.PARKING: LandCover.PARKING, Material.PARKING_LINE: LandCover.PARKING,
    Material.GRASS: LandCover.GRASS, Material.FOREST: LandCover.FOREST,
    Material.WATER: LandCover.WATER, Material.SAND: LandCover.UNKNOWN,
    Material.ROOF_TEXTURED: LandCover.BUILDING_TEXTURED,
    Material.ROOF_UNIFORM: LandCover.BUILDING_UNIFORM,
}.items():
    MATERIAL_TO_COVER[int(_m)] = int(_c)

# Base colour (RGB) and structural-texture amplitudes (DN) per material: fine (pixel), medium
# (~3 m) and coarse (~25 m) noise. Natural materials (grass, forest, water) get their texture from
# the day's own random stream instead (see _paint_nature).
_MATERIAL_STYLE = {
    #                      base RGB          fine  med  coarse
    Material.GROUND:       ((146, 140, 128), 7.0, 7.0, 9.0),
    Material.SIDEWALK:     ((170, 167, 160), 5.0, 3.0, 5.0),
    Material.KERB:         ((198, 196, 190), 4.0, 0.0, 0.0),
    Material.ROAD:         ((84, 85, 88), 5.0, 4.0, 7.0),
    Material.MARKING:      ((222, 222, 212), 6.0, 8.0, 0.0),
    Material.SQUARE:       ((160, 156, 148), 1.2, 0.0, 0.0),
    Material.PARKING:      ((96, 96, 99), 5.0, 4.0, 6.0),
    Material.PARKING_LINE: ((214, 214, 204), 6.0, 0.0, 0.0),
    Material.GRASS:        ((92, 128, 58), 0.0, 0.0, 0.0),
    Material.FOREST:       ((46, 76, 38), 0.0, 0.0, 0.0),
    Material.WATER:        ((40, 66, 78), 0.0, 0.0, 0.0),
    Material.SAND:         ((186, 172, 138), 6.0, 5.0, 6.0),
    Material.ROOF_TEXTURED: ((150, 150, 150), 6.0, 4.0, 0.0),
    Material.ROOF_UNIFORM: ((188, 188, 184), 0.8, 0.0, 0.0),
}
_BASE_RGB = np.zeros((256, 3), dtype=np.float32)
_AMP_FINE = np.zeros(256, dtype=np.float32)
_AMP_MED = np.zeros(256, dtype=np.float32)
_AMP_COARSE = np.zeros(256, dtype=np.float32)
for _m, (_rgb, _f, _md, _co) in _MATERIAL_STYLE.items():
    _BASE_RGB[int(_m)] = _rgb
    _AMP_FINE[int(_m)] = _f
    _AMP_MED[int(_m)] = _md
    _AMP_COARSE[int(_m)] = _co

_GRASS_LUSH = np.array([82, 126, 52], dtype=np.float32)
_GRASS_DRY = np.array([136, 138, 78], dtype=np.float32)
_FOREST_BASE = np.array([44, 74, 36], dtype=np.float32)
_WATER_BASE = np.array([38, 64, 76], dtype=np.float32)

_GABLE_TONES = ((168, 86, 64), (142, 72, 58), (96, 96, 104), (118, 94, 78), (128, 126, 122),
                (104, 136, 122))
_GABLE_WEIGHTS = (0.34, 0.18, 0.2, 0.14, 0.1, 0.04)
_FLAT_TONES = ((176, 172, 164), (128, 126, 122), (206, 204, 198), (150, 146, 138), (96, 96, 104))
_FLAT_WEIGHTS = (0.3, 0.22, 0.18, 0.2, 0.1)
_UNIFORM_TONES = ((192, 192, 188), (172, 180, 188), (206, 206, 200))
_CAR_COLOURS = ((236, 236, 234), (30, 30, 34), (162, 164, 168), (92, 94, 98), (150, 32, 30),
                (34, 54, 120), (200, 182, 70))
_CAR_WEIGHTS = (0.25, 0.2, 0.24, 0.1, 0.08, 0.08, 0.05)


class Stream(IntEnum):
    """Independent random streams (numpy Generators seeded from [seed, stream, ...])."""

    FEATURES = 1
    GRAPH = 2
    BLOCKS = 3
    DAYS = 4
    TRAFFIC = 5
    TEX_FINE = 10
    TEX_MEDIUM = 11
    TEX_COARSE = 12
    NAT_FINE = 20
    NAT_MEDIUM = 21
    NAT_COARSE = 22
    NAT_CANOPY = 23
    NAT_WARP = 24
    SENSOR = 30


class RoadClass(IntEnum):
    STREET = 1
    AVENUE = 2
    DIAGONAL = 3


class FeatureKind(str, Enum):
    LAKE = "lake"
    FOREST = "forest"
    PARK = "park"
    SQUARE = "square"
    DISTRICT = "uniform_district"


class BlockKind(IntEnum):
    YARD = 0
    PERIMETER = 1
    DETACHED = 2
    BIG = 3
    PARK = 4
    PARKING = 5
    INDUSTRIAL = 6


class RoofStyle(IntEnum):
    FLAT = 1      # textured: parapet, HVAC boxes
    GABLE = 2     # two facets and a ridge
    HIP = 3       # four facets
    UNIFORM = 4   # one flat tone, no details


class _Blocked(IntEnum):
    """Codes of the road-blocking raster."""

    FREE = 0
    HARD = 1    # no roads at all (lake, forest, park, square)
    RIVER = 2   # roads may cross (bridges) but no nodes


@dataclass(frozen=True)
class CityConfig:
    """Parameters of a generated city. Lengths in metres, shares are fractions of the map area."""

    seed: int = 0
    width_px: int = 900
    height_px: int = 1000
    m_per_px: float = 0.53
    origin_lat_deg: float = 48.1372       # Munich, Marienplatz
    origin_lon_deg: float = 11.5755
    # road network
    road_spacing_m: float = 80.0          # mean distance between parallel streets
    road_spacing_jitter: float = 0.25     # +- fraction of the spacing, per grid line
    node_jitter_m: float = 4.0            # std of node displacement
    grid_rotation_max_deg: float = 20.0
    street_width_min_m: float = 6.0
    street_width_max_m: float = 12.0
    avenue_width_min_m: float = 16.0
    avenue_width_max_m: float = 22.0
    avenue_every_n: int = 4               # every n-th grid line is an avenue
    sidewalk_width_m: float = 3.0
    edge_removal_share: float = 0.12      # street segments removed (tees, corners)
    diagonal_share: float = 0.10          # nodes that get a corner-cutting diagonal (wyes)
    bend_share: float = 0.08              # street segments with a bend in the middle
    curve_share: float = 0.12             # segments drawn as smooth curves
    # open areas (the bad-matching surfaces of seed paper section 4.2)
    water_share: float = 0.10
    lake_diameter_m: float = 190.0
    river_width_m: float = 35.0
    river_every_km2: float = 6.0          # one river per this much map area; 0 = no rivers
    forest_share: float = 0.10
    forest_diameter_m: float = 190.0
    park_share: float = 0.015
    park_diameter_m: float = 110.0
    square_share: float = 0.025
    square_size_m: float = 90.0
    parking_share: float = 0.03
    uniform_district_share: float = 0.08
    uniform_district_diameter_m: float = 170.0
    hall_length_m: float = 40.0
    hall_width_m: float = 20.0
    courtyard_grass_share: float = 0.3
    # traffic
    cars_per_100m_lane: float = 2.5
    parking_occupancy: float = 0.6

    def __post_init__(self) -> None:
        check(isinstance(self.seed, int) and 0 <= self.seed < 2 ** 63, "seed", self.seed,
              "an integer in [0, 2**63)")
        for key in ("width_px", "height_px"):
            v = getattr(self, key)
            check(isinstance(v, int) and MIN_SIDE_PX <= v <= MAX_SIDE_PX, key, v,
                  f"an integer number of pixels in [{MIN_SIDE_PX}, {MAX_SIDE_PX}]")
        check(0.05 <= self.m_per_px <= 10.0, "m_per_px", self.m_per_px, "metres per pixel in [0.05, 10]")
        check(-85.0 <= self.origin_lat_deg <= 85.0, "origin_lat_deg", self.origin_lat_deg,
              "a latitude in [-85, 85] degrees")
        check(-180.0 <= self.origin_lon_deg <= 180.0, "origin_lon_deg", self.origin_lon_deg,
              "a longitude in [-180, 180] degrees")
        check(20.0 <= self.road_spacing_m <= 500.0, "road_spacing_m", self.road_spacing_m,
              "metres in [20, 500]")
        check(0.0 <= self.road_spacing_jitter <= 0.4, "road_spacing_jitter", self.road_spacing_jitter,
              "a fraction in [0, 0.4]")
        check(0.0 <= self.node_jitter_m <= 0.1 * self.road_spacing_m, "node_jitter_m",
              self.node_jitter_m, "metres in [0, road_spacing_m / 10]")
        check(0.0 <= self.grid_rotation_max_deg <= 45.0, "grid_rotation_max_deg",
              self.grid_rotation_max_deg, "degrees in [0, 45]")
        check(2.5 <= self.street_width_min_m <= self.street_width_max_m <= 30.0,
              "street_width_min_m/street_width_max_m", (self.street_width_min_m, self.street_width_max_m),
              "2.5 <= min <= max <= 30 metres")
        check(self.street_width_max_m <= self.avenue_width_min_m <= self.avenue_width_max_m <= 50.0,
              "avenue_width_min_m/avenue_width_max_m", (self.avenue_width_min_m, self.avenue_width_max_m),
              "street_width_max_m <= min <= max <= 50 metres")
        check(self.avenue_width_max_m <= 0.4 * self.road_spacing_m, "avenue_width_max_m",
              self.avenue_width_max_m, "at most 0.4 * road_spacing_m")
        check(isinstance(self.avenue_every_n, int) and 1 <= self.avenue_every_n <= 100,
              "avenue_every_n", self.avenue_every_n, "an integer in [1, 100]")
        check(0.0 <= self.sidewalk_width_m <= 10.0, "sidewalk_width_m", self.sidewalk_width_m,
              "metres in [0, 10]")
        for key in ("edge_removal_share", "diagonal_share", "bend_share", "curve_share"):
            v = getattr(self, key)
            check(0.0 <= v <= 0.5, key, v, "a fraction in [0, 0.5]")
        shares = ("water_share", "forest_share", "park_share", "square_share", "parking_share",
                  "uniform_district_share")
        for key in shares:
            v = getattr(self, key)
            check(0.0 <= v <= 0.4, key, v, "a fraction of the map area in [0, 0.4]")
        total = sum(getattr(self, k) for k in shares)
        check(total <= 0.7, "+".join(shares), round(total, 3), "a sum of at most 0.7 (the rest is city)")
        for key in ("lake_diameter_m", "forest_diameter_m", "park_diameter_m", "square_size_m",
                    "uniform_district_diameter_m"):
            v = getattr(self, key)
            check(20.0 <= v <= 5000.0, key, v, "metres in [20, 5000]")
        check(5.0 <= self.river_width_m <= 500.0, "river_width_m", self.river_width_m,
              "metres in [5, 500]")
        check(self.river_every_km2 >= 0.0, "river_every_km2", self.river_every_km2,
              "square kilometres >= 0 (0 = no rivers)")
        check(10.0 <= self.hall_width_m <= self.hall_length_m <= 200.0, "hall_width_m/hall_length_m",
              (self.hall_width_m, self.hall_length_m), "10 <= width <= length <= 200 metres")
        check(0.0 <= self.courtyard_grass_share <= 1.0, "courtyard_grass_share",
              self.courtyard_grass_share, "a fraction in [0, 1]")
        check(0.0 <= self.cars_per_100m_lane <= 20.0, "cars_per_100m_lane", self.cars_per_100m_lane,
              "cars per 100 m of lane in [0, 20]")
        check(0.0 <= self.parking_occupancy <= 1.0, "parking_occupancy", self.parking_occupancy,
              "a fraction in [0, 1]")

    @property
    def area_m2(self) -> float:
        return self.width_px * self.height_px * self.m_per_px ** 2


def _rng(cfg: CityConfig, stream: Stream, *extra: int) -> np.random.Generator:
    return np.random.default_rng([cfg.seed, GENERATOR_VERSION, int(stream), *extra])


# ---------------------------------------------------------------------------------------------
# drawing helpers (continuous pixel coordinates, see scenenav/core/frames.py)

def _cv(pts, dx: float = 0.0, dy: float = 0.0) -> np.ndarray:
    """Continuous (u, v) points -> int32 OpenCV points with _SHIFT fractional bits.

    OpenCV puts integer coordinate (c, r) at the centre of pixel (c, r), which is continuous
    (c + 0.5, r + 0.5); ``dx, dy`` (integers) translate into a sub-image.
    """
    q = np.asarray(pts, dtype=np.float64) * _SCALE
    q -= ((0.5 + dx) * _SCALE, (0.5 + dy) * _SCALE)
    return np.rint(q, out=q).astype(np.int32)


def _fill_convex(img: np.ndarray, poly, value, dx: int = 0, dy: int = 0) -> None:
    cv2.fillConvexPoly(img, _cv(poly, dx, dy), value, cv2.LINE_8, _SHIFT)


def _stroke(img: np.ndarray, polys, value, thickness: int, dx: int = 0, dy: int = 0) -> None:
    if not polys:
        return
    cv2.polylines(img, [_cv(p, dx, dy) for p in polys], False, value, max(1, int(thickness)),
                  cv2.LINE_8, _SHIFT)


def _rect(centre, ax, bx, la: float, lb: float) -> np.ndarray:
    """Rectangle corners with corners[0] -> corners[1] along the longer side."""
    c = np.asarray(centre, dtype=float)
    ha = np.asarray(ax) * (la / 2.0)
    hb = np.asarray(bx) * (lb / 2.0)
    pts = np.array([c - ha - hb, c + ha - hb, c + ha + hb, c - ha + hb])
    if la < lb:
        pts = pts[[1, 2, 3, 0]]
    return pts


def _arc_lengths(poly: np.ndarray) -> np.ndarray:
    seg = np.hypot(*np.diff(poly, axis=0).T)
    return np.concatenate([[0.0], np.cumsum(seg)])


def _normals(poly: np.ndarray) -> np.ndarray:
    t = np.gradient(poly, axis=0)
    t /= np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-9)[:, None]
    return np.stack([-t[:, 1], t[:, 0]], axis=1)


def _interp(poly: np.ndarray, arc: np.ndarray, s) -> np.ndarray:
    s = np.asarray(s, dtype=float)
    return np.stack([np.interp(s, arc, poly[:, 0]), np.interp(s, arc, poly[:, 1])], axis=-1)


def _sub_polyline(poly: np.ndarray, arc: np.ndarray, s0: float, s1: float) -> np.ndarray:
    inner = (arc > s0) & (arc < s1)
    return np.concatenate([_interp(poly, arc, [s0]), poly[inner], _interp(poly, arc, [s1])])


def _blob_radii(rng: np.random.Generator, n: int, roughness: float, floor: float) -> np.ndarray:
    """Relative radius r(theta) of a smooth random blob at n angles (mean 1)."""
    theta = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r = np.ones(n)
    for k in range(2, 7):
        r += rng.uniform(0.0, roughness / k) * np.cos(k * theta + rng.uniform(0.0, 2.0 * np.pi))
    return np.maximum(r, floor)


def _blob_polygon(centre, radius_px: float, rel: np.ndarray, extra_px: float = 0.0) -> np.ndarray:
    theta = np.linspace(0.0, 2.0 * np.pi, rel.size, endpoint=False)
    r = radius_px * rel + extra_px
    return np.stack([centre[0] + r * np.cos(theta), centre[1] + r * np.sin(theta)], axis=1)


# ---------------------------------------------------------------------------------------------
# open features

@dataclass
class _Feature:
    kind: FeatureKind
    centre: np.ndarray
    radius_px: float          # core radius (water / canopy / grass / district / square half-diagonal)
    rel: np.ndarray | None = None      # blob shape
    half_sizes_px: tuple[float, float] = (0.0, 0.0)  # squares
    angle_rad: float = 0.0


def _feature_count(share: float, diameter_m: float, cfg: CityConfig, square: bool = False) -> int:
    area = diameter_m ** 2 if square else math.pi * (diameter_m / 2.0) ** 2
    return int(math.floor(share * cfg.area_m2 / area + 0.5))


def _place_features(cfg: CityConfig, rng: np.random.Generator, grid_angle: float) -> list[_Feature]:
    W, H, mpp = cfg.width_px, cfg.height_px, cfg.m_per_px
    gap = 50.0 / mpp
    shore = 10.0 / mpp
    plan = []  # (kind, core radius px, placement radius px, inside fraction)
    for kind, share, diam, inside in (
            (FeatureKind.LAKE, cfg.water_share, cfg.lake_diameter_m, 1.0),
            (FeatureKind.FOREST, cfg.forest_share, cfg.forest_diameter_m, 1.0),
            (FeatureKind.DISTRICT, cfg.uniform_district_share, cfg.uniform_district_diameter_m, 0.8),
            (FeatureKind.PARK, cfg.park_share, cfg.park_diameter_m, 0.7),
            (FeatureKind.SQUARE, cfg.square_share, cfg.square_size_m, 0.9)):
        n = _feature_count(share, diam, cfg, square=kind is FeatureKind.SQUARE)
        for _ in range(n):
            # lakes and forests stay at least the configured size: their inscribed circle must
            # hold a camera footprint (the blobs below never dent more than 12 %)
            scale = rng.uniform(1.0, 1.15) if kind in (FeatureKind.LAKE, FeatureKind.FOREST) \
                else rng.uniform(0.85, 1.15)
            r = diam * scale / 2.0 / mpp
            if kind is FeatureKind.SQUARE:
                r *= math.sqrt(2.0) * 0.8
            extra = shore if kind is FeatureKind.LAKE else 0.0
            plan.append((kind, r, r + extra, inside))
    placed: list[_Feature] = []
    centres = np.zeros((0, 2))
    radii = np.zeros(0)
    for kind, r_core, r_place, inside in plan:
        ok = False
        for shrink in (1.0, 0.85, 0.72):
            rc, rp = r_core * shrink, r_place * shrink
            m = rp * inside
            if W - 2 * m <= 0 or H - 2 * m <= 0:
                continue
            # best of many candidates: as far as possible from the features already placed and
            # from the map centre (which stays city), so features spread out evenly
            cands = np.stack([rng.uniform(m, W - m, 96), rng.uniform(m, H - m, 96)], axis=1)
            score = np.hypot(*(cands - np.array([W / 2.0, H / 2.0])).T)
            if kind is FeatureKind.SQUARE:     # squares may be central
                score = np.full(len(cands), 10.0 * (W + H))
            if centres.size:
                clear = np.min(np.hypot(cands[:, None, 0] - centres[None, :, 0],
                                        cands[:, None, 1] - centres[None, :, 1])
                               - radii[None, :], axis=1) - rp
                score = np.where(clear >= gap, np.minimum(score, clear), -np.inf)
            best = int(np.argmax(score))
            if np.isfinite(score[best]):
                c = cands[best]
                ok = True
                break
        if not ok:
            log.info("no room for a %s of radius %.0f m; skipped", kind.value, r_core * mpp)
            continue
        feat = _Feature(kind=kind, centre=c, radius_px=rc)
        if kind in (FeatureKind.LAKE, FeatureKind.PARK):
            feat.rel = _blob_radii(rng, 96, 0.25, 0.88)
        elif kind is FeatureKind.FOREST:
            feat.rel = _blob_radii(rng, 128, 0.35, 0.88)
        elif kind is FeatureKind.SQUARE:
            aspect = rng.uniform(0.75, 1.0)
            half = rc / math.sqrt(1.0 + aspect ** 2)
            feat.half_sizes_px = (half, half * aspect)
            feat.angle_rad = grid_angle
        placed.append(feat)
        centres = np.vstack([centres, c])
        radii = np.append(radii, rp)
    return placed


def _square_polygon(f: _Feature, extra_px: float = 0.0) -> np.ndarray:
    ca, sa = math.cos(f.angle_rad), math.sin(f.angle_rad)
    ax, bx = np.array([ca, sa]), np.array([-sa, ca])
    hx, hy = f.half_sizes_px
    return _rect(f.centre, ax, bx, 2 * (hx + extra_px), 2 * (hy + extra_px))


@dataclass
class _Ring:
    """Ring road around a feature: closed polygon of vertices in angular order."""

    centre: np.ndarray
    poly: np.ndarray
    width_m: float
    off_px: float      # distance of the ring centreline outside the feature's edge


_SHORE_M = 10.0          # promenade and lawn around lakes
_RING_CLEAR_M = 30.0     # grid roads keep this far outside a ring (room for a row of buildings)


def _feature_outline(f: _Feature, extra_px: float) -> np.ndarray:
    if f.kind is FeatureKind.SQUARE:
        return _square_polygon(f, extra_px)
    return _blob_polygon(f.centre, f.radius_px, f.rel, extra_px)


def _feature_edge_px(f: _Feature, mpp: float) -> float:
    """Extra radius of the drawn feature beyond its core shape (the lake shore)."""
    return _SHORE_M / mpp if f.kind is FeatureKind.LAKE else 0.0


def _make_rings(features: list[_Feature], cfg: CityConfig,
                rng: np.random.Generator) -> list[_Ring | None]:
    mpp = cfg.m_per_px
    spacing = 12.0 / mpp
    rings: list[_Ring | None] = []
    for f in features:
        if f.kind is FeatureKind.DISTRICT:
            rings.append(None)
            continue
        w = round(rng.uniform(cfg.street_width_min_m, cfg.street_width_min_m + 2.0) * 2) / 2
        off = (w / 2.0 + cfg.sidewalk_width_m + 1.0) / mpp
        outline = _feature_outline(f, _feature_edge_px(f, mpp) + off)
        if f.kind is FeatureKind.SQUARE:
            verts = []
            for i in range(4):
                p, q = outline[i], outline[(i + 1) % 4]
                k = max(1, int(math.ceil(np.hypot(*(q - p)) / spacing)))
                verts += [p + (q - p) * (j / k) for j in range(k)]
            poly = np.array(verts)
        else:
            closed = np.vstack([outline, outline[:1]])
            arc = _arc_lengths(closed)
            k = max(48, int(arc[-1] / spacing))
            poly = _interp(closed, arc, np.linspace(0.0, arc[-1], k, endpoint=False))
        rings.append(_Ring(centre=f.centre, poly=poly, width_m=w, off_px=off))
    return rings


def _river_polylines(cfg: CityConfig, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    if cfg.river_every_km2 <= 0.0:
        return []
    n = int(cfg.area_m2 / 1e6 / cfg.river_every_km2)
    W, H, mpp = cfg.width_px, cfg.height_px, cfg.m_per_px
    out = []
    step = 12.0 / mpp
    for _ in range(n):
        side = int(rng.integers(4))
        t = rng.uniform(0.15, 0.85)
        start, heading = {0: ((t * W, -50.0), math.pi / 2), 1: ((W + 50.0, t * H), math.pi),
                          2: ((t * W, H + 50.0), -math.pi / 2), 3: ((-50.0, t * H), 0.0)}[side]
        p = np.array(start, dtype=float)
        heading += rng.uniform(-0.4, 0.4)
        base = heading
        turn = 0.0
        pts = [p.copy()]
        for _ in range(int(4 * (W + H) / step)):
            turn = 0.9 * turn + rng.normal(0.0, 0.025)
            heading += turn - 0.08 * (heading - base)
            p = p + step * np.array([math.cos(heading), math.sin(heading)])
            pts.append(p.copy())
            if not (-200 <= p[0] <= W + 200 and -200 <= p[1] <= H + 200):
                break
        width = cfg.river_width_m * rng.uniform(0.8, 1.3) / mpp
        out.append((np.array(pts), width))
    return out


# ---------------------------------------------------------------------------------------------
# road graph

@dataclass
class _Edge:
    a: int
    b: int
    width_m: float
    road_class: RoadClass
    ctrl: np.ndarray | None = None   # quadratic Bezier control point (curved edges)
    alive: bool = True
    modified: bool = False


class _RoadGraph:
    """Nodes (continuous pixel positions) and edges (straight or quadratic Bezier)."""

    def __init__(self) -> None:
        self.pos: list[np.ndarray] = []
        self.adj: list[list[int]] = []
        self.node_alive: list[bool] = []
        self.edges: list[_Edge] = []

    def add_node(self, p) -> int:
        self.pos.append(np.asarray(p, dtype=float))
        self.adj.append([])
        self.node_alive.append(True)
        return len(self.pos) - 1

    def add_edge(self, a: int, b: int, width_m: float, road_class: RoadClass,
                 ctrl: np.ndarray | None = None, modified: bool = False) -> int:
        self.edges.append(_Edge(a, b, width_m, road_class, ctrl, True, modified))
        e = len(self.edges) - 1
        self.adj[a].append(e)
        self.adj[b].append(e)
        return e

    def kill_edge(self, e: int) -> None:
        E = self.edges[e]
        if not E.alive:
            return
        E.alive = False
        self.adj[E.a].remove(e)
        self.adj[E.b].remove(e)

    def kill_node(self, n: int) -> None:
        for e in list(self.adj[n]):
            self.kill_edge(e)
        self.node_alive[n] = False

    def degree(self, n: int) -> int:
        return len(self.adj[n])

    def other(self, e: int, n: int) -> int:
        E = self.edges[e]
        return E.b if E.a == n else E.a

    def arm_angle(self, e: int, n: int) -> float:
        E = self.edges[e]
        target = E.ctrl if E.ctrl is not None else self.pos[self.other(e, n)]
        d = target - self.pos[n]
        return math.atan2(d[1], d[0])

    def chord(self, e: int) -> float:
        E = self.edges[e]
        return float(np.hypot(*(self.pos[E.b] - self.pos[E.a])))

    def polyline(self, e: int, step_px: float | None = None) -> np.ndarray:
        """Points along the edge from a to b; straight edges give 2 points unless step_px is set."""
        E = self.edges[e]
        pa, pb = self.pos[E.a], self.pos[E.b]
        length = self.chord(e)
        if E.ctrl is None:
            if step_px is None:
                return np.array([pa, pb])
            t = np.linspace(0.0, 1.0, max(2, int(math.ceil(length / step_px)) + 1))[:, None]
            return pa + t * (pb - pa)
        step = step_px if step_px is not None else 3.0
        t = np.linspace(0.0, 1.0, max(12, int(math.ceil(length / step)) + 1))[:, None]
        return (1 - t) ** 2 * pa + 2 * (1 - t) * t * E.ctrl + t ** 2 * pb

    def split(self, e: int, t_from_a: float, offset_px: float) -> int:
        """Replace edge e by two edges through a new node (offset sideways for bends)."""
        E = self.edges[e]
        pa, pb = self.pos[E.a], self.pos[E.b]
        d = pb - pa
        n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
        m = self.add_node(pa + t_from_a * d + n * offset_px)
        self.kill_edge(e)
        self.add_edge(E.a, m, E.width_m, E.road_class, modified=True)
        self.add_edge(m, E.b, E.width_m, E.road_class, modified=True)
        return m

    def kind(self, n: int) -> JunctionKind | None:
        return classify_arms([self.arm_angle(e, n) for e in self.adj[n]])

    def alive_edges(self) -> list[int]:
        return [i for i, E in enumerate(self.edges) if E.alive]


def _grid_graph(cfg: CityConfig, rng: np.random.Generator, angle: float) -> _RoadGraph:
    W, H, mpp = cfg.width_px, cfg.height_px, cfg.m_per_px
    s = cfg.road_spacing_m / mpp
    half = 0.5 * math.hypot(W, H) + 1.5 * s
    jit = cfg.road_spacing_jitter

    def lines() -> tuple[np.ndarray, list[tuple[float, RoadClass]]]:
        pos = [-half - rng.uniform(0.0, s)]
        while pos[-1] < half:
            pos.append(pos[-1] + s * rng.uniform(1.0 - jit, 1.0 + jit))
        phase = int(rng.integers(cfg.avenue_every_n))
        styles = []
        for i in range(len(pos)):
            if i % cfg.avenue_every_n == phase:
                w = rng.uniform(cfg.avenue_width_min_m, cfg.avenue_width_max_m)
                styles.append((round(w * 2) / 2, RoadClass.AVENUE))
            else:
                w = rng.uniform(cfg.street_width_min_m, cfg.street_width_max_m)
                styles.append((round(w * 2) / 2, RoadClass.STREET))
        return np.array(pos), styles

    xs, col_styles = lines()
    ys, row_styles = lines()
    ca, sa = math.cos(angle), math.sin(angle)
    centre = np.array([W / 2.0, H / 2.0])
    jitter = cfg.node_jitter_m / mpp
    g = _RoadGraph()
    index = -np.ones((len(xs), len(ys)), dtype=np.int64)
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            p = centre + np.array([ca * x - sa * y, sa * x + ca * y]) + rng.normal(0.0, jitter, 2)
            if -1.5 * s <= p[0] <= W + 1.5 * s and -1.5 * s <= p[1] <= H + 1.5 * s:
                index[i, j] = g.add_node(p)
    for i in range(len(xs)):
        for j in range(len(ys)):
            n = index[i, j]
            if n < 0:
                continue
            if i + 1 < len(xs) and index[i + 1, j] >= 0:
                w, cls = row_styles[j]
                g.add_edge(int(n), int(index[i + 1, j]), w, cls)
            if j + 1 < len(ys) and index[i, j + 1] >= 0:
                w, cls = col_styles[i]
                g.add_edge(int(n), int(index[i, j + 1]), w, cls)
    return g


def _in_map(p: np.ndarray, W: int, H: int, margin: float = 0.0) -> bool:
    return margin <= p[0] < W - margin and margin <= p[1] < H - margin


def _sample(raster: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Raster values at continuous points (0 outside the raster)."""
    H, W = raster.shape
    u = np.floor(pts[:, 0]).astype(np.int64)
    v = np.floor(pts[:, 1]).astype(np.int64)
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    out = np.zeros(len(pts), dtype=raster.dtype)
    out[inside] = raster[v[inside], u[inside]]
    return out


def _path_is_free(blocked: np.ndarray, pts: np.ndarray) -> bool:
    return not np.any(_sample(blocked, pts) != _Blocked.FREE)


def _eligible_street(g: _RoadGraph, e: int, min_len: float) -> bool:
    E = g.edges[e]
    return (E.alive and E.road_class is RoadClass.STREET and not E.modified and E.ctrl is None
            and g.chord(e) >= min_len)


def _corner_diagonal(g: _RoadGraph, n: int, rng: np.random.Generator, cfg: CityConfig, s_px: float,
                     blocked: np.ndarray | None = None) -> bool:
    """Cut the corner between two perpendicular street arms of node n with a diagonal (two wyes)."""
    arms = sorted((g.arm_angle(e, n), e) for e in g.adj[n])
    pairs = []
    for k in range(len(arms)):
        (a1, e1), (a2, e2) = arms[k], arms[(k + 1) % len(arms)]
        gap = (a2 - a1) % (2 * math.pi)
        if (math.radians(70) <= gap <= math.radians(110) and _eligible_street(g, e1, 0.55 * s_px)
                and _eligible_street(g, e2, 0.55 * s_px)):
            pairs.append((e1, e2))
    if not pairs:
        return False
    e1, e2 = pairs[int(rng.integers(len(pairs)))]
    t1, t2 = rng.uniform(0.4, 0.6, 2)
    ends = []
    for e, t in ((e1, t1), (e2, t2)):
        E = g.edges[e]
        ends.append((e, t if E.a == n else 1.0 - t))
    p = [g.pos[g.edges[e].a] + t * (g.pos[g.edges[e].b] - g.pos[g.edges[e].a]) for e, t in ends]
    for here, there in ((p[0], p[1]), (p[1], p[0])):
        # keep the wye's acute angle open enough to read as two separate roads
        d1, d2 = g.pos[n] - here, there - here
        cos = float(d1 @ d2) / max(float(np.hypot(*d1) * np.hypot(*d2)), 1e-9)
        if cos > math.cos(math.radians(35.0)):
            return False
    if blocked is not None:
        seg = p[0] + np.linspace(0, 1, 40)[:, None] * (p[1] - p[0])
        if not _path_is_free(blocked, seg):
            return False
    m1 = g.split(ends[0][0], ends[0][1], 0.0)
    m2 = g.split(ends[1][0], ends[1][1], 0.0)
    hi = min(cfg.street_width_max_m, cfg.street_width_min_m + 3.0)
    width = round(rng.uniform(cfg.street_width_min_m, hi) * 2) / 2
    g.add_edge(m1, m2, width, RoadClass.DIAGONAL, modified=True)
    return True


def _bend(g: _RoadGraph, e: int, rng: np.random.Generator,
          blocked: np.ndarray | None = None) -> bool:
    dev = math.radians(rng.uniform(16.0, 26.0))
    offset = 0.5 * g.chord(e) * math.tan(dev) * (1 if rng.random() < 0.5 else -1)
    if blocked is not None:
        E = g.edges[e]
        pa, pb = g.pos[E.a], g.pos[E.b]
        d = pb - pa
        n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
        m = 0.5 * (pa + pb) + n * offset
        t = np.linspace(0, 1, 30)[:, None]
        if not (_path_is_free(blocked, pa + t * (m - pa)) and _path_is_free(blocked, m + t * (pb - m))):
            return False
    g.split(e, 0.5, offset)
    return True


def _build_graph(cfg: CityConfig, rng: np.random.Generator, angle: float, blocked: np.ndarray,
                 owner: np.ndarray, rings: list[_Ring | None]) -> _RoadGraph:
    W, H = cfg.width_px, cfg.height_px
    s_px = cfg.road_spacing_m / cfg.m_per_px
    g = _grid_graph(cfg, rng, angle)

    # tees and corners: remove street segments, never leaving a dead end
    for e in rng.permutation(len(g.edges)):
        E = g.edges[e]
        draw = rng.random()
        if (E.alive and E.road_class is RoadClass.STREET and draw < cfg.edge_removal_share
                and g.degree(E.a) >= 3 and g.degree(E.b) >= 3):
            g.kill_edge(int(e))
    # wyes: corner-cutting diagonals
    for n in rng.permutation(len(g.pos)):
        draw = rng.random()
        if draw < cfg.diagonal_share and g.node_alive[n] and _in_map(g.pos[n], W, H):
            _corner_diagonal(g, int(n), rng, cfg, s_px)
    # bends, then smooth curves
    for e in rng.permutation(len(g.edges)):
        draw = rng.random()
        if draw < cfg.bend_share and _eligible_street(g, int(e), 0.6 * s_px):
            _bend(g, int(e), rng)
    for e in rng.permutation(len(g.edges)):
        E = g.edges[e]
        draw = rng.random()
        if (draw < cfg.curve_share and E.alive and not E.modified
                and E.road_class in (RoadClass.STREET, RoadClass.AVENUE)):
            pa, pb = g.pos[E.a], g.pos[E.b]
            d = pb - pa
            n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
            dev = math.radians(rng.uniform(10.0, 20.0)) * (1 if rng.random() < 0.5 else -1)
            E.ctrl = 0.5 * (pa + pb) + n * 0.5 * g.chord(int(e)) * math.tan(dev)
            E.modified = True

    _cut_at_features(g, blocked, owner, rings, cfg)
    _ensure_kinds(g, cfg, rng, s_px, blocked)
    for n in range(len(g.pos)):
        if g.node_alive[n] and g.degree(n) == 0:
            g.kill_node(n)
    return g


def _cut_at_features(g: _RoadGraph, blocked: np.ndarray, owner: np.ndarray,
                     rings: list[_Ring | None], cfg: CityConfig) -> None:
    """Connect the street grid to the ring roads around features; rivers get bridges.

    An edge entering a feature's clearance zone is cut where it meets the feature's ring road and
    joined to it (a tee or wye on the ring); without a ring in reach it ends in a cul-de-sac (stubs
    shorter than 30 m are dropped). Nodes inside any zone are removed. Edges crossing a river with
    both ends on land stay (bridges); edges running along a river are removed.
    """
    mpp = cfg.m_per_px
    step = 2.0
    back = int(math.ceil(3.0 / mpp / step))
    min_stub = 30.0 / mpp
    join = 8.0 / mpp
    node_free = [g.node_alive[n] and _sample(blocked, g.pos[n][None])[0] == _Blocked.FREE
                 for n in range(len(g.pos))]
    attach: dict[int, list[int]] = {i: [] for i, r in enumerate(rings) if r is not None}
    polys = [r.poly for r in rings if r is not None]
    ring_pts = np.concatenate(polys) if polys else np.zeros((0, 2))
    near_ring = 45.0 / mpp
    for e in g.alive_edges():
        E = g.edges[e]
        pts = g.polyline(e, step)
        codes = _sample(blocked, pts)
        along_river = np.mean(codes == _Blocked.RIVER) > 0.5
        if (not along_river and not np.any(codes == _Blocked.HARD)
                and node_free[E.a] and node_free[E.b]):
            continue
        g.kill_edge(e)
        if along_river:
            continue
        own = _sample(owner, pts)
        bad = np.nonzero(codes != _Blocked.FREE)[0]
        for node, seq in ((E.a, np.arange(len(pts))), (E.b, np.arange(len(pts))[::-1])):
            if not node_free[node]:
                continue
            hits = np.nonzero(own[seq] != 0)[0]
            if hits.size and _meets_ring_squarely(rings[int(own[seq[hits[0]]]) - 1],
                                                  g.pos[node], pts[int(seq[hits[0]])]):
                j = int(seq[hits[0]])
                ring_id = int(own[j]) - 1
                if float(np.hypot(*(pts[j] - g.pos[node]))) < join:
                    attach[ring_id].append(node)
                else:
                    end = g.add_node(pts[j])
                    node_free.append(True)
                    g.add_edge(node, end, E.width_m, E.road_class, modified=True)
                    attach[ring_id].append(end)
                continue
            idx = int(bad[0] - back) if node == E.a else int(bad[-1] + back)
            if idx < 0 or idx >= len(pts):
                continue
            if float(np.hypot(*(pts[idx] - g.pos[node]))) < min_stub or ring_pts.size and \
                    np.min(np.hypot(*(ring_pts - pts[idx]).T)) < near_ring:
                continue   # too short, or a dead end right next to a ring road: drop the road
            stub = g.add_node(pts[idx])
            node_free.append(True)
            g.add_edge(node, stub, E.width_m, E.road_class, modified=True)
    for n in range(len(g.pos)):
        if g.node_alive[n] and not node_free[n]:
            g.kill_node(n)
    for ring_id, nodes in attach.items():
        _close_ring(g, rings[ring_id], ring_id, sorted(set(nodes)), owner, join)


def _meets_ring_squarely(ring: _Ring, start: np.ndarray, hit: np.ndarray,
                         min_angle_deg: float = 40.0) -> bool:
    """True if a road from ``start`` reaching the ring at ``hit`` is not grazing along it."""
    k = int(np.argmin(np.hypot(*(ring.poly - hit).T)))
    tangent = ring.poly[(k + 1) % len(ring.poly)] - ring.poly[k - 1]
    d = hit - start
    norm = float(np.hypot(*tangent) * np.hypot(*d))
    if norm < 1e-9:
        return True
    sin = abs(float(tangent[0] * d[1] - tangent[1] * d[0])) / norm
    return sin >= math.sin(math.radians(min_angle_deg))


def _close_ring(g: _RoadGraph, ring: _Ring, ring_id: int, nodes: list[int], owner: np.ndarray,
                join: float) -> None:
    """Add the ring road: its own vertices plus the attachment nodes, chained by angle."""
    att = np.array([g.pos[n] for n in nodes]) if nodes else np.zeros((0, 2))
    ids = list(nodes)
    for p in ring.poly:
        if att.size and np.min(np.hypot(*(att - p).T)) < join:
            continue
        ids.append(g.add_node(p))
    ang = [math.atan2(*(g.pos[n] - ring.centre)[::-1]) for n in ids]
    order = [ids[i] for i in np.argsort(ang, kind="stable")]
    for i, n in enumerate(order):
        m = order[(i + 1) % len(order)]
        pa, pb = g.pos[n], g.pos[m]
        t = np.linspace(0.0, 1.0, max(4, int(np.hypot(*(pb - pa)) / 2.0)))[:, None]
        own = _sample(owner, pa + t * (pb - pa))
        if np.any((own != 0) & (own != ring_id + 1)):
            continue
        g.add_edge(n, m, ring.width_m, RoadClass.STREET, modified=True)
    for n in ids:
        if g.node_alive[n] and g.degree(n) == 0:
            g.kill_node(n)


def _present_kinds(g: _RoadGraph, W: int, H: int, margin: float) -> set[JunctionKind]:
    out = set()
    for n in range(len(g.pos)):
        if g.node_alive[n] and _in_map(g.pos[n], W, H, margin):
            k = g.kind(n)
            if k is not None:
                out.add(k)
    return out


def _ensure_kinds(g: _RoadGraph, cfg: CityConfig, rng: np.random.Generator, s_px: float,
                  blocked: np.ndarray) -> None:
    """Make sure every junction kind occurs inside the map (small maps can miss some by chance)."""
    W, H = cfg.width_px, cfg.height_px
    margin = min(0.5 * s_px, 0.2 * min(W, H))
    for kind in (JunctionKind.TEE, JunctionKind.CORNER, JunctionKind.WYE, JunctionKind.BEND):
        if kind in _present_kinds(g, W, H, margin):
            continue
        nodes = [n for n in rng.permutation(len(g.pos)) if g.node_alive[n]
                 and _in_map(g.pos[n], W, H, margin) and g.degree(n) >= 3]
        done = False
        for n in nodes:
            n = int(n)
            if kind is JunctionKind.TEE and g.degree(n) == 4:
                for e in g.adj[n]:
                    if (g.edges[e].road_class is RoadClass.STREET
                            and g.degree(g.other(e, n)) >= 3):
                        g.kill_edge(e)
                        done = True
                        break
            elif kind is JunctionKind.CORNER and g.degree(n) in (3, 4):
                arms = sorted((g.arm_angle(e, n), e) for e in g.adj[n])
                # keep two arms roughly perpendicular, remove the rest
                for k in range(len(arms)):
                    (a1, e1), (a2, e2) = arms[k], arms[(k + 1) % len(arms)]
                    gap = (a2 - a1) % (2 * math.pi)
                    rest = [e for _, e in arms if e not in (e1, e2)]
                    if (math.radians(70) <= gap <= math.radians(110)
                            and all(g.edges[e].road_class is not RoadClass.AVENUE
                                    and g.degree(g.other(e, n)) >= 3 for e in rest)):
                        for e in rest:
                            g.kill_edge(e)
                        done = True
                        break
            elif kind is JunctionKind.WYE:
                done = _corner_diagonal(g, n, rng, cfg, s_px, blocked)
            elif kind is JunctionKind.BEND:
                for e in list(g.adj[n]):
                    other = g.other(e, n)
                    if (_eligible_street(g, e, 0.6 * s_px) and _in_map(g.pos[other], W, H, margin)
                            and _bend(g, e, rng, blocked)):
                        done = True
                        break
            if done:
                break
        if not done:
            log.debug("could not add a %s junction", kind.value)


def _junctions(g: _RoadGraph, W: int, H: int) -> tuple[Junction, ...]:
    out = []
    for n in range(len(g.pos)):
        if not g.node_alive[n] or not _in_map(g.pos[n], W, H):
            continue
        kind = g.kind(n)
        if kind is not None:
            p = g.pos[n]
            out.append(Junction(u_px=round(float(p[0]), 3), v_px=round(float(p[1]), 3),
                                arms=g.degree(n), kind=kind))
    return tuple(out)


# ---------------------------------------------------------------------------------------------
# material raster: features and roads

def _draw_features(material: np.ndarray, blocked: np.ndarray, owner: np.ndarray,
                   features: list[_Feature], rings: list[_Ring | None],
                   rivers: list[tuple[np.ndarray, float]], cfg: CityConfig,
                   rng: np.random.Generator, river_margin_px: float) -> None:
    mpp = cfg.m_per_px
    clear = _RING_CLEAR_M / mpp
    for i, (f, ring) in enumerate(zip(features, rings)):
        if ring is None:
            continue
        edge = _feature_edge_px(f, mpp)
        _fill_poly(blocked, _feature_outline(f, edge + ring.off_px + clear), _Blocked.HARD)
        _fill_poly(owner, ring.poly, i + 1)
    for f in features:
        if f.kind is FeatureKind.LAKE:
            _fill_poly(material, _feature_outline(f, _SHORE_M / mpp), Material.SIDEWALK)
            _fill_poly(material, _feature_outline(f, 0.5 * _SHORE_M / mpp), Material.GRASS)
            _fill_poly(material, _feature_outline(f, 2.5 / mpp), Material.SAND)
            _fill_poly(material, _feature_outline(f, 0.0), Material.WATER)
        elif f.kind is FeatureKind.FOREST:
            _fill_poly(material, _feature_outline(f, 0.0), Material.FOREST)
        elif f.kind is FeatureKind.PARK:
            _fill_poly(material, _feature_outline(f, 0.0), Material.GRASS)
            n_clumps = int(math.pi * (f.radius_px * mpp) ** 2 / 900.0)
            for _ in range(n_clumps):
                ang = rng.uniform(0, 2 * math.pi)
                rad = f.radius_px * 0.75 * math.sqrt(rng.uniform())
                c = f.centre + rad * np.array([math.cos(ang), math.sin(ang)])
                for _ in range(int(rng.integers(1, 5))):
                    q = c + rng.normal(0.0, 4.0 / mpp, 2)
                    cv2.circle(material, tuple(int(x) for x in _cv(q)),
                               int(rng.uniform(2.5, 5.5) / mpp * _SCALE), int(Material.FOREST), -1,
                               cv2.LINE_8, _SHIFT)
        elif f.kind is FeatureKind.SQUARE:
            _fill_poly(material, _feature_outline(f, 0.0), Material.SQUARE)
    for pts, width in rivers:
        _stroke(blocked, [pts], int(_Blocked.RIVER), int(width + 2 * river_margin_px))
        _stroke(material, [pts], int(Material.GRASS), int(width + 24.0 / mpp))
        _stroke(material, [pts], int(Material.SAND), int(width + 4.0 / mpp))
        _stroke(material, [pts], int(Material.WATER), int(width))


def _fill_poly(img: np.ndarray, poly: np.ndarray, value) -> None:
    cv2.fillPoly(img, [_cv(poly)], int(value), cv2.LINE_8, _SHIFT)


@dataclass
class _Lanes:
    """All traffic lanes concatenated, for vectorised car sampling."""

    pts: np.ndarray        # (N, 2) lane polyline points
    arc: np.ndarray        # (N,) global arc length (lanes separated by gaps)
    start: np.ndarray      # (L,) global arc of each lane's first usable point
    usable: np.ndarray     # (L,) usable length of each lane
    sign: np.ndarray       # (L,) +1 along the polyline, -1 against it


def _end_clearance_px(g: _RoadGraph, e: int, n: int, mpp: float) -> float:
    """Distance from node n along edge e to where the junction area ends (0 for plain nodes)."""
    if g.degree(n) < 3 and g.kind(n) is not JunctionKind.CORNER:
        return 0.0
    widths = [g.edges[o].width_m for o in g.adj[n] if o != e]
    return (max(widths, default=0.0) / 2.0 + 1.0) / mpp


def _draw_roads(material: np.ndarray, g: _RoadGraph, cfg: CityConfig,
                rng: np.random.Generator) -> _Lanes:
    mpp = cfg.m_per_px
    edges = g.alive_edges()
    shapes = {e: g.polyline(e) for e in edges}
    width_px = {e: g.edges[e].width_m / mpp for e in edges}
    for e in edges:
        _stroke(material, [shapes[e]], int(Material.SIDEWALK),
                round(width_px[e] + 2 * cfg.sidewalk_width_m / mpp))
    for e in edges:
        _stroke(material, [shapes[e]], int(Material.KERB), round(width_px[e]) + 2)
    for e in edges:
        _stroke(material, [shapes[e]], int(Material.ROAD), round(width_px[e]))

    marks = np.zeros_like(material)
    thin = max(1, round(0.2 / mpp))
    zebra_w = max(1, round(0.8 / mpp))
    crossings = {n: rng.random() < 0.6 for n in range(len(g.pos))}
    lane_pts, lane_arc, lane_start, lane_len, lane_sign = [], [], [], [], []
    arc_offset = 0.0
    for e in edges:
        E = g.edges[e]
        w = width_px[e]
        dense = g.polyline(e, 1.0 / mpp)
        arc = _arc_lengths(dense)
        total = arc[-1]
        clear = [_end_clearance_px(g, e, E.a, mpp), _end_clearance_px(g, e, E.b, mpp)]
        zebra = [crossings[E.a] and clear[0] > 0, crossings[E.b] and clear[1] > 0]
        s0 = clear[0] + (4.0 / mpp if zebra[0] else 0.0)
        s1 = total - clear[1] - (4.0 / mpp if zebra[1] else 0.0)
        normals = _normals(dense)
        segs: list[np.ndarray] = []
        solids: list[np.ndarray] = []
        if s1 - s0 > 2.0 / mpp and E.width_m >= 7.0:
            if E.road_class is RoadClass.AVENUE:
                n_lanes = 2 if E.width_m < 19.0 else 3
                solids.append(_sub_polyline(dense, arc, s0, s1))
                for k in range(1, n_lanes):
                    for sgn in (-1.0, 1.0):
                        off = dense + normals * (sgn * k * w / (2 * n_lanes))
                        segs += _dashes(off, _arc_lengths(off), s0, s1, 3.0 / mpp, 9.0 / mpp)
                for sgn in (-1.0, 1.0):
                    off = dense + normals * (sgn * (w / 2.0 - 0.6 / mpp))
                    solids.append(_sub_polyline(off, _arc_lengths(off), s0, s1))
            else:
                segs += _dashes(dense, arc, s0, s1, 3.0 / mpp, 9.0 / mpp)
        _stroke(marks, segs, 1, thin)
        _stroke(marks, solids, 1, thin)
        for end, (cl, z) in enumerate(zip(clear, zebra)):
            if not z or total < cl + 4.0 / mpp:
                continue
            a0, a1 = (cl, cl + 3.0 / mpp) if end == 0 else (total - cl - 3.0 / mpp, total - cl)
            p0, p1 = _interp(dense, arc, [a0, a1])
            nrm = _normals(np.array([p0, p1]))[0]
            offs = np.arange(-w / 2 + 0.6 / mpp, w / 2 - 0.6 / mpp, 1.6 / mpp)
            stripes = [np.array([p0 + nrm * o, p1 + nrm * o]) for o in offs]
            _stroke(marks, stripes, 1, zebra_w)
        # traffic lanes
        n_dir = 1 if E.width_m < 10.0 else (2 if E.width_m < 18.0 else 3)
        lane_w = w / (2 * n_dir)
        c0 = clear[0] + 3.0 / mpp if clear[0] > 0 else 0.0
        c1 = total - (clear[1] + 3.0 / mpp if clear[1] > 0 else 0.0)
        if c1 - c0 < 6.0 / mpp:
            continue
        for k in range(n_dir):
            for sgn in (-1.0, 1.0):
                off = dense + normals * (sgn * (k + 0.5) * lane_w)
                oarc = _arc_lengths(off)
                scale = oarc[-1] / max(total, 1e-9)
                lane_pts.append(off)
                lane_arc.append(oarc + arc_offset)
                lane_start.append(arc_offset + c0 * scale)
                lane_len.append((c1 - c0) * scale)
                lane_sign.append(sgn)
                arc_offset += oarc[-1] + 10.0
    on_road = (marks > 0) & (material == Material.ROAD)
    material[on_road] = Material.MARKING
    if lane_pts:
        lanes = _Lanes(np.concatenate(lane_pts), np.concatenate(lane_arc), np.array(lane_start),
                       np.array(lane_len), np.array(lane_sign))
    else:
        lanes = _Lanes(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))
    return lanes


def _dashes(poly: np.ndarray, arc: np.ndarray, s0: float, s1: float, dash: float,
            period: float) -> list[np.ndarray]:
    starts = np.arange(s0, s1 - 0.5 * dash, period)
    if starts.size == 0:
        return []
    ends = np.minimum(starts + dash, s1)
    p0 = _interp(poly, arc, starts)
    p1 = _interp(poly, arc, ends)
    return list(np.stack([p0, p1], axis=1))


# ---------------------------------------------------------------------------------------------
# blocks and buildings

@dataclass
class _Building:
    corners: np.ndarray         # (4, 2) continuous px; corners[0] -> corners[1] is the long side
    height_m: float
    style: RoofStyle
    tone: tuple[float, float, float]
    hvac: np.ndarray            # (k, 4, 2) roof boxes
    hvac_height_m: float = 2.0


class _Block:
    """One connected piece of free ground between roads and features."""

    def __init__(self, mask: np.ndarray, x0: int, y0: int, setback_px: float) -> None:
        self.mask = mask
        self.x0, self.y0 = x0, y0
        padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        dist = cv2.distanceTransform(padded, cv2.DIST_L2, 3)[1:-1, 1:-1]
        self.inner = (dist > setback_px).astype(np.uint8)
        self.occ = np.zeros_like(mask)

    def try_place(self, corners: np.ndarray, max_bad: float = 0.04,
                  claim: np.ndarray | None = None) -> bool:
        """Claim a convex polygon (local coords) if it lies inside the block and is free.

        ``claim`` (a larger polygon around ``corners``) is marked occupied instead, to keep gaps.
        """
        h, w = self.mask.shape
        lo = np.floor(corners.min(axis=0)).astype(int) - 1
        hi = np.ceil(corners.max(axis=0)).astype(int) + 2
        if lo[0] < 0 or lo[1] < 0 or hi[0] > w or hi[1] > h:
            return False
        sub = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), dtype=np.uint8)
        _fill_convex(sub, corners, 1, int(lo[0]), int(lo[1]))
        area = int(np.count_nonzero(sub))
        if area < 4:
            return False
        win = (slice(lo[1], hi[1]), slice(lo[0], hi[0]))
        bad = np.count_nonzero(sub & ((1 - self.inner[win]) | self.occ[win]))
        if bad > max_bad * area:
            return False
        if claim is None:
            self.occ[win] |= sub
        else:
            _fill_convex(self.occ, claim, 1)
        return True

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float] | None:
        """Centre, long axis, short axis and extents of the minimum-area rectangle of the block."""
        cnts, _ = cv2.findContours(self.inner, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not cnts or sum(cv2.contourArea(c) for c in cnts) < 20:
            return None
        pts = np.concatenate(cnts)
        (cx, cy), (w, h), ang = cv2.minAreaRect(pts)
        box = cv2.boxPoints(((cx, cy), (w, h), ang))
        e1, e2 = box[1] - box[0], box[2] - box[1]
        l1, l2 = float(np.hypot(*e1)), float(np.hypot(*e2))
        if l1 < 1.0 or l2 < 1.0:
            return None
        a, b = e1 / l1, e2 / l2
        if l1 < l2:
            a, b, l1, l2 = b, a, l2, l1
        return np.array([cx + 0.5, cy + 0.5]), a, b, l1 + 1.0, l2 + 1.0


class _Layout:
    """Block-filling rules; buildings are kept in global continuous pixel coordinates."""

    def __init__(self, cfg: CityConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.rng = rng
        self.ppm = 1.0 / cfg.m_per_px
        self.buildings: list[_Building] = []
        self.spots: list[np.ndarray] = []   # parking stalls: (u, v, dir_u, dir_v)

    def m(self, metres: float) -> float:
        return metres * self.ppm

    def _tone(self, tones, weights) -> tuple[float, float, float]:
        base = np.array(tones[int(self.rng.choice(len(tones), p=np.array(weights) / sum(weights)))],
                        dtype=float)
        return tuple(float(x) for x in np.clip(base * self.rng.uniform(0.9, 1.1), 0, 255))

    def add(self, blk: _Block, corners: np.ndarray, style: RoofStyle, height_m: float,
            tone: tuple[float, float, float] | None = None) -> None:
        rng = self.rng
        if tone is None:
            tone = self._tone(_GABLE_TONES, _GABLE_WEIGHTS) if style in (RoofStyle.GABLE, RoofStyle.HIP) \
                else self._tone(_FLAT_TONES, _FLAT_WEIGHTS)
        glob = corners + np.array([blk.x0, blk.y0], dtype=float)
        hvac = np.zeros((0, 4, 2))
        if style is RoofStyle.FLAT:
            a = glob[1] - glob[0]
            b = glob[3] - glob[0]
            la, lb = float(np.hypot(*a)), float(np.hypot(*b))
            a, b = a / la, b / lb
            area_m2 = la * lb / self.ppm ** 2
            k = min(12, 1 + int(rng.poisson(area_m2 / 150.0)))
            boxes = []
            inset = self.m(1.5)
            for _ in range(k):
                sa, sb = self.m(rng.uniform(1.5, 4.0)), self.m(rng.uniform(1.5, 3.0))
                if la - 2 * inset - sa <= 0 or lb - 2 * inset - sb <= 0:
                    break
                ta = rng.uniform(inset, la - inset - sa)
                tb = rng.uniform(inset, lb - inset - sb)
                c = glob[0] + a * (ta + sa / 2) + b * (tb + sb / 2)
                boxes.append(_rect(c, a, b, sa, sb))
            if boxes:
                hvac = np.array(boxes)
        self.buildings.append(_Building(glob, float(height_m), style, tone, hvac,
                                        float(rng.uniform(1.2, 2.5))))

    # -- block kinds --------------------------------------------------------------------------

    def perimeter(self, blk: _Block) -> None:
        rng = self.rng
        cnts, _ = cv2.findContours(blk.inner, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        depth = self.m(rng.uniform(10.0, 16.0))
        gable_share = rng.uniform(0.2, 0.7)
        for cnt in sorted(cnts, key=lambda c: -cv2.contourArea(c)):
            if cv2.contourArea(cnt) < self.m(12.0) ** 2:
                continue
            poly = cv2.approxPolyDP(cnt, self.m(1.5), True)[:, 0, :].astype(float) + 0.5
            for i in range(len(poly)):
                p0, p1 = poly[i], poly[(i + 1) % len(poly)]
                e = p1 - p0
                length = float(np.hypot(*e))
                if length < self.m(8.0):
                    continue
                e /= length
                nrm = np.array([-e[1], e[0]])
                mid = 0.5 * (p0 + p1)
                if not _inside(blk.inner, mid + nrm * self.m(3.0)):
                    nrm = -nrm
                    if not _inside(blk.inner, mid + nrm * self.m(3.0)):
                        continue
                front = p0 + nrm * self.m(1.0)
                t = rng.uniform(0.0, self.m(2.0))
                while t < length - self.m(6.0):
                    f = min(self.m(rng.uniform(9.0, 26.0)), length - t)
                    if f < self.m(6.0):
                        break
                    c = [front + e * t, front + e * (t + f), front + e * (t + f) + nrm * depth,
                         front + e * t + nrm * depth]
                    corners = np.array(c)
                    if blk.try_place(corners):
                        style = RoofStyle.GABLE if rng.random() < gable_share else RoofStyle.FLAT
                        corners = _long_first(corners)
                        self.add(blk, corners, style, rng.uniform(12.0, 24.0))
                        t += f + (0.0 if rng.random() < 0.6 else self.m(rng.uniform(1.0, 4.0)))
                    else:
                        t += self.m(2.0)
        # big courtyards get outbuildings; very big blocks (next to features) get houses inside
        free_m2 = np.count_nonzero(blk.inner & (1 - blk.occ)) / self.ppm ** 2
        if free_m2 > 6000.0:
            self.detached(blk)
        elif free_m2 > 1500.0 and rng.random() < 0.5:
            self.detached(blk, (6.0, 12.0), (5.0, 9.0), (22.0, 26.0), RoofStyle.FLAT, (3.0, 6.0))

    def detached(self, blk: _Block, size_a=(8.0, 13.0), size_b=(7.0, 11.0), pitch=(16.0, 22.0),
                 style: RoofStyle | None = None, heights=(6.0, 10.0)) -> None:
        rng = self.rng
        fr = blk.frame()
        if fr is None:
            return
        c, a, b, la, lb = fr
        pa, pb = self.m(rng.uniform(*pitch)), self.m(rng.uniform(*pitch))
        na, nb = max(1, int(la // pa)), max(1, int(lb // pb))
        for ia in range(na):
            for ib in range(nb):
                ta = (ia - (na - 1) / 2) * pa + self.m(rng.normal(0, 0.8))
                tb = (ib - (nb - 1) / 2) * pb + self.m(rng.normal(0, 0.8))
                sa, sb = self.m(rng.uniform(*size_a)), self.m(rng.uniform(*size_b))
                corners = _rect(c + a * ta + b * tb, a, b, sa, sb)
                if blk.try_place(corners):
                    st = style if style is not None else (
                        RoofStyle.GABLE if rng.random() < 0.5 else
                        (RoofStyle.HIP if rng.random() < 0.6 else RoofStyle.FLAT))
                    self.add(blk, corners, st, rng.uniform(*heights))

    def big(self, blk: _Block, uniform_tone: tuple[float, float, float] | None = None) -> None:
        """One large building (flat roof with HVAC, or a uniform roof), houses around it."""
        rng = self.rng
        fr = blk.frame()
        if fr is None:
            return
        c, a, b, la, lb = fr
        fa, fb = rng.uniform(0.55, 0.85), rng.uniform(0.55, 0.85)
        uniform = rng.random() < 0.4 or uniform_tone is not None
        for _ in range(5):
            corners = _rect(c, a, b, la * fa, lb * fb)
            if blk.try_place(corners):
                if uniform:
                    tone = uniform_tone or self._tone(_UNIFORM_TONES, (1, 1, 1))
                    self.add(blk, corners, RoofStyle.UNIFORM, rng.uniform(8.0, 14.0), tone)
                else:
                    self.add(blk, corners, RoofStyle.FLAT, rng.uniform(10.0, 20.0))
                break
            fa *= 0.85
            fb *= 0.85
        self.detached(blk, (8.0, 14.0), (7.0, 12.0), (18.0, 24.0), None, (6.0, 12.0))

    def halls(self, blk: _Block, spec: tuple[float, float, float, tuple[float, float, float]]) -> bool:
        """Pack identical halls row by row (greedy scan in the block's rectangle frame)."""
        length, width, height, tone = spec
        fr = blk.frame()
        if fr is None:
            return False
        c, a0, b0, la0, lb0 = fr
        for a, b, la, lb in ((a0, b0, la0, lb0), (b0, a0, lb0, la0)):
            if self._pack_halls(blk, c, a, b, la, lb, length, width, height, tone):
                return True
        return False

    def _pack_halls(self, blk: _Block, c, a, b, la: float, lb: float, length: float, width: float,
                    height: float, tone: tuple[float, float, float]) -> bool:
        gap_a, gap_b = self.m(10.0), self.m(12.0)
        ha, hb = self.m(length), self.m(width)
        step = self.m(2.5)
        count = 0
        tb = -lb / 2 + hb / 2
        while tb <= lb / 2 - hb / 2 + 1e-9:
            placed = False
            ta = -la / 2 + ha / 2
            while ta <= la / 2 - ha / 2 + 1e-9:
                centre = c + a * ta + b * tb
                outer = _rect(centre, a, b, ha + gap_a, hb + gap_b)
                hall = _rect(centre, a, b, ha, hb)
                if (all(_inside(blk.inner, q) for q in hall) and not _inside(blk.occ, centre)
                        and blk.try_place(hall, max_bad=0.01, claim=outer)):
                    self.add(blk, hall, RoofStyle.UNIFORM, height, tone)
                    placed = True
                    count += 1
                    ta += ha + gap_a
                else:
                    ta += step
            tb += hb + gap_b if placed else step
        return count > 0

    def parking(self, blk: _Block, material_win: np.ndarray) -> None:
        fr = blk.frame()
        area = blk.inner.astype(bool)
        material_win[area] = Material.PARKING
        if fr is None:
            return
        c, a, b, la, lb = fr
        stall_w, stall_d, aisle = self.m(2.5), self.m(5.0), self.m(6.5)
        period = 2 * stall_d + aisle
        lines = np.zeros_like(blk.mask)
        segs = []
        n_rows = int(lb // period) + 1
        for r in range(n_rows):
            row0 = -lb / 2 + self.m(1.0) + r * period
            for side, rb in ((0, row0), (1, row0 + stall_d)):
                for k in range(int(la // stall_w) + 1):
                    ta = -la / 2 + k * stall_w
                    p = c + a * ta + b * rb
                    segs.append(np.array([p, p + b * stall_d]))
                    centre = c + a * (ta + stall_w / 2) + b * (rb + stall_d / 2)
                    corners = _rect(centre, a, b, stall_w * 0.9, stall_d * 0.9)
                    if all(_inside(blk.inner, q) for q in corners):
                        direction = b if side == 0 else -b
                        self.spots.append(np.array([centre[0] + blk.x0, centre[1] + blk.y0,
                                                    direction[0], direction[1]]))
        _stroke(lines, segs, 1, 1)
        material_win[(lines > 0) & area] = Material.PARKING_LINE


def _inside(mask: np.ndarray, p: np.ndarray) -> bool:
    u, v = int(math.floor(p[0])), int(math.floor(p[1]))
    return 0 <= v < mask.shape[0] and 0 <= u < mask.shape[1] and bool(mask[v, u])


def _long_first(corners: np.ndarray) -> np.ndarray:
    if np.hypot(*(corners[1] - corners[0])) < np.hypot(*(corners[3] - corners[0])):
        return corners[[1, 2, 3, 0]]
    return corners


def _trees(material_win: np.ndarray, region: np.ndarray, rng: np.random.Generator, ppm: float,
           per_m2: float) -> None:
    ys, xs = np.nonzero(region)
    n = int(rng.poisson(len(ys) / ppm ** 2 * per_m2))
    if n == 0 or len(ys) == 0:
        return
    canopy = np.zeros_like(region, dtype=np.uint8)
    idx = rng.integers(len(ys), size=n)
    for i in idx:
        r = rng.uniform(2.0, 4.5) * ppm
        cv2.circle(canopy, (int(xs[i]), int(ys[i])), max(1, int(r)), 1, -1)
    material_win[(canopy > 0) & region] = Material.FOREST


def _layout_blocks(material: np.ndarray, features: list[_Feature], cfg: CityConfig,
                   rng: np.random.Generator) -> _Layout:
    mpp = cfg.m_per_px
    ppm = 1.0 / mpp
    lay = _Layout(cfg, rng)
    free = (material == Material.GROUND).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(free, connectivity=4)
    del free
    area_px = stats[:, cv2.CC_STAT_AREA]
    ids = [k for k in range(1, n) if area_px[k] * mpp ** 2 >= 40.0]
    districts = [f for f in features if f.kind is FeatureKind.DISTRICT]
    hall_specs = []
    for _ in districts:
        hall_specs.append((cfg.hall_length_m * rng.uniform(0.9, 1.1),
                           cfg.hall_width_m * rng.uniform(0.9, 1.1), rng.uniform(7.0, 11.0),
                           tuple(float(x) for x in _UNIFORM_TONES[int(rng.integers(len(_UNIFORM_TONES)))])))

    # district blocks: nearest to the district centre first, until they cover ~60 % of its disc
    member: dict[int, int] = {}
    if districts and ids:
        ids_arr = np.array(ids)
        for i, f in enumerate(districts):
            dist = np.hypot(*(cents[ids_arr] + 0.5 - f.centre).T)
            want = 0.6 * math.pi * f.radius_px ** 2
            got = 0.0
            for k in ids_arr[np.argsort(dist, kind="stable")]:
                if got >= want or np.hypot(*(cents[k] + 0.5 - f.centre)) > 1.5 * f.radius_px:
                    break
                if int(k) in member or area_px[k] * mpp ** 2 < 1500.0:
                    continue
                member[int(k)] = i
                got += float(area_px[k])

    def district_of(k: int) -> int:
        return member.get(k, -1)

    kinds: dict[int, BlockKind] = {}
    budget = cfg.parking_share * cfg.area_m2
    for k in rng.permutation(ids):
        a = area_px[k] * mpp ** 2
        if 700.0 <= a <= min(12000.0, 1.5 * budget) and district_of(int(k)) < 0:
            kinds[int(k)] = BlockKind.PARKING
            budget -= 0.8 * a
    kind_list = (BlockKind.PERIMETER, BlockKind.DETACHED, BlockKind.BIG, BlockKind.PARK)
    kind_p = np.array([0.55, 0.25, 0.14, 0.06])
    setback = 1.5 * ppm
    for k in ids:
        x, y, w, h = (int(v) for v in stats[k, :4])
        a_m2 = area_px[k] * mpp ** 2
        d = district_of(k)
        if k in kinds:
            kind = kinds[k]
        elif d >= 0:
            kind = BlockKind.INDUSTRIAL
        elif a_m2 < 350.0:
            kind = BlockKind.YARD
        else:
            kind = kind_list[int(rng.choice(len(kind_list), p=kind_p))]
            if kind is BlockKind.PARK and a_m2 > 5000.0:   # big open areas are the features' job
                kind = BlockKind.PERIMETER
        mask = (labels[y:y + h, x:x + w] == k).astype(np.uint8)
        blk = _Block(mask, x, y, setback)
        win = material[y:y + h, x:x + w]
        first = len(lay.buildings)
        grass_yard = False
        tree_density = 0.0
        if kind is BlockKind.PERIMETER:
            lay.perimeter(blk)
            grass_yard = rng.random() < cfg.courtyard_grass_share
            tree_density = 1.0 / 250.0 if grass_yard else 1.0 / 900.0
        elif kind is BlockKind.DETACHED:
            lay.detached(blk)
            grass_yard = rng.random() < 0.35
            tree_density = 1.0 / 250.0
        elif kind is BlockKind.BIG:
            lay.big(blk)
            tree_density = 1.0 / 1500.0
        elif kind is BlockKind.INDUSTRIAL:
            if not lay.halls(blk, hall_specs[d]):
                lay.big(blk, uniform_tone=hall_specs[d][3])
        elif kind is BlockKind.PARKING:
            lay.parking(blk, win)
        elif kind is BlockKind.PARK:
            grass_yard = True
            tree_density = 1.0 / 120.0
        else:
            grass_yard = rng.random() < 0.5
        block_px = mask.astype(bool)
        yard = block_px & (win == Material.GROUND)
        if grass_yard:
            win[yard] = Material.GRASS
        if tree_density > 0:
            _trees(win, yard & (blk.occ == 0), rng, ppm, tree_density)
        for bld in lay.buildings[first:]:
            mat = Material.ROOF_UNIFORM if bld.style is RoofStyle.UNIFORM else Material.ROOF_TEXTURED
            _fill_convex(material, bld.corners, int(mat))
    return lay


# ---------------------------------------------------------------------------------------------
# scene

@dataclass
class _Scene:
    cfg: CityConfig
    material: np.ndarray
    junctions: tuple[Junction, ...]
    buildings: list[_Building]
    bld_bbox: np.ndarray           # (n, 4) u0, v0, u1, v1
    lanes: _Lanes
    spots: np.ndarray              # (n, 4) u, v, dir_u, dir_v
    features: list[_Feature]
    fine: NoiseField
    medium: SmoothNoise
    coarse: SmoothNoise


def build_scene(cfg: CityConfig) -> _Scene:
    """Layout and material raster of a city (no rendering)."""
    W, H, mpp = cfg.width_px, cfg.height_px, cfg.m_per_px
    t0 = time.perf_counter()
    frng = _rng(cfg, Stream.FEATURES)
    angle = math.radians(frng.uniform(-cfg.grid_rotation_max_deg, cfg.grid_rotation_max_deg))
    river_margin = (cfg.avenue_width_max_m / 2.0 + cfg.sidewalk_width_m + 2.0) / mpp
    features = _place_features(cfg, frng, angle)
    rings = _make_rings(features, cfg, frng)
    rivers = _river_polylines(cfg, frng)
    material = np.full((H, W), int(Material.GROUND), dtype=np.uint8)
    blocked = np.zeros((H, W), dtype=np.uint8)
    owner = np.zeros((H, W), dtype=np.uint16)
    _draw_features(material, blocked, owner, features, rings, rivers, cfg, frng, river_margin)
    grng = _rng(cfg, Stream.GRAPH)
    graph = _build_graph(cfg, grng, angle, blocked, owner, rings)
    del blocked, owner
    junctions = _junctions(graph, W, H)
    t1 = time.perf_counter()
    lanes = _draw_roads(material, graph, cfg, grng)
    t2 = time.perf_counter()
    lay = _layout_blocks(material, features, cfg, _rng(cfg, Stream.BLOCKS))
    t3 = time.perf_counter()
    if lay.buildings:
        corners = np.array([b.corners for b in lay.buildings])
        bbox = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1)
    else:
        bbox = np.zeros((0, 4))
    spots = np.array(lay.spots) if lay.spots else np.zeros((0, 4))
    log.debug("layout %.2fs, roads %.2fs, blocks %.2fs: %d junctions, %d buildings, %d stalls",
              t1 - t0, t2 - t1, t3 - t2, len(junctions), len(lay.buildings), len(spots))
    return _Scene(cfg=cfg, material=material, junctions=junctions, buildings=lay.buildings,
                  bld_bbox=bbox, lanes=lanes, spots=spots, features=features,
                  fine=NoiseField((cfg.seed, GENERATOR_VERSION, Stream.TEX_FINE), W),
                  medium=SmoothNoise((cfg.seed, GENERATOR_VERSION, Stream.TEX_MEDIUM), W, 3.0 / mpp),
                  coarse=SmoothNoise((cfg.seed, GENERATOR_VERSION, Stream.TEX_COARSE), W, 25.0 / mpp))


# ---------------------------------------------------------------------------------------------
# rendering

@dataclass
class _Cars:
    corners: np.ndarray     # (n, 4, 2), corners[0] -> corners[1] along the car, [1] at the front
    colour: np.ndarray      # (n, 3)
    centre_v: np.ndarray    # (n,)


def _cars_for_day(sc: _Scene, day: DayConditions) -> _Cars:
    cfg = sc.cfg
    mpp = cfg.m_per_px
    rng = _rng(cfg, Stream.TRAFFIC, day.traffic_seed)
    lanes = sc.lanes
    pos_list, dir_list = [], []
    total = float(lanes.usable.sum()) if lanes.usable.size else 0.0
    if total > 0 and cfg.cars_per_100m_lane > 0:
        n = int(rng.poisson(total * mpp / 100.0 * cfg.cars_per_100m_lane))
        g = np.sort(rng.uniform(0.0, total, n))
        cum = np.concatenate([[0.0], np.cumsum(lanes.usable)])
        lane = np.clip(np.searchsorted(cum, g, side="right") - 1, 0, len(lanes.usable) - 1)
        keep = np.ones(n, dtype=bool)
        if n > 1:
            close = (np.diff(g) < 7.0 / mpp) & (lane[1:] == lane[:-1])
            keep[1:] &= ~close
        g, lane = g[keep], lane[keep]
        arc = lanes.start[lane] + (g - cum[lane])
        j = np.clip(np.searchsorted(lanes.arc, arc, side="right") - 1, 0, len(lanes.arc) - 2)
        seg = lanes.pts[j + 1] - lanes.pts[j]
        seg_len = np.maximum(np.hypot(seg[:, 0], seg[:, 1]), 1e-9)
        frac = np.clip((arc - lanes.arc[j]) / seg_len, 0.0, 1.0)
        pos_list.append(lanes.pts[j] + seg * frac[:, None])
        dir_list.append(seg / seg_len[:, None] * lanes.sign[lane][:, None])
    if len(sc.spots):
        occupied = rng.random(len(sc.spots)) < cfg.parking_occupancy
        sp = sc.spots[occupied]
        flip = np.where(rng.random(len(sp)) < 0.5, 1.0, -1.0)[:, None]
        pos_list.append(sp[:, :2])
        dir_list.append(sp[:, 2:] * flip)
    if not pos_list:
        return _Cars(np.zeros((0, 4, 2)), np.zeros((0, 3)), np.zeros(0))
    pos = np.concatenate(pos_list)
    direc = np.concatenate(dir_list)
    m = len(pos)
    length = rng.uniform(4.0, 5.0, m) / mpp
    width = rng.uniform(1.7, 1.95, m) / mpp
    side = np.stack([-direc[:, 1], direc[:, 0]], axis=1)
    hl = (direc * (length / 2)[:, None])
    hw = (side * (width / 2)[:, None])
    corners = np.stack([pos - hl - hw, pos + hl - hw, pos + hl + hw, pos - hl + hw], axis=1)
    probs = np.array(_CAR_WEIGHTS) / sum(_CAR_WEIGHTS)
    colour = np.array(_CAR_COLOURS, dtype=np.float32)[rng.choice(len(_CAR_COLOURS), size=m, p=probs)]
    colour *= rng.uniform(0.9, 1.1, (m, 1)).astype(np.float32)
    return _Cars(corners, colour, pos[:, 1])


def _facets(b: _Building) -> list[tuple[np.ndarray, np.ndarray]]:
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


def _paint_roofs(canvas: np.ndarray, sc: _Scene, idx: np.ndarray, sun: np.ndarray, top: int) -> None:
    for i in idx:
        b = sc.buildings[i]
        tone = b.tone
        _fill_convex(canvas, b.corners, tone, 0, top)
        if b.style in (RoofStyle.GABLE, RoofStyle.HIP):
            for poly, nrm in _facets(b):
                f = 1.0 + 0.22 * float(nrm @ sun)
                _fill_convex(canvas, poly, tuple(min(255.0, c * f) for c in tone), 0, top)
            if b.style is RoofStyle.GABLE:
                p0, p1, p2, p3 = b.corners
                ridge = np.array([0.5 * (p0 + p3), 0.5 * (p1 + p2)])
                _stroke(canvas, [ridge], tuple(min(255.0, c * 1.12) for c in tone), 1, 0, top)
        elif b.style is RoofStyle.FLAT:
            cv2.polylines(canvas, [_cv(b.corners, 0, top)], True,
                          tuple(min(255.0, c * 1.15) for c in tone), 1, cv2.LINE_8, _SHIFT)


class _StripFields:
    """Rows [a, b) of the day's natural noise fields, drawn once per strip on first use."""

    def __init__(self, fields: dict, a: int, b: int) -> None:
        self._fields, self._a, self._b = fields, a, b
        self._cache: dict[str, np.ndarray] = {}

    def __getitem__(self, key: str) -> np.ndarray:
        if key not in self._cache:
            self._cache[key] = self._fields[key].rows(self._a, self._b)
        return self._cache[key]


def _paint_nature(canvas: np.ndarray, mat: np.ndarray, a: int, b: int, sc: _Scene,
                  day: DayConditions, nat: dict) -> None:
    """Grass, forest canopy and water ripples from the day's own random stream."""
    mpp = sc.cfg.m_per_px
    f = _StripFields(nat, a, b)
    grass = mat == Material.GRASS
    if grass.any():
        base = _GRASS_LUSH + (_GRASS_DRY - _GRASS_LUSH) * day.grass_dryness
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
        h = cv2.GaussianBlur(f["canopy"][y0:y1, x0:x1], (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        h *= 2.0 * sigma * math.sqrt(math.pi)
        gx = cv2.Sobel(h, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(h, cv2.CV_32F, 0, 1, ksize=3)
        sun = day.sun_vector_px()
        shade = gx * float(-sun[0] * sigma / 8.0) + gy * float(-sun[1] * sigma / 8.0)
        sub = forest[y0:y1, x0:x1]
        hf, sf = h[sub], shade[sub]
        lum = 1.0 + 0.16 * hf + 0.35 * sf + 0.10 * f["coarse"][y0:y1, x0:x1][sub]
        lum = np.where(hf < -1.3, lum * 0.55, lum)
        col = _FOREST_BASE[None, :] * lum[:, None]
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
        col = _WATER_BASE[None, :] * (1.0 + 0.07 * f["coarse"][water])[:, None]
        col += (rip * 5.0 + np.maximum(rip - 1.2, 0.0) * 60.0)[:, None]
        col += f["fine"][water][:, None] * 2.0
        canvas[water] = col


def _paint_cars(canvas: np.ndarray, cars: _Cars, idx: np.ndarray, top: int) -> None:
    for i in idx:
        c = cars.corners[i]
        col = cars.colour[i]
        _fill_convex(canvas, c, tuple(float(x) for x in col), 0, top)
        front = c[1] - c[0]
        shield = np.array([c[0] + front * 0.58, c[0] + front * 0.75, c[3] + front * 0.75,
                           c[3] + front * 0.58])
        _fill_convex(canvas, shield, tuple(float(x) * 0.3 + 10 for x in col), 0, top)


def _shadow_mask(sc: _Scene, day: DayConditions, cars: _Cars, b_idx: np.ndarray, c_idx: np.ndarray,
                 top: int, shape: tuple[int, int]) -> np.ndarray:
    mpp = sc.cfg.m_per_px
    m = np.zeros(shape, dtype=np.uint8)
    d1 = day.shadow_offset_px(1.0, mpp)
    for i in b_idx:
        bld = sc.buildings[i]
        pts = np.vstack([bld.corners, bld.corners + d1 * bld.height_m])
        cv2.fillConvexPoly(m, cv2.convexHull(_cv(pts, 0, top)), 1, cv2.LINE_8, _SHIFT)
    dc = d1 * _CAR_HEIGHT_M
    for i in c_idx:
        pts = np.vstack([cars.corners[i], cars.corners[i] + dc])
        cv2.fillConvexPoly(m, cv2.convexHull(_cv(pts, 0, top)), 1, cv2.LINE_8, _SHIFT)
    for i in b_idx:
        _fill_convex(m, sc.buildings[i].corners, 0, 0, top)
    for i in c_idx:
        _fill_convex(m, cars.corners[i], 0, 0, top)
    for i in b_idx:
        bld = sc.buildings[i]
        for box in bld.hvac:
            pts = np.vstack([box, box + d1 * bld.hvac_height_m])
            cv2.fillConvexPoly(m, cv2.convexHull(_cv(pts, 0, top)), 1, cv2.LINE_8, _SHIFT)
    out = m.astype(np.float32)
    return cv2.GaussianBlur(out, (0, 0), 0.8)


def _render_strip(sc: _Scene, day: DayConditions, cars: _Cars, nat: dict, sensor: NoiseField,
                  r0: int, r1: int) -> np.ndarray:
    cfg = sc.cfg
    H, W = sc.material.shape
    a, b = max(0, r0 - STRIP_MARGIN), min(H, r1 + STRIP_MARGIN)
    mat = sc.material[a:b]
    canvas = _BASE_RGB[mat]
    sun = day.sun_vector_px()
    bb = sc.bld_bbox
    in_rows = np.nonzero((bb[:, 3] >= a - 2) & (bb[:, 1] < b + 2))[0] if len(bb) else np.zeros(0, int)
    _paint_roofs(canvas, sc, in_rows, sun, a)
    tex = _AMP_FINE[mat] * sc.fine.rows(a, b)
    tex += _AMP_MED[mat] * sc.medium.rows(a, b)
    tex += _AMP_COARSE[mat] * sc.coarse.rows(a, b)
    canvas += tex[:, :, None]
    del tex
    _paint_nature(canvas, mat, a, b, sc, day, nat)
    car_idx = np.nonzero((cars.centre_v >= a - 8) & (cars.centre_v < b + 8))[0]
    _paint_cars(canvas, cars, car_idx, a)
    reach = float(np.hypot(*day.shadow_offset_px(_MAX_BUILDING_HEIGHT_M, cfg.m_per_px))) + 2
    sh_idx = np.nonzero((bb[:, 3] >= a - reach) & (bb[:, 1] < b + reach))[0] if len(bb) \
        else np.zeros(0, int)
    shadow = _shadow_mask(sc, day, cars, sh_idx, car_idx, a, mat.shape)
    tint = np.array([1.0, 0.97, 0.86], dtype=np.float32) * day.shadow_strength
    canvas *= 1.0 - shadow[:, :, None] * tint
    del shadow
    for i in in_rows:
        for box in sc.buildings[i].hvac:
            _fill_convex(canvas, box, (214.0, 214.0, 210.0), 0, a)
    return finish_strip(canvas, r0 - a, r1 - r0, r0, day, sensor)


def render(sc: _Scene, day: DayConditions) -> np.ndarray:
    """Render the scene as captured on ``day``: (H, W, 3) uint8 RGB."""
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
    cars = _cars_for_day(sc, day)
    out = np.empty((H, W, 3), dtype=np.uint8)
    for r0 in range(0, H, STRIP_ROWS):
        r1 = min(H, r0 + STRIP_ROWS)
        out[r0:r1] = _render_strip(sc, day, cars, nat, sensor, r0, r1)
    return out


def generate_world(cfg: CityConfig, name: str | None = None) -> World:
    """Generate a city world; the same ``cfg`` always gives identical arrays."""
    t0 = time.perf_counter()
    sc = build_scene(cfg)
    t1 = time.perf_counter()
    drng = _rng(cfg, Stream.DAYS)
    capture = capture_day(drng)
    ref_day = other_day(drng, capture)
    ortho = render(sc, capture)
    reference = render(sc, ref_day)
    t2 = time.perf_counter()
    landcover = MATERIAL_TO_COVER[sc.material]
    gen = dataclasses.asdict(cfg)
    gen["generator_version"] = GENERATOR_VERSION
    gen["features"] = [{"kind": f.kind.value, "u_px": round(float(f.centre[0]), 1),
                        "v_px": round(float(f.centre[1]), 1),
                        "radius_m": round(f.radius_px * cfg.m_per_px, 1)} for f in sc.features]
    manifest = WorldManifest(
        format_version=FORMAT_VERSION,
        name=name or f"city-seed{cfg.seed}-{cfg.width_px}x{cfg.height_px}",
        width_px=cfg.width_px, height_px=cfg.height_px, m_per_px=cfg.m_per_px,
        origin_lat_deg=cfg.origin_lat_deg, origin_lon_deg=cfg.origin_lon_deg,
        source=WorldSource.GENERATED.value, seed=cfg.seed, has_landcover=True, has_junctions=True,
        missing_ground_truth=(), conventions=CONVENTIONS, generator=gen)
    log.info("generated %s: layout %.1fs, rendering %.1fs, %d junctions, %d buildings",
             manifest.name, t1 - t0, t2 - t1, len(sc.junctions), len(sc.buildings))
    return World(manifest=manifest, orthophoto=ortho, reference=reference, landcover=landcover,
                 junctions=sc.junctions)
