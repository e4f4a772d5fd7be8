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

from autopilot_bridge.config import AutopilotNodeConfig
from guidance.config import GuidanceNodeConfig
from perception.config import PerceptionNodeConfig
from scenenav.app.realism import Realism, apply_realism
from scenenav.core.camera_geometry import ground_footprint_m
from scenenav.core.clock import ClockConfig
from scenenav.core.config import apply_overrides, check, is_finite_number, load_config, load_yaml, to_dict
from scenenav.core.contracts import ClockMode
from scenenav.core.errors import UserError
from sitl.config import SimConfig, check_camera_answer_ticks


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
class RecorderConfig:
    camera_every_n: int = 10           # every n-th camera frame goes to the MCAP log and the live view (0: none)
    truth_every_n_ticks: int = 5       # truth.csv decimation (1: every control tick)
    min_free_disk_mb: float = 200.0    # the launcher refuses to start with less free on the run's disk
    mcap_chunk_s: float = 2.0          # bus.mcap chunks close every this many wall seconds (crash loss)

    def __post_init__(self) -> None:
        check(self.camera_every_n >= 0, "camera_every_n", self.camera_every_n, ">= 0")
        check(self.min_free_disk_mb >= 0, "min_free_disk_mb", self.min_free_disk_mb, ">= 0 MB")
        check(self.mcap_chunk_s > 0, "mcap_chunk_s", self.mcap_chunk_s, "> 0 s")
        check(self.truth_every_n_ticks >= 1, "truth_every_n_ticks",
              self.truth_every_n_ticks, ">= 1")


@dataclass(frozen=True)
class EvaluationConfig:
    false_fix_threshold_m: float = 5.0  # a fix whose error exceeds this is false
    plot_dsm: bool = True               # trajectory.png: the DSM's hillshade and contours under the path
    # A guided mission succeeded when it was completed and the vehicle ended within this distance
    # of its last goal (``mission_succeeded``). 20 m: issue 12's bound on the `realistic` estimate
    # error (10 m), twice, because the last 40 m of the landing are dead-reckoned (SN_VIS_MIN_ALT);
    # it separates the landings the estimate brought home from the failsafe landings (70-100 m off)
    # and the missions "completed" on a false lock (150-370 m off) of the development worlds.
    goal_tolerance_m: float = 20.0      # success: completed and ended this near the last goal

    def __post_init__(self) -> None:
        check(self.false_fix_threshold_m > 0, "false_fix_threshold_m",
              self.false_fix_threshold_m, "> 0 m")
        check(math.isfinite(self.goal_tolerance_m) and self.goal_tolerance_m > 0, "goal_tolerance_m",
              self.goal_tolerance_m, "a number > 0 (m)")


#: Roles whose node a run starts itself unless an external node of that role is named.
BUILTIN_ROLES = ("perception", "autopilot", "guidance")
#: Roles that are the run itself (the hub and the run's records): never external.
RUN_ROLES = ("sim", "recorder")


@dataclass(frozen=True)
class ExternalNode:
    """One node started outside the launcher: its role and its node id on the bus."""

    role: str
    node_id: str

    @property
    def spec(self) -> str:
        return f"{self.role}:{self.node_id}"


def parse_external(spec: str, key: str = "nodes") -> ExternalNode:
    """``ROLE:ID`` -> ExternalNode; ConfigError (one line) for anything else."""
    from scenenav.core.keys import check_name
    role, sep, node_id = str(spec).partition(":")
    try:
        if not sep:
            raise ValueError("no ':'")
        check_name("role", role)
        check_name("node id", node_id)
    except ValueError:
        check(False, key, spec, "ROLE:ID (letters, digits, '_' or '-' on each side), e.g. "
                                "perception:my_matcher")
    check(role not in RUN_ROLES, key, spec,
          f"a role other than {' or '.join(RUN_ROLES)} (the run itself is never external)")
    return ExternalNode(role, node_id)


