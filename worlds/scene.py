"""The scene of a city: layout and material raster, everything the two renderings share.

:func:`build_scene` runs the layout stages in their fixed order (features, street graph, roads,
blocks), each from its own random stream.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np

from worlds.blocks import Building, layout_blocks
from worlds.city_config import GENERATOR_VERSION, CityConfig, Stream, stream_rng
from worlds.features import Feature, draw_features, make_rings, place_features, river_polylines
from worlds.landcover import Junction
from worlds.materials import Material
from worlds.reference import NoiseField, SmoothNoise
from worlds.road_graph import build_graph, graph_junctions
from worlds.roads import Lanes, draw_roads
from worlds.surface import finish_buildings, tree_crowns

log = logging.getLogger(__name__)


@dataclass
class Scene:
    """Layout and material raster of one city, plus its structural noise fields (shared by both days)."""

    cfg: CityConfig
    material: np.ndarray
    junctions: tuple[Junction, ...]
    buildings: list[Building]
    bld_bbox: np.ndarray           # (n, 4) u0, v0, u1, v1
    lanes: Lanes
    spots: np.ndarray              # (n, 4) u, v, dir_u, dir_v
    features: list[Feature]
    crowns: np.ndarray             # (n, 4) tree crowns: u, v, radius px, height m
    fine: NoiseField
    medium: SmoothNoise
    coarse: SmoothNoise


def build_scene(cfg: CityConfig) -> Scene:
    """Layout and material raster of a city (no rendering)."""
    W, H, mpp = cfg.width_px, cfg.height_px, cfg.m_per_px
    t0 = time.perf_counter()
    frng = stream_rng(cfg, Stream.FEATURES)
    angle = math.radians(frng.uniform(-cfg.grid_rotation_max_deg, cfg.grid_rotation_max_deg))
    river_margin = (cfg.avenue_width_max_m / 2.0 + cfg.sidewalk_width_m + 2.0) / mpp
    features = place_features(cfg, frng, angle)
    rings = make_rings(features, cfg, frng)
    rivers = river_polylines(cfg, frng)
    material = np.full((H, W), int(Material.GROUND), dtype=np.uint8)
    blocked = np.zeros((H, W), dtype=np.uint8)
    owner = np.zeros((H, W), dtype=np.uint16)
    crowns: list[tuple[float, float, float]] = []
    draw_features(material, blocked, owner, features, rings, rivers, cfg, frng, river_margin, crowns)
    grng = stream_rng(cfg, Stream.GRAPH)
    graph = build_graph(cfg, grng, angle, blocked, owner, rings)
    del blocked, owner
    junctions = graph_junctions(graph, W, H)
    t1 = time.perf_counter()
    lanes = draw_roads(material, graph, cfg, grng)
    t2 = time.perf_counter()
    lay = layout_blocks(material, features, cfg, stream_rng(cfg, Stream.BLOCKS))
    t3 = time.perf_counter()
    finish_buildings(lay.buildings, cfg, stream_rng(cfg, Stream.HEIGHTS))
    tree_rows = tree_crowns(crowns + lay.crowns, features, material, cfg, stream_rng(cfg, Stream.TREES))
    if lay.buildings:
        corners = np.array([b.corners for b in lay.buildings])
        bbox = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1)
    else:
        bbox = np.zeros((0, 4))
    spots = np.array(lay.spots) if lay.spots else np.zeros((0, 4))
    log.debug("layout %.2fs, roads %.2fs, blocks %.2fs: %d junctions, %d buildings, %d stalls",
              t1 - t0, t2 - t1, t3 - t2, len(junctions), len(lay.buildings), len(spots))
    return Scene(cfg=cfg, material=material, junctions=junctions, buildings=lay.buildings,
                  bld_bbox=bbox, lanes=lanes, spots=spots, features=features,
                  crowns=tree_rows,
                  fine=NoiseField((cfg.seed, GENERATOR_VERSION, Stream.TEX_FINE), W),
                  medium=SmoothNoise((cfg.seed, GENERATOR_VERSION, Stream.TEX_MEDIUM), W, 3.0 / mpp),
                  coarse=SmoothNoise((cfg.seed, GENERATOR_VERSION, Stream.TEX_COARSE), W, 25.0 / mpp))
