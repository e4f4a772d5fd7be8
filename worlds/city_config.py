"""The parameters of a generated city (:class:`CityConfig`) and its independent random streams.

Every stage of the generator draws from its own numpy Generator, seeded from
``[seed, GENERATOR_VERSION, stream, ...]`` (:func:`stream_rng`), so adding draws to one stage never
changes what another stage draws.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from scenenav.core.config import check

#: Bump when the output of the generator changes for the same config (invalidates caches).
GENERATOR_VERSION = 2
#: The source files (in ``worlds/``) whose code decides the generated arrays; ``worlds/default.py``
#: hashes them (sorted) to name the cache folders, so a change to any of them regenerates the worlds.
GENERATOR_SOURCES = ("blocks.py", "changes.py", "city_config.py", "drawing.py", "features.py",
                     "generator.py", "landcover.py", "materials.py", "perspective.py", "raycast.py",
                     "reference.py", "registration.py", "rendering.py", "road_graph.py", "roads.py",
                     "scene.py", "shadows.py", "surface.py", "traffic.py", "world.py")


#: Values of CityConfig.reference_kind and CityConfig.season (scenenav.core.formats.world_manifest
#: ReferenceKind and worlds.reference.Season spell the same strings).
REFERENCE_KINDS = ("orthophoto", "perspective")
SEASONS = ("summer", "winter")

MIN_SIDE_PX = 256
MAX_SIDE_PX = 16384


class Stream(IntEnum):
    """Independent random streams (numpy Generators seeded from [seed, stream, ...])."""

    FEATURES = 1
    GRAPH = 2
    BLOCKS = 3
    DAYS = 4
    TRAFFIC = 5
    HEIGHTS = 6
    TREES = 7
    CHANGES = 8
    REGISTRATION = 9
    TEX_FINE = 10
    TEX_MEDIUM = 11
    TEX_COARSE = 12
    NAT_FINE = 20
    NAT_MEDIUM = 21
    NAT_COARSE = 22
    NAT_CANOPY = 23
    NAT_WARP = 24
    SENSOR = 30


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
    # the reference map ("another day", docs/worlds.md)
    reference_kind: str = "perspective"   # the kind perception uses: orthophoto | perspective
    reference_height_m: float = 500.0     # eye of the perspective reference above the map centre
    season: str = "summer"                # of the reference: summer | winter (leaf-off, snow)
    reroofed_share: float = 0.045         # buildings with a new roof tone in the reference
    added_share: float = 0.01             # buildings built since the reference (bare lot there)
    demolished_share: float = 0.005       # buildings in the reference, gone on the capture day
    misregistration_shift_m: float = 2.0  # global shift of the reference: this x U(0.7, 1) metres
    misregistration_warp_m: float = 0.7   # sum of the amplitudes of the smooth warp terms

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
        check(self.reference_kind in REFERENCE_KINDS, "reference_kind", self.reference_kind,
              " or ".join(REFERENCE_KINDS))
        check(50.0 <= self.reference_height_m <= 20000.0, "reference_height_m", self.reference_height_m,
              "metres above the map centre in [50, 20000]")
        check(self.season in SEASONS, "season", self.season, " or ".join(SEASONS))
        for key in ("reroofed_share", "added_share", "demolished_share"):
            v = getattr(self, key)
            check(0.0 <= v <= 0.3, key, v, "a fraction of the buildings in [0, 0.3]")
        check(self.reroofed_share + self.added_share + self.demolished_share <= 0.5,
              "reroofed_share+added_share+demolished_share",
              self.reroofed_share + self.added_share + self.demolished_share, "a sum of at most 0.5")
        check(0.0 <= self.misregistration_shift_m <= 20.0, "misregistration_shift_m",
              self.misregistration_shift_m, "metres in [0, 20]")
        check(0.0 <= self.misregistration_warp_m <= 10.0, "misregistration_warp_m",
              self.misregistration_warp_m, "metres in [0, 10]")

    @property
    def area_m2(self) -> float:
        return self.width_px * self.height_px * self.m_per_px ** 2


def stream_rng(cfg: CityConfig, stream: Stream, *extra: int) -> np.random.Generator:
    return np.random.default_rng([cfg.seed, GENERATOR_VERSION, int(stream), *extra])