@dataclass(frozen=True)
class ExternalConfig:
    """Nodes the user starts (``scenenav run --external ROLE:ID``); docs/interfaces.md section 1."""

    nodes: tuple[str, ...] = ()        # ROLE:ID of each node started outside the run; the clock waits for it
    join_timeout_s: float = 120.0      # wall seconds the run waits for them (from run.json on), then gives up
    # wall seconds the clock then waits for every node of the run to link to them (each echoes them,
    # docs/interfaces.md "Presence"), then starts with a warning: loopback peers link within
    # milliseconds; a node on another machine needs Zenoh's scouting and gossip over the network
    link_timeout_s: float = 10.0
    # the address every node of the run listens on (the hub and the live view included): 127.0.0.1
    # keeps the run on this machine; an address of one of its interfaces (or 0.0.0.0, all of them)
    # lets a node or a viewer on another machine join (docs/interfaces.md "A node on another machine")
    listen_host: str = "127.0.0.1"

    def __post_init__(self) -> None:
        import ipaddress
        try:
            ipaddress.IPv4Address(self.listen_host)
        except ValueError:
            check(False, "listen_host", self.listen_host,
                  "an IPv4 address of this machine: 127.0.0.1 (this machine only), 0.0.0.0 (every "
                  "interface) or one interface's address")
        members = [parse_external(s) for s in self.nodes]
        ids = [m.node_id for m in members]
        check(len(set(ids)) == len(ids), "nodes", list(self.nodes), "distinct node ids")
        check(self.join_timeout_s > 0, "join_timeout_s", self.join_timeout_s, "> 0 s")
        check(self.link_timeout_s >= 0, "link_timeout_s", self.link_timeout_s, ">= 0 s")

    def members(self) -> tuple[ExternalNode, ...]:
        return tuple(parse_external(s) for s in self.nodes)

    def of_role(self, role: str) -> tuple[ExternalNode, ...]:
        return tuple(m for m in self.members() if m.role == role)


