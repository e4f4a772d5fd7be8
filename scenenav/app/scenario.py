"""Scenario configuration: one YAML file describes a whole run (schema in docs/scenarios.md).

Every section is a frozen dataclass with units in its key names; unknown keys and out-of-range
values are one-line errors naming the file and the key.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

from scenenav.core.config import apply_overrides, check, load_config, load_yaml, to_dict
from scenenav.core.clock import ClockConfig
from scenenav.core.errors import UserError
from sitl.config import SimConfig


class FlightMode(str, Enum):
    SCRIPTED = "scripted"     # kinematic path, no autopilot (logging runs, like the paper's flights)
    AUTOPILOT = "autopilot"   # the MAVLink autopilot flies the route as a mission
    IDLE = "idle"             # the vehicle waits on the ground for a ground station (scenenav sitl)


@dataclass(frozen=True)
class FlightConfig:
    mode: FlightMode = FlightMode.SCRIPTED
    route_enu_m: tuple[tuple[float, float], ...] = ()   # [x, y] waypoints in m; empty: a bowtie fitted to the world
    altitude_m: float = 100.0
    speed_m_s: float = 10.0
    turn_radius_m: float = 30.0
    start_enu_m: tuple[float, float] = (0.0, 0.0)   # autopilot/idle: take-off point on the ground
    start_heading_deg: float = 0.0                   # compass, clockwise from north

    def __post_init__(self) -> None:
        check(len(self.route_enu_m) != 1, "route_enu_m", self.route_enu_m,
              "at least two [x, y] waypoints in metres, or [] for a route fitted to the world")
        check(5.0 <= self.altitude_m <= 1000.0, "altitude_m", self.altitude_m, "5 to 1000 m")
        check(0.5 <= self.speed_m_s <= 30.0, "speed_m_s", self.speed_m_s, "0.5 to 30 m/s")
        check(self.turn_radius_m >= 0, "turn_radius_m", self.turn_radius_m, ">= 0 m")


@dataclass(frozen=True)
class PerceptionNodeConfig:
    enabled: bool = True
    method: str = "none"               # cnn | assistant-map | statistical | none
    assistant_map: str = ""            # .npz for method assistant-map (empty: built online)
    weights: str = ""                  # CNN weights .pt (empty: perception/weights/default.pt)
    lockstep: bool = True              # the simulator waits for this node's answer to each frame
    decision_rule: str = "paper"       # cnn, assistant-map: paper (P(bad) > 0.5) or combined (docs/perception.md)
    decision_model: str = ""           # combined rule: model .json (empty: the shipped one)
    swap_at_s: float = 0.0             # > 0: at this simulated time a second node takes over (swap)
    swap_method: str = "statistical"   # method of that second node (perception-2)

    def __post_init__(self) -> None:
        methods = ("cnn", "assistant-map", "statistical", "none")
        check(self.method in methods, "method", self.method, "one of cnn, assistant-map, statistical, none")
        check(self.decision_rule in ("paper", "combined"), "decision_rule", self.decision_rule,
              "paper or combined")
        check(not (self.decision_rule == "combined" and self.weights.endswith(".pt")), "weights",
              self.weights, "empty with decision_rule combined (the decision model names the CNN it "
              "was fitted with; choose another model with decision_model)")
        check(self.swap_at_s >= 0, "swap_at_s", self.swap_at_s, ">= 0 s (0 = no swap)")
        check(self.swap_method in methods, "swap_method", self.swap_method,
              "one of cnn, assistant-map, statistical, none")


@dataclass(frozen=True)
class RecorderConfig:
    camera_every_n: int = 10           # every n-th camera frame goes to the MCAP log (0: none)
    truth_every_n_ticks: int = 5       # truth.csv decimation (1: every control tick)

    def __post_init__(self) -> None:
        check(self.camera_every_n >= 0, "camera_every_n", self.camera_every_n, ">= 0")
        check(self.truth_every_n_ticks >= 1, "truth_every_n_ticks",
              self.truth_every_n_ticks, ">= 1")


@dataclass(frozen=True)
class EvaluationConfig:
    false_fix_threshold_m: float = 5.0  # a fix whose error exceeds this is false

    def __post_init__(self) -> None:
        check(self.false_fix_threshold_m > 0, "false_fix_threshold_m",
              self.false_fix_threshold_m, "> 0 m")


class MissionEndMode(str, Enum):
    """What an autopilot flight does after the last route waypoint."""

    LAND = "land"    # land at the last waypoint
    RTL = "rtl"      # return to the take-off point and land there


UDP_OUT_OFF = ("none", "off", "0", "")


def _udp_out_ok(text: str) -> bool:
    if text.lower() in UDP_OUT_OFF:
        return True
    host, sep, port = text.rpartition(":")
    return bool(sep and host and port.isdigit() and 0 < int(port) <= 65535)


@dataclass(frozen=True)
class AutopilotNodeConfig:
    mavlink_tcp_port: int = 5760       # MAVLink TCP server on 127.0.0.1 (0 = off)
    mavlink_udp_out: str = "127.0.0.1:14550"   # MAVLink UDP output HOST:PORT, or none
    auto_start: bool = True            # autopilot flights: arm and start AUTO once the EKF is aligned
    mission_end: MissionEndMode = MissionEndMode.LAND   # autopilot flights: after the last waypoint
    params_file: str = ""              # JSON {"NAME": value} of ArduPilot parameters set at start
    vision_wait_s: float = 5.0         # lockstep: wall seconds to wait for the fix of an acked frame
    estimate_rate_hz: float = 20.0     # autopilot/estimate rate (simulated time)
    params: dict[str, float] = field(default_factory=dict)   # ArduPilot parameters {NAME: value}, after params_file

    def __post_init__(self) -> None:
        check(0 <= self.mavlink_tcp_port <= 65535, "mavlink_tcp_port", self.mavlink_tcp_port,
              "a TCP port 1..65535, or 0 for off")
        check(_udp_out_ok(self.mavlink_udp_out), "mavlink_udp_out", self.mavlink_udp_out,
              "HOST:PORT (e.g. 127.0.0.1:14550), or none")
        check(self.vision_wait_s >= 0, "vision_wait_s", self.vision_wait_s, ">= 0 s")
        check(0 < self.estimate_rate_hz <= 1000, "estimate_rate_hz", self.estimate_rate_hz,
              "0 to 1000 Hz")
        if self.params:
            from autopilot_bridge.flight_core import PARAM_SPECS
            known = {spec.name for spec in PARAM_SPECS}
            unknown = sorted(set(self.params) - known)
            check(not unknown, "params", unknown, "ArduCopter parameter names the autopilot knows "
                  "(docs/mavlink.md lists them)")


@dataclass(frozen=True)
class GuidanceConfig:
    """The guidance node (guidance/node.py): plans a route over the assistant map around bad
    matching areas and flies it as a MAVLink mission. Needs ``flight.mode: autopilot``; the
    autopilot then waits for this node instead of starting ``flight.route_enu_m`` by itself."""

    enabled: bool = False              # start the guidance node (needs flight.mode autopilot)
    # Each leg (take-off point -> first goal -> second ...) is planned around bad areas; the
    # mission ends with autopilot.mission_end.
    goals_enu_m: tuple[tuple[float, float], ...] = ()   # via-points and goal, [x east, y north] m
    assistant_map: str = ""            # .npz; empty: the world's map built with the CNN (cached)
    assistant_map_stride_px: int = 10  # stride of that built map
    start_after_s: float = 1.0         # simulated seconds before the mission is uploaded and started
    check_period_s: float = 1.0        # simulated seconds between drift / map-change checks
    replan_drift_m: float = 40.0       # replan when the estimate is this far from the route
    footprint_m: float | None = None   # camera-footprint width kept clear; None: from altitude and FOV
    clearance_m: float = 10.0          # extra distance kept between footprint edge and bad area
    unvisited_weight: float = 0.5      # unvisited map cells as obstacles: 0 free .. 1 hard
    waypoint_spacing_m: float = 50.0   # spacing of the mission's waypoints along the route

    def __post_init__(self) -> None:
        check(not self.enabled or len(self.goals_enu_m) >= 1, "goals_enu_m", self.goals_enu_m,
              "at least one [x, y] goal in metres when guidance is enabled")
        check(self.assistant_map_stride_px >= 1, "assistant_map_stride_px",
              self.assistant_map_stride_px, "a positive number of pixels")
        check(self.start_after_s >= 0, "start_after_s", self.start_after_s, ">= 0 s")
        check(self.check_period_s > 0, "check_period_s", self.check_period_s, "> 0 s")
        check(self.replan_drift_m > 0, "replan_drift_m", self.replan_drift_m, "> 0 m")
        check(self.footprint_m is None or self.footprint_m >= 0, "footprint_m", self.footprint_m,
              "a width >= 0 m, or null for the camera footprint")
        check(self.clearance_m >= 0, "clearance_m", self.clearance_m, ">= 0 m")
        check(0 <= self.unvisited_weight <= 1, "unvisited_weight", self.unvisited_weight, "0 to 1")
        check(self.waypoint_spacing_m > 0, "waypoint_spacing_m", self.waypoint_spacing_m, "> 0 m")


@dataclass(frozen=True)
class ScenarioConfig:
    name: str = "default"
    seed: int = 0
    world: str = "default"             # a world folder, "default", or "generated:seed=N,width_px=W,..."
    duration_s: float = 90.0           # simulated seconds at most
    clock: ClockConfig = field(default_factory=ClockConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    flight: FlightConfig = field(default_factory=FlightConfig)
    perception: PerceptionNodeConfig = field(default_factory=PerceptionNodeConfig)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    autopilot: AutopilotNodeConfig = field(default_factory=AutopilotNodeConfig)
    guidance: GuidanceConfig = field(default_factory=GuidanceConfig)

    def __post_init__(self) -> None:
        check(self.duration_s > 0, "duration_s", self.duration_s, "a positive number of seconds")
        check(not self.guidance.enabled or self.flight.mode == FlightMode.AUTOPILOT,
              "guidance.enabled", self.guidance.enabled,
              "false unless flight.mode is autopilot (the guidance node flies through the autopilot)")
        check(self.seed >= 0, "seed", self.seed, "a non-negative integer")


def bowtie_route(world, altitude_m: float = 100.0, fov_deg: float = 60.0,
                 margin_m: float = 10.0) -> tuple[tuple[float, float], ...]:
    """A route for any world: SW -> SE -> NW -> NE -> SW, inset so the camera footprint stays on
    the map. The diagonals cross the centre; the legs cover the edge districts."""
    half_fp = altitude_m * math.tan(math.radians(fov_deg / 2))
    hx = world.width_px * world.m_per_px / 2 - half_fp - margin_m
    hy = world.height_px * world.m_per_px / 2 - half_fp - margin_m
    if hx < 20 or hy < 20:
        raise UserError(f"world {world.manifest.name}: {world.width_px}x{world.height_px} px at "
                        f"{world.m_per_px} m/px is too small for a {2 * half_fp:.0f} m camera footprint "
                        f"at {altitude_m:.0f} m (needs at least {2 * (half_fp + margin_m + 20):.0f} m a side); "
                        f"give flight.route_enu_m or a lower flight.altitude_m")
    return ((-hx, -hy), (hx, -hy), (-hx, hy), (hx, hy), (-hx, -hy))


def route_for(cfg: "ScenarioConfig", world) -> tuple[tuple[float, float], ...]:
    """The scenario's route, or the bowtie fitted to ``world`` when ``flight.route_enu_m`` is empty."""
    if cfg.flight.route_enu_m:
        return cfg.flight.route_enu_m
    return bowtie_route(world, cfg.flight.altitude_m, cfg.sim.camera.fov_deg)


def load_scenario(path: str | Path | None, overrides: tuple[str, ...] = ()) -> ScenarioConfig:
    """Load a scenario YAML (None: all defaults) and apply ``key=value`` overrides."""
    data = load_yaml(path) if path else {}
    source = str(path) if path else "scenario"
    if overrides:
        data = apply_overrides(data, list(overrides))
        source += " (with --set overrides)"
    return load_config(ScenarioConfig, data, source)


def scenario_to_dict(cfg: ScenarioConfig) -> dict:
    return to_dict(cfg)


def replace(cfg, **changes):
    """dataclasses.replace for nested frozen configs (re-runs the range checks)."""
    return dataclasses.replace(cfg, **changes)
