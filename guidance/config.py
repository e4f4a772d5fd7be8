"""Configuration of guidance: the route planner, the scenario's ``guidance`` section, the node.

``PlannerConfig``: the potential-field route planner (``scenenav plan`` and the guidance node).
``GuidanceNodeConfig``: the scenario's ``guidance`` section. ``GuidanceRunConfig``: what the guidance
node itself needs (derived from the scenario by ``scenenav/app/nodes.py``).

Every field carries its unit in its name; ``PlannerConfig.__post_init__`` range-checks through
``scenenav.core.config.check`` (raising ``ConfigError``, a ``UserError``). Build one from YAML or
``--set key=value`` overrides with ``scenenav.core.config.load_config(PlannerConfig, mapping)``.
The meaning of every parameter is documented in ``docs/guidance.md``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from scenenav.core.camera_geometry import ground_footprint_m
from scenenav.core.config import check
from scenenav.core.formats.assistant_map_file import WORLD_MAP_STRIDE_M, check_stride_m

# Seed paper, section 6.1: the camera has a 60 degree field of view (square 200x200 image);
# section 6.3: the drone flew at 100 m. Ground footprint width: scenenav.core.camera_geometry.
DEFAULT_ALTITUDE_M = 100.0
DEFAULT_CAMERA_FOV_DEG = 60.0
# Seed paper, section 5.4: a matching with probability < 0.5 of being true is excluded (bad area).
DEFAULT_BAD_PROBABILITY_THRESHOLD = 0.5
# Seed paper, section 5.4 / 6.3: average speed 10 m/s.
DEFAULT_CRUISE_SPEED_M_S = 10.0
# A gentle bank for a multicopter at cruise: a_lat = g * tan(bank); 2.5 m/s^2 is ~14 degrees of
# bank, well inside ArduCopter's default ANGLE_MAX of 30 degrees (ArduPilot parameter docs).
DEFAULT_MAX_LATERAL_ACCEL_M_S2 = 2.5


class RouteEnd(str, enum.Enum):
    """What the exported mission does after the last waypoint."""

    NONE = "none"
    LAND = "land"
    RTL = "rtl"


class RouteFormat(str, enum.Enum):
    """Route file formats written by ``scenenav plan``."""

    JSON = "json"
    WPL = "wpl"


class PlannerMethod(str, enum.Enum):
    """Which planner produced the route."""

    POTENTIAL_FIELD = "potential_field"
    NAVIGATION_FUNCTION = "navigation_function"


class FallbackReason(str, enum.Enum):
    """Why the classic potential-field descent was abandoned for the navigation function."""

    NONE = "none"
    LOCAL_MINIMUM = "local_minimum"
    OSCILLATION = "oscillation"
    CLEARANCE = "clearance"
    MAX_STEPS = "max_steps"
    TOO_LONG = "too_long"
    HIGHER_COST = "higher_cost"
    START_OR_GOAL_IN_CLEARANCE_ZONE = "start_or_goal_in_clearance_zone"


@dataclass(frozen=True)
class PlannerConfig:
    """Parameters of :func:`guidance.planner.plan_route` (units in the names; see docs/guidance.md)."""

    # --- footprint and clearance -------------------------------------------------------------
    altitude_m: float = DEFAULT_ALTITUDE_M
    camera_fov_deg: float = DEFAULT_CAMERA_FOV_DEG
    # Diameter of the camera-footprint disc; None = 2 * altitude_m * tan(camera_fov_deg / 2).
    footprint_m: float | None = None
    # Required distance from the footprint edge to the nearest bad cell (extra margin).
    clearance_m: float = 10.0
    bad_probability_threshold: float = DEFAULT_BAD_PROBABILITY_THRESHOLD
    # Weight of unvisited (NaN) cells as obstacles: 0 = free, 1 = as hard as bad cells.
    unvisited_weight: float = 0.5
    # Keep the whole camera footprint (camera_footprint_radius_m, from altitude and FOV whatever
    # footprint_m says) on the map: beyond its edge there is nothing to match. Off: only the
    # unvisited-ground cost keeps the route off the edge (with footprint_m 0, nothing does).
    keep_footprint_on_map: bool = False
    # --- planning grid --------------------------------------------------------------------------
    grid_cell_m: float = 2.0
    max_grid_cells: int = 1_200_000
    # --- classic potential field ----------------------------------------------------------------
    influence_distance_m: float = 60.0
    attractive_gain: float = 1.0
    attractive_quadratic_radius_m: float = 20.0
    repulsive_gain_m: float = 20.0
    step_m: float = 4.0
    goal_tolerance_m: float = 5.0
    stall_window_steps: int = 40
    min_progress_m: float = 4.0
    max_cell_visits: int = 4
    max_steps: int = 20000
    pf_max_length_ratio: float = 1.3
    # --- navigation function (fallback) ---------------------------------------------------------
    nav_repulsive_weight: float = 0.05
    # --- smoothing and waypoints ------------------------------------------------------------------
    cruise_speed_m_s: float = DEFAULT_CRUISE_SPEED_M_S
    max_lateral_accel_m_s2: float = DEFAULT_MAX_LATERAL_ACCEL_M_S2
    waypoint_spacing_m: float = 50.0
    arc_chord_tolerance_m: float = 1.0

    def __post_init__(self) -> None:
        check(self.altitude_m > 0, "altitude_m", self.altitude_m, "a positive height in metres")
        check(0 < self.camera_fov_deg < 180, "camera_fov_deg", self.camera_fov_deg,
              "an angle in (0, 180) degrees")
        check(self.footprint_m is None or self.footprint_m >= 0, "footprint_m", self.footprint_m,
              "a non-negative width in metres (0 = point footprint)")
        check(self.clearance_m >= 0, "clearance_m", self.clearance_m, "a non-negative distance in metres")
        check(0 < self.bad_probability_threshold < 1, "bad_probability_threshold",
              self.bad_probability_threshold, "a probability in (0, 1)")
        check(0 <= self.unvisited_weight <= 1, "unvisited_weight", self.unvisited_weight,
              "a weight in [0, 1] (0 = free, 1 = hard obstacle)")
        check(self.grid_cell_m > 0, "grid_cell_m", self.grid_cell_m, "a positive cell size in metres")
        check(self.max_grid_cells >= 100, "max_grid_cells", self.max_grid_cells, "an integer >= 100")
        check(self.influence_distance_m > 0, "influence_distance_m", self.influence_distance_m,
              "a positive distance in metres")
        check(self.attractive_gain > 0, "attractive_gain", self.attractive_gain, "a positive gain")
        check(self.attractive_quadratic_radius_m >= 0, "attractive_quadratic_radius_m",
              self.attractive_quadratic_radius_m, "a non-negative distance in metres")
        check(self.repulsive_gain_m >= 0, "repulsive_gain_m", self.repulsive_gain_m,
              "a non-negative gain in metres")
        check(self.step_m > 0, "step_m", self.step_m, "a positive step in metres")
        check(self.goal_tolerance_m >= self.step_m, "goal_tolerance_m", self.goal_tolerance_m,
              f"a distance in metres >= step_m ({self.step_m})")
        check(self.stall_window_steps >= 2, "stall_window_steps", self.stall_window_steps, "an integer >= 2")
        check(self.min_progress_m > 0, "min_progress_m", self.min_progress_m, "a positive distance in metres")
        check(self.max_cell_visits >= 1, "max_cell_visits", self.max_cell_visits, "an integer >= 1")
        check(self.max_steps >= 1, "max_steps", self.max_steps, "an integer >= 1")
        check(self.pf_max_length_ratio >= 1, "pf_max_length_ratio", self.pf_max_length_ratio, "a ratio >= 1")
        check(self.nav_repulsive_weight >= 0, "nav_repulsive_weight", self.nav_repulsive_weight,
              "a non-negative weight")
        check(self.cruise_speed_m_s > 0, "cruise_speed_m_s", self.cruise_speed_m_s, "a positive speed in m/s")
        check(self.max_lateral_accel_m_s2 > 0, "max_lateral_accel_m_s2", self.max_lateral_accel_m_s2,
              "a positive acceleration in m/s^2")
        check(self.waypoint_spacing_m > 0, "waypoint_spacing_m", self.waypoint_spacing_m,
              "a positive distance in metres")
        check(self.arc_chord_tolerance_m > 0, "arc_chord_tolerance_m", self.arc_chord_tolerance_m,
              "a positive distance in metres")

    @property
    def footprint_width_m(self) -> float:
        """Footprint disc diameter actually used (explicit ``footprint_m`` or from altitude and FOV)."""
        if self.footprint_m is not None:
            return float(self.footprint_m)
        return ground_footprint_m(self.altitude_m, self.camera_fov_deg)

    @property
    def camera_footprint_radius_m(self) -> float:
        """Half the camera's ground footprint from altitude and FOV, whatever ``footprint_m`` says:
        how far inside the reference map a capture's centre must be for the whole capture to be in it."""
        return ground_footprint_m(self.altitude_m, self.camera_fov_deg) / 2.0

    @property
    def required_distance_m(self) -> float:
        """Distance from the drone (footprint centre) to the nearest bad cell that the route keeps."""
        return self.footprint_width_m / 2.0 + self.clearance_m

    @property
    def turn_radius_m(self) -> float:
        """Corner radius flown at cruise speed: v^2 / a_lat."""
        return self.cruise_speed_m_s ** 2 / self.max_lateral_accel_m_s2


