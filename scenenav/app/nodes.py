"""``scenenav node <kind>``: the entry point of each child process of a run.

Every node reads the run's resolved scenario (``<run>/scenario.yaml``), joins the bus of the run
(namespace + hub port), logs to stderr (the launcher sends it to ``<run>/logs/<node>.log``) and stops
cleanly on SIGINT/SIGTERM.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from enum import Enum
from pathlib import Path
from types import SimpleNamespace

from scenenav.app.scenario import FlightMode, ScenarioConfig, load_scenario, route_for
from scenenav.app.signals import stop_event
from scenenav.core.bus import EXIT_HUB_PORT_TAKEN, BusConfig, HubPortTaken
from scenenav.core.contracts import LockstepRole
from scenenav.core.formats.atomic_file import write_atomic
from scenenav.core.formats.run_folder import HUB_FILE
from scenenav.core.presence import parse_node_key, parse_sees_key

log = logging.getLogger(__name__)


def write_stats(path: Path, data: dict) -> bool:
    """Write a node's stats JSON whole (temporary file renamed) or not at all; a full disk is one
    error line, not a traceback (the summary then says the file is missing)."""
    try:
        write_atomic(path, json.dumps(data, indent=2, default=str))
        return True
    except OSError as exc:
        log.error("cannot write %s: %s", path, exc.strerror or exc)
        return False


def load_world_for(cfg: ScenarioConfig):
    from worlds.default import is_generated_spec, load_world_spec
    from worlds.world import load_world
    return load_world_spec(cfg.world) if is_generated_spec(cfg.world) else load_world(cfg.world)


def sim_node_config(cfg: ScenarioConfig, world, expect: tuple[str, ...] = ()):
    """The simulator node's ``sitl.config.SimNodeConfig`` from the scenario: the route resolved
    against ``world`` for scripted flights, the lockstep members named in ``expect`` (``tick``,
    ``camera``; repeatable)."""
    from sitl.config import ScriptedFlight, SimNodeConfig
    flight = cfg.flight
    scripted = None
    if flight.mode == FlightMode.SCRIPTED:
        scripted = ScriptedFlight(route_for(cfg, world), flight.altitude_m, flight.speed_m_s,
                                  flight.turn_radius_m)
    return SimNodeConfig(
        sim=cfg.sim, clock=cfg.clock, duration_s=cfg.duration_s, seed=cfg.seed, scripted=scripted,
        start_enu_m=flight.start_enu_m, start_heading_deg=flight.start_heading_deg,
        end_with_mission=flight.mode == FlightMode.AUTOPILOT,
        expected_tick_members=sum(1 for item in expect if item == LockstepRole.TICK.value),
        expected_camera_members=sum(1 for item in expect if item == LockstepRole.CAMERA.value))


#: Written by the simulator once it stopped waiting for the external nodes: which joined, which not.
EXTERNAL_FILE = "external.json"
#: Exit code of the simulator when an external node did not join in time (``EX_UNAVAILABLE``).
EXIT_EXTERNAL_MISSING = 69


class ExternalWaitEnd(str, Enum):
    """How the wait for the external nodes ended (``EXTERNAL_FILE``'s ``ended``)."""

    JOINED = "joined"        # every external node's token was up
    TIMEOUT = "timeout"      # external.join_timeout_s ran out: the run gives up
    STOPPED = "stopped"      # the run was stopped (Ctrl-C, SIGTERM) while it waited


#: How often the wait for the external nodes looks at the run's stop request (wall seconds); a
#: token's arrival wakes it at once.
EXTERNAL_STOP_POLL_S = 0.05


def external_wait_facts(specs: list[str], joined_at_s: dict[str, float], began_s: float,
                        ended_s: float, ended: ExternalWaitEnd, began_unix_s: float,
                        join_timeout_s: float) -> dict:
    """``EXTERNAL_FILE``'s contents after the wait for the external nodes ``specs`` (``ROLE:ID``).

    ``began_s``: ``time.monotonic()`` when the wait began (the hub listens and ``HUB_FILE`` is
    written; the launcher then writes run.json and says "start them now"); ``joined_at_s``: when
    the token of each node still up at the end arrived; ``ended_s``: when the run stopped waiting.
    ``waited_s`` is the wall time from the start to the arrival of the last token, or, when one is
    missing, to the moment the run gave up (``ended``: timeout or stopped); ``joined_after_s`` the
    same per node that joined."""
    joined = [s for s in specs if s in joined_at_s]
    missing = [s for s in specs if s not in joined_at_s]
    after_s = {s: round(max(0.0, joined_at_s[s] - began_s), 3) for s in joined}
    last_s = max(after_s.values(), default=0.0)
    return {"joined": joined, "missing": missing,
            "waited_s": last_s if not missing else round(max(0.0, ended_s - began_s), 3),
            "joined_after_s": after_s, "ended": ended.value,
            "began_unix_s": round(began_unix_s, 3), "join_timeout_s": join_timeout_s}


def wait_external_nodes(node, cfg: ScenarioConfig, run_dir: Path,
                        stop: threading.Event | None = None) -> bool:
    """Before the clock starts, once the hub listens: wait until every external node
    (``external.nodes``) has declared its liveliness token ``nodes/<role>/<id>``, at most
    ``external.join_timeout_s`` wall seconds. Writes ``EXTERNAL_FILE`` (``external_wait_facts``);
    False if one is missing (or ``stop`` was set meanwhile)."""
    members = cfg.external.members()
    if not members:
        return True
    # the wait begins now, before the watches: a token they deliver at once arrives after it
    began_s, began_unix_s = time.monotonic(), time.time()
    live: dict[str, float] = {}            # ROLE:ID -> time.monotonic() its token arrived
    changed = threading.Condition()

    def on_change(spec: str, alive: bool) -> None:
        now_s = time.monotonic()
        with changed:
            if alive:
                live.setdefault(spec, now_s)      # a repeated sample of a live token is no new arrival
            else:
                live.pop(spec, None)
            changed.notify_all()

    for m in members:
        node.bus.watch_liveliness(node.keys.node_alive(m.role, m.node_id),
                                  lambda _k, alive, spec=m.spec: on_change(spec, alive))
    specs = [m.spec for m in members]
    timeout_s = cfg.external.join_timeout_s
    log.info("waiting up to %.0f s for external node(s) %s", timeout_s, ", ".join(specs))
    deadline_s = began_s + timeout_s
    ended = ExternalWaitEnd.TIMEOUT
    with changed:
        while True:
            if all(s in live for s in specs):
                ended = ExternalWaitEnd.JOINED
                break
            if stop is not None and stop.is_set():
                ended = ExternalWaitEnd.STOPPED
                break
            left_s = deadline_s - time.monotonic()
            if left_s <= 0.0:
                break
            changed.wait(min(EXTERNAL_STOP_POLL_S, left_s))
        joined_at_s = dict(live)
    facts = external_wait_facts(specs, joined_at_s, began_s, time.monotonic(), ended, began_unix_s,
                                timeout_s)
    write_stats(run_dir / EXTERNAL_FILE, facts)
    if ended is ExternalWaitEnd.STOPPED:
        log.info("stopped after %.1f s of waiting for external node(s) %s", facts["waited_s"],
                 ", ".join(facts["missing"]))
        return False
    if facts["missing"]:
        log.error("external node(s) %s did not join within %g s (external.join_timeout_s)",
                  ", ".join(facts["missing"]), timeout_s)
        return False
    log.info("external node(s) joined after %.3f s: %s", facts["waited_s"],
             ", ".join(f"{s} ({t:.3f} s)" for s, t in facts["joined_after_s"].items()))
    return True


def confirm_external_links(node, cfg: ScenarioConfig, run_dir: Path,
                           stop: threading.Event | None = None) -> None:
    """The simulator's last step before the clock starts (every lockstep member has joined): wait
    for the run's nodes to link to the external ones (``wait_external_links``) and add the outcome
    to ``EXTERNAL_FILE`` (``links_waited_s``, ``unlinked``)."""
    t0 = time.monotonic()
    unlinked = wait_external_links(node, cfg.external.members(), stop, cfg.external.link_timeout_s)
    path = run_dir / EXTERNAL_FILE
    try:
        facts = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        facts = {}
    facts.update({"links_waited_s": round(time.monotonic() - t0, 3), "unlinked": unlinked})
    write_stats(path, facts)


def wait_external_links(node, members, stop: threading.Event | None, timeout_s: float) -> list[str]:
    """Wait until every other node of the run (each live ``nodes/<role>/<id>`` but the simulator and
    the external ones) has echoed every external member (``Keys.node_sees``: it has a link to it),
    at most ``timeout_s``. Returns the links still missing, ``OBSERVER->ROLE:ID`` (logged).

    Why: the simulator (the hub) sees a node's token as soon as the node connects to it, but the
    node's direct links to the other peers (the recorder, the autopilot) are made afterwards by
    gossip, and Zenoh peers do not forward for each other: a fix published before its link to the
    recorder exists is not recorded (seen once in 2026-12-05's CI: frame 0's fix and ack of
    tests/e2e/test_external_node.py missing from fixes.csv). Gossip meshes loopback peers within
    milliseconds; past the limit (``external.link_timeout_s``) the clock starts anyway, with a
    warning."""
    external = {(m.role, m.node_id) for m in members}
    own = ("sim", "sim")
    keys = node.keys

    def missing() -> tuple[list[str], int]:
        alive = {parse_node_key(keys, k) for k in node.bus.alive_tokens(keys.node_alive_all)}
        sees = {parse_sees_key(keys, k) for k in node.bus.alive_tokens(keys.node_sees_all)}
        observers = sorted(n for n in alive - external - {own} if n is not None)
        return ([f"{o[0]}:{o[1]}->{e[0]}:{e[1]}" for o in observers for e in sorted(external)
                 if (o, e) not in sees], len(observers) * len(external))

    deadline = time.monotonic() + timeout_s
    left, links = missing()
    while left and time.monotonic() < deadline and not (stop is not None and stop.is_set()):
        time.sleep(0.05)
        left, links = missing()
    if not left:
        log.info("every node of the run links to the external node(s) (%d link(s) echoed)", links)
    else:
        log.warning("after %.0f s, no link yet for %s (a node that does not echo, or a slow mesh): "
                    "starting the clock anyway; the first messages between them may be lost",
                    timeout_s, ", ".join(left))
    return left


def run_sim(run_dir: Path, bus_cfg: BusConfig, expect: tuple[str, ...]) -> int:
    stop = stop_event()     # first: a stop signal while the node is being built is not lost
    from sitl.node import SimulatorNode
    cfg = load_scenario(run_dir / "scenario.yaml")
    world = load_world_for(cfg)
    try:
        node = SimulatorNode(sim_node_config(cfg, world, expect), world, bus_cfg)
    except HubPortTaken as exc:
        log.error("%s; the launcher starts the run again on another port", exc)
        return EXIT_HUB_PORT_TAKEN
    threading.Thread(target=lambda: (stop.wait(), node.stop()), daemon=True).start()
    if "recorder" in expect:
        node_ready = threading.Event()
        node.bus.watch_liveliness(node.keys.node_alive("recorder", "recorder"),
                                  lambda _k, alive: node_ready.set() if alive else None)
        deadline = time.monotonic() + cfg.clock.startup_timeout_s
        while not node_ready.wait(0.2) and not stop.is_set() and time.monotonic() < deadline:
            pass
        if not node_ready.is_set() and not stop.is_set():
            log.warning("recorder did not come up; running without it")
    # the hub listens (and the recorder records): say so. The launcher waits for this file before
    # it writes run.json, so an outside node that joins from run.json never talks before the
    # recorder listens (its NodeInfo is recorded).
    write_stats(run_dir / HUB_FILE, {"hub_port": bus_cfg.hub_port})
    if not wait_external_nodes(node, cfg, run_dir, stop):
        node.close()
        return 0 if stop.is_set() else EXIT_EXTERNAL_MISSING
    links = (lambda: confirm_external_links(node, cfg, run_dir, stop)) if cfg.external.members() else None
    try:
        stats = node.run(before_clock=links)
    finally:
        node.close()
    write_stats(run_dir / "sim_stats.json", dataclasses.asdict(stats))
    return 0


def run_recorder(run_dir: Path, bus_cfg: BusConfig) -> int:
    stop = stop_event()     # first: a stop signal while the node is being built is not lost
    from scenenav.app.recorder import RecorderNode
    cfg = load_scenario(run_dir / "scenario.yaml")
    node = RecorderNode(run_dir, cfg.recorder, bus_cfg)
    # the maps of the view (viz/map/...) after the node is up: the simulator waits for it
    from scenenav.app.viz import map_messages, run_assistant_map
    node.set_viz_maps(map_messages(load_world_for(cfg), run_assistant_map(cfg)))
    stop.wait()
    info = node.close()
    write_stats(run_dir / "recorder_stats.json", info)
    return 0


def run_live(run_dir: Path, bus_cfg: BusConfig, port: int) -> int:
    stop = stop_event()     # first: a stop signal while the node is being built is not lost
    from scenenav.app.live import LiveNode
    from scenenav.app.viz import map_messages, run_assistant_map
    cfg = load_scenario(run_dir / "scenario.yaml")
    try:
        node = LiveNode(run_dir, bus_cfg, port, cfg.recorder.camera_every_n,
                        tuple(map_messages(load_world_for(cfg), run_assistant_map(cfg))))
    except RuntimeError as exc:       # the port is taken: the run flies on without a live view
        log.error("live view: cannot listen on port %d: %s", port, exc)
        return 1
    node.run(stop)
    write_stats(run_dir / "live_stats.json", node.close())
    return 0


def _perception_weights(pcfg) -> str | None:
    """What the perception node loads: a CNN .pt (paper rule) or a decision model .json (combined
    rule; it names the CNN it was fitted with)."""
    if pcfg.decision_rule == "combined":
        from perception.decision import decision_model_path
        return str(decision_model_path(pcfg.decision_model))
    return pcfg.weights or None


def perception_camera(cfg: ScenarioConfig):
    """The camera the perception node expects: the scenario's simulated camera (FOV and size)."""
    from perception.config import ExpectedCamera
    cam = cfg.sim.camera
    return ExpectedCamera(fov_deg=cam.fov_deg, width_px=cam.width_px, height_px=cam.height_px)


def run_perception(run_dir: Path | None, bus_cfg: BusConfig, method: str | None,
                   node_id: str, world_dir: str | None, assistant_map: str | None,
                   lockstep: bool | None) -> int:
    stop = stop_event()     # first: a stop signal while the node is being built is not lost
    from perception.node import PerceptionNode
    cfg = load_scenario(run_dir / "scenario.yaml") if run_dir else ScenarioConfig()
    world = load_world_for(cfg) if not world_dir else __import__(
        "worlds.world", fromlist=["load_world"]).load_world(world_dir)
    pcfg = cfg.perception
    settings = dataclasses.replace(
        pcfg, method=method or pcfg.method,
        assistant_map=assistant_map if assistant_map is not None else pcfg.assistant_map,
        lockstep=pcfg.lockstep if lockstep is None else lockstep)
    node = PerceptionNode(world, bus_cfg, node_id, settings, out_dir=run_dir, camera=perception_camera(cfg),
                          weights=_perception_weights(pcfg))
    stop.wait()
    node.close()
    return 0


def guidance_config_from_scenario(cfg: ScenarioConfig, mavlink_port: int, lockstep: bool):
    """GuidanceRunConfig + PlannerConfig from a ScenarioConfig (its flight, guidance, autopilot and
    sim.camera sections)."""
    from guidance.config import GuidanceRunConfig, PlannerConfig, RouteEnd
    g = cfg.guidance
    end = RouteEnd.RTL if cfg.autopilot.mission_end.value == "rtl" else RouteEnd.LAND
    node_cfg = GuidanceRunConfig(
        start_enu_m=tuple(cfg.flight.start_enu_m), goals_enu_m=tuple(tuple(p) for p in g.goals_enu_m),
        assistant_map=g.assistant_map, altitude_m=cfg.flight.altitude_m, end=end, snap_goals_m=g.snap_goals_m,
        replan_drift_m=g.replan_drift_m, check_period_s=g.check_period_s,
        start_after_s=g.start_after_s, mavlink_url=f"tcp:127.0.0.1:{mavlink_port}", lockstep=lockstep)
    planner_cfg = dataclasses.replace(
        PlannerConfig(), altitude_m=cfg.flight.altitude_m, camera_fov_deg=cfg.sim.camera.fov_deg,
        footprint_m=g.footprint_m, clearance_m=g.clearance_m, unvisited_weight=g.unvisited_weight,
        keep_footprint_on_map=g.keep_footprint_on_map,
        cruise_speed_m_s=cfg.flight.speed_m_s, waypoint_spacing_m=g.waypoint_spacing_m)
    return node_cfg, planner_cfg


def run_mavlink_port(run_dir: Path, timeout_s: float) -> int:
    """The MAVLink TCP port the autopilot of THIS run bound (``<run>/mavlink.json``, written once
    it is bound; waited for up to ``timeout_s``), never a port from the configuration that another
    run may hold."""
    from scenenav.core.errors import UserError
    from scenenav.core.formats.run_folder import MAVLINK_FILE
    path = run_dir / MAVLINK_FILE
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            port = json.loads(path.read_text()).get("tcp_port")
        except (OSError, ValueError, AttributeError):
            port = None
        else:
            if not port:
                raise UserError(f"{path}: the autopilot of this run serves no MAVLink TCP port; "
                                "guidance needs autopilot.mavlink_tcp_port != 0")
            return int(port)
        if time.monotonic() > deadline:
            raise UserError(f"{path}: not written within {timeout_s:.0f} s; expected the autopilot "
                            "of this run to report its MAVLink ports")
        time.sleep(0.1)


def run_guidance(run_dir: Path, bus_cfg: BusConfig) -> int:
    stop = stop_event()     # first: a stop signal while the node is being built is not lost
    from guidance.node import GuidanceNode
    from scenenav.core.contracts import ClockMode
    from scenenav.core.formats.world_manifest import read_manifest
    from worlds.default import world_folder
    cfg = load_scenario(run_dir / "scenario.yaml")
    world = read_manifest(world_folder(cfg.world))
    node_cfg, planner_cfg = guidance_config_from_scenario(
        cfg, run_mavlink_port(run_dir, cfg.clock.startup_timeout_s),
        lockstep=cfg.clock.mode == ClockMode.LOCKSTEP)
    node = GuidanceNode(world, bus_cfg, node_cfg, planner_cfg, out_dir=run_dir)
    threading.Thread(target=lambda: (stop.wait(), node.stop()), daemon=True).start()
    try:
        node.run()
        if node.failure is not None:
            # the mission can never start: a failed node, named in the run's summary
            log.error("guidance: %s", node.failure)
            return 1
        stop.wait()          # stay up (liveliness) until the launcher stops the run
    finally:
        stats = node.close()
        write_stats(run_dir / "guidance_stats.json", stats)
    return 0


def world_manifest(cfg: ScenarioConfig):
    """The scenario world's manifest (no images loaded)."""
    from scenenav.core.formats.world_manifest import read_manifest
    from worlds.default import world_folder
    return read_manifest(world_folder(cfg.world))


def scenario_route(cfg: ScenarioConfig) -> tuple[tuple[float, float], ...]:
    """The scenario's route (``flight.route_enu_m``, or the route fitted to the world)."""
    if cfg.flight.route_enu_m:
        return cfg.flight.route_enu_m
    m = world_manifest(cfg)
    shape = SimpleNamespace(width_px=m.width_px, height_px=m.height_px, m_per_px=m.m_per_px,
                            manifest=m)
    return route_for(cfg, shape)


def autopilot_setup(cfg: ScenarioConfig, origin_lat_lon_deg: tuple[float, float] | None = None):
    """The autopilot node's setup for a scenario: its section, the world's geodetic origin (read from
    the world unless given), the take-off point, the position source (external navigation without
    GPS) and, for an autopilot flight without a guidance node, the route it flies by itself."""
    from autopilot_bridge.config import AutopilotSetup, FlightCoreConfig, PositionSource, RouteMission
    if origin_lat_lon_deg is None:
        m = world_manifest(cfg)
        origin_lat_lon_deg = (m.origin_lat_deg, m.origin_lon_deg)
    start = cfg.flight.start_enu_m
    core = FlightCoreConfig(origin_lat_deg=origin_lat_lon_deg[0], origin_lon_deg=origin_lat_lon_deg[1],
                            start_enu_m=(float(start[0]), float(start[1])))
    autopilot_flight = cfg.flight.mode == FlightMode.AUTOPILOT
    mission = None
    if autopilot_flight and cfg.autopilot.auto_start and not cfg.guidance.enabled:
        # with a guidance node the mission comes over MAVLink from that node instead
        mission = RouteMission(scenario_route(cfg), cfg.flight.altitude_m)
    return AutopilotSetup(
        node=cfg.autopilot, core=core,
        position_source=PositionSource.GPS if cfg.sim.gps.enabled else PositionSource.EXTNAV,
        mission=mission, mission_ends_run=autopilot_flight)


def run_autopilot(run_dir: Path | None, bus_cfg: BusConfig) -> int:
    stop = stop_event()     # first: a stop signal while the node is being built is not lost
    from autopilot_bridge.node import AutopilotNode
    cfg = load_scenario(run_dir / "scenario.yaml") if run_dir else ScenarioConfig()
    node = AutopilotNode(autopilot_setup(cfg), bus_cfg, run_dir)
    try:
        stop.wait()
    finally:
        node.close()
    return 0
