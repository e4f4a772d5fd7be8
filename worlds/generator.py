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

The stages live in their own modules (this one only puts them together):

* ``worlds/city_config.py``: :class:`CityConfig` and the independent random streams;
* ``worlds/features.py``: open features (lakes, forests, parks, squares, districts, rivers);
* ``worlds/road_graph.py``: the street graph and the junction ground truth;
* ``worlds/roads.py``: roads, markings and traffic lanes in the material raster;
* ``worlds/blocks.py``: blocks and buildings;
* ``worlds/materials.py``: the material classes, their land-cover classes and their palette;
* ``worlds/drawing.py``: drawing and polyline helpers in continuous pixel coordinates;
* ``worlds/scene.py``: the layout stages in order (:func:`build_scene`);
* ``worlds/traffic.py``: the cars of one day;
* ``worlds/rendering.py``: rendering one day (:func:`render`); ``worlds/reference.py``: the days
  and the photometric pipeline.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from scenenav.core.formats.world_manifest import (
    CONVENTIONS,
    FORMAT_VERSION,
    ReferenceInfo,
    ReferenceKind,
    WorldManifest,
    WorldSource,
)
from worlds.changes import day_scenes, plan_changes
from worlds.city_config import GENERATOR_SOURCES, GENERATOR_VERSION, CityConfig, Stream, stream_rng
from worlds.materials import MATERIAL_TO_COVER, Material
from worlds.perspective import perspective_reference
from worlds.reference import Season, capture_day, other_day, tone_map
from worlds.registration import draw_misregistration, misregister
from worlds.rendering import render
from worlds.scene import build_scene
from worlds.surface import surface_model
from worlds.world import World

log = logging.getLogger(__name__)

__all__ = ["GENERATOR_SOURCES", "GENERATOR_VERSION", "CityConfig", "build_scene", "generate_world", "render"]

def generate_world(cfg: CityConfig, name: str | None = None) -> World:
    """Generate a city world; the same ``cfg`` always gives identical arrays."""
    t0 = time.perf_counter()
    base = build_scene(cfg)
    changes = plan_changes(base, cfg, stream_rng(cfg, Stream.CHANGES))
    sc, ref_sc = day_scenes(base, changes)
    dsm, facade = surface_model(sc)
    ref_dsm, ref_facade = surface_model(ref_sc)
    t1 = time.perf_counter()
    drng = stream_rng(cfg, Stream.DAYS)
    capture = capture_day(drng)
    ref_day = other_day(drng, capture, Season(cfg.season))
    ortho = render(sc, capture, dsm)
    reference = render(ref_sc, ref_day, ref_dsm)
    t2 = time.perf_counter()
    # the walls of the other day get its tone curve and colour balance like everything else
    ref_walls = ref_facade          # in place, in strips (8000 x 8000 px: no full-size float copy)
    for r0 in range(0, ref_walls.shape[0], 512):
        rows = ref_walls[r0:r0 + 512]
        none = rows.max(axis=2) == 0
        rows[:] = np.clip(tone_map(rows.astype(np.float32), ref_day) + 0.5, 0, 255).astype(np.uint8)
        rows[none] = 0
    del ref_facade
    persp = perspective_reference(reference, ref_dsm, ref_walls, cfg.m_per_px, cfg.reference_height_m,
                                  canopy=ref_sc.material == Material.FOREST)
    del ref_sc
    del ref_dsm, ref_walls
    shift_e, shift_n, warp = draw_misregistration(cfg, stream_rng(cfg, Stream.REGISTRATION))
    info = ReferenceInfo(kind=ReferenceKind(cfg.reference_kind), camera_height_m=cfg.reference_height_m,
                         shift_east_m=shift_e, shift_north_m=shift_n, warp=warp, season=cfg.season,
                         changed_buildings=changes.count)
    reference = misregister(reference, info, cfg.m_per_px)
    persp = misregister(persp, info, cfg.m_per_px)
    t3 = time.perf_counter()
    landcover = MATERIAL_TO_COVER[sc.material]
    gen = dataclasses.asdict(cfg)
    gen["generator_version"] = GENERATOR_VERSION
    gen["features"] = [{"kind": f.kind.value, "u_px": round(float(f.centre[0]), 1),
                        "v_px": round(float(f.centre[1]), 1),
                        "radius_m": round(f.radius_px * cfg.m_per_px, 1)} for f in sc.features]
    gen["changes"] = {"reroofed": len(changes.reroofed), "added": len(changes.added),
                      "demolished": len(changes.demolished)}
    manifest = WorldManifest(
        format_version=FORMAT_VERSION,
        name=name or f"city-seed{cfg.seed}-{cfg.width_px}x{cfg.height_px}",
        width_px=cfg.width_px, height_px=cfg.height_px, m_per_px=cfg.m_per_px,
        origin_lat_deg=cfg.origin_lat_deg, origin_lon_deg=cfg.origin_lon_deg,
        source=WorldSource.GENERATED.value, seed=cfg.seed, has_landcover=True, has_junctions=True,
        missing_ground_truth=(), conventions=CONVENTIONS, generator=gen, has_dsm=True, reference=info)
    log.info("generated %s: layout and surface %.1fs, rendering %.1fs, perspective reference and "
             "misregistration %.1fs, %d junctions, %d buildings (%d changed), %d trees",
             manifest.name, t1 - t0, t2 - t1, t3 - t2, len(sc.junctions), len(sc.buildings),
             changes.count, len(sc.crowns))
    return World(manifest=manifest, orthophoto=ortho, reference=reference, landcover=landcover,
                 junctions=sc.junctions, dsm_m=dsm, facade_rgb=facade, reference_perspective=persp)