@dataclass(frozen=True)
class GuidanceNodeConfig:
    """The ``guidance`` section of a scenario (YAML key ``guidance``).

    The guidance node (guidance/node.py) plans a route over the assistant map around bad matching
    areas and flies it as a MAVLink mission. Needs ``flight.mode: autopilot``; the autopilot then
    waits for this node instead of starting ``flight.route_enu_m`` by itself. The app layer turns it
    into a ``GuidanceRunConfig`` + ``PlannerConfig`` (scenenav/app/nodes.py).
    """

    enabled: bool = False              # start the guidance node (needs flight.mode autopilot)
    # Each leg (take-off point -> first goal -> second ...) is planned around bad areas; the
    # mission ends with autopilot.mission_end.
    goals_enu_m: tuple[tuple[float, float], ...] = ()   # via-points and goal, [x east, y north] m
    assistant_map: str = ""            # .npz; empty: the world's map built with the CNN (cached)
    # 5.3 m: rounded to whole pixels of the world, 10 px on the default 0.53 m/px world (the pixel
    # stride it had before; scenenav.core.formats.assistant_map_file.stride_px_for).
    assistant_map_stride_m: float = WORLD_MAP_STRIDE_M   # cell spacing of that built map, metres of ground
    # The same in whole pixels of the world, as scenarios gave it until 2026-12-06 (run folders from
    # before keep loading and rebuild the same map); 0 = unset: assistant_map_stride_m decides.
    assistant_map_stride_px: int = 0
    # What that built map classifies: "reference" (the paper's way, 5.3, and all a real user has:
    # the CNN over footprint crops of the reference map) or "captures" (nadir captures rendered with
    # the world's DSM over each cell: simulator knowledge a real flight does not have).
    assistant_map_source: str = "reference"
    start_after_s: float = 1.0         # simulated seconds before the mission is uploaded and started
    check_period_s: float = 1.0        # simulated seconds between drift / map-change checks
    replan_drift_m: float = 40.0       # replan when the estimate is this far from the route
    footprint_m: float | None = None   # camera-footprint width kept clear; None: from altitude and FOV
    clearance_m: float = 10.0          # extra distance kept between footprint edge and bad area
    keep_footprint_on_map: bool = False  # keep the whole camera footprint on the map (route and goals)
    unvisited_weight: float = 0.5      # unvisited map cells as obstacles: 0 free .. 1 hard
    waypoint_spacing_m: float = 50.0   # spacing of the mission's waypoints along the route
    # A goal on a bad matching area is moved to the nearest point with the route's clearance within
    # this distance (0: refused with "no route"), e.g. a mission reused on other worlds.
    snap_goals_m: float = 0.0          # move a goal on a bad area to the nearest good point within this, and leave a start on one straight to such a point (0: refuse)

    def __post_init__(self) -> None:
        check(self.snap_goals_m >= 0, "snap_goals_m", self.snap_goals_m, ">= 0 m")
        check(not self.enabled or len(self.goals_enu_m) >= 1, "goals_enu_m", self.goals_enu_m,
              "at least one [x, y] goal in metres when guidance is enabled")
        check_stride_m(self.assistant_map_stride_m, "assistant_map_stride_m")
        check(type(self.assistant_map_stride_px) is int and self.assistant_map_stride_px >= 0,
              "assistant_map_stride_px", self.assistant_map_stride_px,
              "a whole number of pixels >= 0 (0 = unset: assistant_map_stride_m decides)")
        check(self.assistant_map_stride_px == 0 or self.assistant_map_stride_m == WORLD_MAP_STRIDE_M,
              "assistant_map_stride_px", self.assistant_map_stride_px,
              "0 when assistant_map_stride_m is set (give the stride once, preferably in metres)")
        check(self.assistant_map_source in ("reference", "captures"), "assistant_map_source",
              self.assistant_map_source, "reference or captures")
        check(self.start_after_s >= 0, "start_after_s", self.start_after_s, ">= 0 s")
        check(self.check_period_s > 0, "check_period_s", self.check_period_s, "> 0 s")
        check(self.replan_drift_m > 0, "replan_drift_m", self.replan_drift_m, "> 0 m")
        check(self.footprint_m is None or self.footprint_m >= 0, "footprint_m", self.footprint_m,
              "a width >= 0 m, or null for the camera footprint")
        check(self.clearance_m >= 0, "clearance_m", self.clearance_m, ">= 0 m")
        check(0 <= self.unvisited_weight <= 1, "unvisited_weight", self.unvisited_weight, "0 to 1")
        check(self.waypoint_spacing_m > 0, "waypoint_spacing_m", self.waypoint_spacing_m, "> 0 m")


