"""Configuration of the potential-field route planner (``scenenav plan``).

Every field carries its unit in its name; ``PlannerConfig.__post_init__`` range-checks through
``scenenav.core.config.check`` (raising ``ConfigError``, a ``UserError``). Build one from YAML or
``--set key=value`` overrides with ``scenenav.core.config.load_config(PlannerConfig, mapping)``.
The meaning of every parameter is documented in ``docs/guidance.md``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from scenenav.core.config import check

# Seed paper, section 6.1: the camera has a 60 degree field of view (square 200x200 image);
# section 6.3: the drone flew at 100 m. Ground footprint width = 2 * h * tan(fov / 2).
DEFAULT_ALTITUDE_M = 100.0
DEFAULT_CAMERA_FOV_DEG = 60.0
# Seed paper, section 5.4: a matching with probability < 0.5 of being true is excluded (bad area).
DEFAULT_BAD_PROBABILITY_THRESHOLD = 0.5
# Seed paper, section 5.4 / 6.3: average speed 10 m/s.
DEFAULT_CRUISE_SPEED_M_S = 10.0
# A gentle bank for a multicopter at cruise: a_lat = g * tan(bank); 2.5 m/s^2 is ~14 degrees of
# bank, well inside ArduCopter's default ANGLE_MAX of 30 degrees (ArduPilot parameter docs).
DEFAULT_MAX_LATERAL_ACCEL_M_S2 = 2.5


def footprint_width_m(altitude_m: float, camera_fov_deg: float) -> float:
    """Ground width of a nadir square camera footprint: 2 * altitude * tan(fov / 2)."""
    return 2.0 * altitude_m * math.tan(math.radians(camera_fov_deg) / 2.0)


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
        return footprint_width_m(self.altitude_m, self.camera_fov_deg)

    @property
    def required_distance_m(self) -> float:
        """Distance from the drone (footprint centre) to the nearest bad cell that the route keeps."""
        return self.footprint_width_m / 2.0 + self.clearance_m

    @property
    def turn_radius_m(self) -> float:
        """Corner radius flown at cruise speed: v^2 / a_lat."""
        return self.cruise_speed_m_s ** 2 / self.max_lateral_accel_m_s2
