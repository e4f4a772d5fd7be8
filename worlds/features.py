"""Large open features: lakes, forests, parks, squares, uniform-roof districts and rivers.

They are placed first (:func:`place_features`, spread out and away from the map centre), each gets
a ring road around it (:func:`make_rings`), big maps get rivers (:func:`river_polylines`), and
:func:`draw_features` draws them into the material raster, the road-blocking raster and the
ring-owner raster the road graph is cut against.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import Enum, IntEnum

import cv2
import numpy as np

from worlds.city_config import CityConfig
from worlds.drawing import (
    SCALE,
    SHIFT,
    arc_lengths,
    blob_polygon,
    blob_radii,
    cv_points,
    fill_poly,
    interp_polyline,
    rect,
    stroke,
)
from worlds.materials import Material

log = logging.getLogger(__name__)


class FeatureKind(str, Enum):
    """Kinds of open feature (the value names them in the world manifest)."""

    LAKE = "lake"
    FOREST = "forest"
    PARK = "park"
    SQUARE = "square"
    DISTRICT = "uniform_district"


class Blocked(IntEnum):
    """Codes of the road-blocking raster."""

    FREE = 0
    HARD = 1    # no roads at all (lake, forest, park, square)
    RIVER = 2   # roads may cross (bridges) but no nodes


@dataclass
class Feature:
    """One placed open feature: kind, centre and size in continuous px, blob shape or square sides."""

    kind: FeatureKind
    centre: np.ndarray
    radius_px: float          # core radius (water / canopy / grass / district / square half-diagonal)
    rel: np.ndarray | None = None      # blob shape
    half_sizes_px: tuple[float, float] = (0.0, 0.0)  # squares
    angle_rad: float = 0.0


def _feature_count(share: float, diameter_m: float, cfg: CityConfig, square: bool = False) -> int:
    area = diameter_m ** 2 if square else math.pi * (diameter_m / 2.0) ** 2
    return int(math.floor(share * cfg.area_m2 / area + 0.5))


def place_features(cfg: CityConfig, rng: np.random.Generator, grid_angle: float) -> list[Feature]:
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
    placed: list[Feature] = []
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
        feat = Feature(kind=kind, centre=c, radius_px=rc)
        if kind in (FeatureKind.LAKE, FeatureKind.PARK):
            feat.rel = blob_radii(rng, 96, 0.25, 0.88)
        elif kind is FeatureKind.FOREST:
            feat.rel = blob_radii(rng, 128, 0.35, 0.88)
        elif kind is FeatureKind.SQUARE:
            aspect = rng.uniform(0.75, 1.0)
            half = rc / math.sqrt(1.0 + aspect ** 2)
            feat.half_sizes_px = (half, half * aspect)
            feat.angle_rad = grid_angle
        placed.append(feat)
        centres = np.vstack([centres, c])
        radii = np.append(radii, rp)
    return placed


def _square_polygon(f: Feature, extra_px: float = 0.0) -> np.ndarray:
    ca, sa = math.cos(f.angle_rad), math.sin(f.angle_rad)
    ax, bx = np.array([ca, sa]), np.array([-sa, ca])
    hx, hy = f.half_sizes_px
    return rect(f.centre, ax, bx, 2 * (hx + extra_px), 2 * (hy + extra_px))


@dataclass
class Ring:
    """Ring road around a feature: closed polygon of vertices in angular order."""

    centre: np.ndarray
    poly: np.ndarray
    width_m: float
    off_px: float      # distance of the ring centreline outside the feature's edge


_SHORE_M = 10.0          # promenade and lawn around lakes
_RING_CLEAR_M = 30.0     # grid roads keep this far outside a ring (room for a row of buildings)


def _feature_outline(f: Feature, extra_px: float) -> np.ndarray:
    if f.kind is FeatureKind.SQUARE:
        return _square_polygon(f, extra_px)
    assert f.rel is not None, "a blob feature has its shape"
    return blob_polygon(f.centre, f.radius_px, f.rel, extra_px)


def _feature_edge_px(f: Feature, mpp: float) -> float:
    """Extra radius of the drawn feature beyond its core shape (the lake shore)."""
    return _SHORE_M / mpp if f.kind is FeatureKind.LAKE else 0.0


def make_rings(features: list[Feature], cfg: CityConfig,
                rng: np.random.Generator) -> list[Ring | None]:
    mpp = cfg.m_per_px
    spacing = 12.0 / mpp
    rings: list[Ring | None] = []
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
            arc = arc_lengths(closed)
            k = max(48, int(arc[-1] / spacing))
            poly = interp_polyline(closed, arc, np.linspace(0.0, arc[-1], k, endpoint=False))
        rings.append(Ring(centre=f.centre, poly=poly, width_m=w, off_px=off))
    return rings


def river_polylines(cfg: CityConfig, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
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


def draw_features(material: np.ndarray, blocked: np.ndarray, owner: np.ndarray,
                   features: list[Feature], rings: list[Ring | None],
                   rivers: list[tuple[np.ndarray, float]], cfg: CityConfig,
                   rng: np.random.Generator, river_margin_px: float,
                   crowns: list[tuple[float, float, float]]) -> None:
    """Draw the features; the tree clumps of parks append their crowns (u, v, radius px) to ``crowns``."""
    mpp = cfg.m_per_px
    clear = _RING_CLEAR_M / mpp
    for i, (f, ring) in enumerate(zip(features, rings, strict=True)):
        if ring is None:
            continue
        edge = _feature_edge_px(f, mpp)
        fill_poly(blocked, _feature_outline(f, edge + ring.off_px + clear), Blocked.HARD)
        fill_poly(owner, ring.poly, i + 1)
    for f in features:
        if f.kind is FeatureKind.LAKE:
            fill_poly(material, _feature_outline(f, _SHORE_M / mpp), Material.SIDEWALK)
            fill_poly(material, _feature_outline(f, 0.5 * _SHORE_M / mpp), Material.GRASS)
            fill_poly(material, _feature_outline(f, 2.5 / mpp), Material.SAND)
            fill_poly(material, _feature_outline(f, 0.0), Material.WATER)
        elif f.kind is FeatureKind.FOREST:
            fill_poly(material, _feature_outline(f, 0.0), Material.FOREST)
        elif f.kind is FeatureKind.PARK:
            fill_poly(material, _feature_outline(f, 0.0), Material.GRASS)
            n_clumps = int(math.pi * (f.radius_px * mpp) ** 2 / 900.0)
            for _ in range(n_clumps):
                ang = rng.uniform(0, 2 * math.pi)
                rad = f.radius_px * 0.75 * math.sqrt(rng.uniform())
                c = f.centre + rad * np.array([math.cos(ang), math.sin(ang)])
                for _ in range(int(rng.integers(1, 5))):
                    q = c + rng.normal(0.0, 4.0 / mpp, 2)
                    rad = int(rng.uniform(2.5, 5.5) / mpp * SCALE)
                    cv2.circle(material, tuple(int(x) for x in cv_points(q)), rad,
                               int(Material.FOREST), -1, cv2.LINE_8, SHIFT)
                    crowns.append((float(q[0]), float(q[1]), rad / SCALE + 0.5))
        elif f.kind is FeatureKind.SQUARE:
            fill_poly(material, _feature_outline(f, 0.0), Material.SQUARE)
    for pts, width in rivers:
        stroke(blocked, [pts], int(Blocked.RIVER), int(width + 2 * river_margin_px))
        stroke(material, [pts], int(Material.GRASS), int(width + 24.0 / mpp))
        stroke(material, [pts], int(Material.SAND), int(width + 4.0 / mpp))
        stroke(material, [pts], int(Material.WATER), int(width))