@dataclass(frozen=True)
class GuidanceRunConfig:
    """What the guidance node needs beyond the planner parameters (units in the names); derived
    from the scenario by the app layer (scenenav/app/nodes.py)."""

    start_enu_m: tuple[float, float] = (0.0, 0.0)   # take-off point, world metres (east, north)
    goals_enu_m: tuple[tuple[float, float], ...] = ((0.0, 0.0),)   # via-points and goal
    assistant_map: str = ""                         # .npz with key ``probability``
    altitude_m: float = 100.0                       # cruise altitude above home
    snap_goals_m: float = 0.0                       # move goals on bad areas up to this far, and leave a start on one (0: refuse)
    end: RouteEnd = RouteEnd.LAND                   # after the last waypoint
    replan_drift_m: float = 40.0                    # replan when this far off the route
    check_period_s: float = 1.0                     # simulated seconds between checks
    start_after_s: float = 1.0                      # simulated seconds before the first start try
    retry_period_s: float = 1.0                     # simulated seconds between start tries
    mavlink_url: str = "tcp:127.0.0.1:5760"
    lockstep: bool = True                           # hold the simulator while planning, starting and replanning

    def __post_init__(self) -> None:
        check(len(self.goals_enu_m) >= 1, "goals_enu_m", self.goals_enu_m, "at least one goal")
        check(self.altitude_m > 0, "altitude_m", self.altitude_m, "a positive height in m")
        check(self.replan_drift_m > 0, "replan_drift_m", self.replan_drift_m, "> 0 m")
        check(self.check_period_s > 0, "check_period_s", self.check_period_s, "> 0 s")
        check(self.start_after_s >= 0, "start_after_s", self.start_after_s, ">= 0 s")
        check(self.retry_period_s > 0, "retry_period_s", self.retry_period_s, "> 0 s")