@dataclass(frozen=True)
class ScenarioConfig:
    name: str = "default"
    seed: int = 0
    realism: Realism = Realism.IDEAL   # ideal | paper | realistic: a bundle of settings under the file's keys (docs/realism.md)
    world: str = "default"             # a world folder, "default", or "generated:seed=N,width_px=W,..."
    duration_s: float = 90.0           # simulated seconds at most
    clock: ClockConfig = field(default_factory=ClockConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    flight: FlightConfig = field(default_factory=FlightConfig)
    perception: PerceptionNodeConfig = field(default_factory=PerceptionNodeConfig)
    recorder: RecorderConfig = field(default_factory=RecorderConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    autopilot: AutopilotNodeConfig = field(default_factory=AutopilotNodeConfig)
    guidance: GuidanceNodeConfig = field(default_factory=GuidanceNodeConfig)
    external: ExternalConfig = field(default_factory=ExternalConfig)

    def __post_init__(self) -> None:
        check(is_finite_number(self.duration_s) and self.duration_s > 0, "duration_s", self.duration_s,
              "a positive, finite number of seconds")
        check(not self.guidance.enabled or self.flight.mode == FlightMode.AUTOPILOT,
              "guidance.enabled", self.guidance.enabled,
              "false unless flight.mode is autopilot (the guidance node flies through the autopilot)")
        check(not self.guidance.enabled or self.autopilot.mavlink_tcp_port != 0,
              "autopilot.mavlink_tcp_port", self.autopilot.mavlink_tcp_port,
              "a port, not 0, when guidance.enabled (the guidance node uploads its mission over the "
              "autopilot's MAVLink TCP port): set a free port, or guidance.enabled=false")
        check(self.seed >= 0, "seed", self.seed, "a non-negative integer")
        check_camera_answer_ticks(self.clock, self.sim.camera)
        # In lockstep the simulator waits up to clock.member_timeout_s for the autopilot's answer,
        # and the autopilot may itself wait up to autopilot.vision_wait_s for perception's fix
        # first: a member timeout not longer than that wait gives up on a healthy autopilot and
        # steps physics on stale motor commands (docs/faults.md).
        check(self.clock.mode != ClockMode.LOCKSTEP or self.flight.mode != FlightMode.AUTOPILOT
              or self.clock.member_timeout_s > self.autopilot.vision_wait_s,
              "clock.member_timeout_s", self.clock.member_timeout_s,
              f"more than autopilot.vision_wait_s = {self.autopilot.vision_wait_s} s (the simulator "
              f"must wait longer for the autopilot than the autopilot waits for a vision fix); raise "
              f"clock.member_timeout_s or lower autopilot.vision_wait_s")


def bowtie_route(world, altitude_m: float = 100.0, fov_deg: float = 60.0,
                 margin_m: float = 10.0) -> tuple[tuple[float, float], ...]:
    """A route for any world: SW -> SE -> NW -> NE -> SW, inset so the camera footprint stays on
    the map. The diagonals cross the centre; the legs cover the edge districts."""
    half_fp = ground_footprint_m(altitude_m, fov_deg) / 2.0
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


#: Top-level key of a scenario YAML naming the scenario it builds on (a path relative to the file).
BASE_KEY = "base"


def _merged(base: dict, top: dict) -> dict:
    """``top`` over ``base``: mappings merge key by key, anything else (lists too) replaces."""
    out = dict(base)
    for key, value in top.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(
            out.get(key), dict) else value
    return out


def scenario_yaml(path: str | Path, _seen: tuple[Path, ...] = ()) -> dict:
    """A scenario YAML as a mapping, with its ``base:`` scenario (and that one's) merged under it:
    a scenario names only what it changes, and follows its base when the base changes."""
    p = Path(path)
    data = load_yaml(p)
    base = data.pop(BASE_KEY, None)
    if base is None:
        return data
    if not isinstance(base, str) or not base:
        raise UserError(f"{p}: base = {base!r}: expected the path of a scenario YAML (relative to "
                        "this file)")
    base_path = (p.parent / base).resolve()
    if base_path in _seen or base_path == p.resolve():
        raise UserError(f"{p}: base = {base!r}: scenarios name each other as base (a cycle)")
    return _merged(scenario_yaml(base_path, (*_seen, p.resolve())), data)


def load_scenario(path: str | Path | None, overrides: tuple[str, ...] = (),
                  external: tuple[str, ...] = ()) -> ScenarioConfig:
    """Load a scenario YAML (None: all defaults; ``base:`` merged, see :func:`scenario_yaml`), apply
    ``key=value`` overrides, add the ``external`` nodes (``ROLE:ID``, from ``--external``) to
    ``external.nodes``, then lay the ``realism`` profile's settings under whatever the file and the
    overrides set (scenenav/app/realism.py)."""
    data = scenario_yaml(path) if path else {}
    source = str(path) if path else "scenario"
    if overrides:
        data = apply_overrides(data, list(overrides))
        source += " (with --set overrides)"
    if external:
        data = with_external(data, external)
        source += " (with --external)"
    return load_config(ScenarioConfig, apply_realism(data, source), source)


def with_external(data: dict, external: tuple[str, ...]) -> dict:
    """Scenario data with the ``ROLE:ID`` nodes of ``--external`` added to ``external.nodes``."""
    data = dict(data)
    section = dict(data.get("external") or {})
    section["nodes"] = [*(section.get("nodes") or []), *external]
    data["external"] = section
    return data


def scenario_to_dict(cfg: ScenarioConfig) -> dict:
    return to_dict(cfg)


def replace(cfg, **changes):
    """dataclasses.replace for nested frozen configs (re-runs the range checks)."""
    return dataclasses.replace(cfg, **changes)
