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

from scenenav.core.formats.world_manifest import CONVENTIONS, FORMAT_VERSION, WorldManifest, WorldSource
from worlds.city_config import GENERATOR_VERSION, CityConfig, Stream, stream_rng
from worlds.materials import MATERIAL_TO_COVER
from worlds.reference import capture_day, other_day
from worlds.rendering import render
from worlds.scene import build_scene
from worlds.world import World

log = logging.getLogger(__name__)

__all__ = ["GENERATOR_SOURCES", "GENERATOR_VERSION", "CityConfig", "build_scene", "generate_world", "render"]

#: The source files (in ``worlds/``) whose code decides the generated arrays; ``worlds/default.py``
#: hashes them (sorted) to name the cache folders, so a change to any of them regenerates the worlds.
GENERATOR_SOURCES = ("blocks.py", "city_config.py", "drawing.py", "features.py", "generator.py",
                     "landcover.py", "materials.py", "reference.py", "rendering.py", "road_graph.py",
                     "roads.py", "scene.py", "traffic.py", "world.py")


def generate_world(cfg: CityConfig, name: str | None = None) -> World:
    """Generate a city world; the same ``cfg`` always gives identical arrays."""
    t0 = time.perf_counter()
    sc = build_scene(cfg)
    t1 = time.perf_counter()
    drng = stream_rng(cfg, Stream.DAYS)
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
