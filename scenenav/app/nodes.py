"""``scenenav node <kind>``: the entry point of each child process of a run.

Every node reads the run's resolved scenario (``<run>/scenario.yaml``), joins the bus of the run
(namespace + hub port), logs to stderr (the launcher sends it to ``<run>/logs/<node>.log``) and stops
cleanly on SIGINT/SIGTERM.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import signal
import threading
from pathlib import Path

from scenenav.core.bus import BusConfig
from scenenav.core.contracts import LockstepRole
from scenenav.app.scenario import FlightMode, ScenarioConfig, load_scenario, route_for

log = logging.getLogger(__name__)


def _stop_event() -> threading.Event:
    ev = threading.Event()

    def handler(signum, _frame):
        log.info("signal %d: stopping", signum)
        ev.set()
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return ev


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


def run_sim(run_dir: Path, bus_cfg: BusConfig, expect: tuple[str, ...]) -> int:
    from sitl.node import SimulatorNode
    cfg = load_scenario(run_dir / "scenario.yaml")
    world = load_world_for(cfg)
    node = SimulatorNode(sim_node_config(cfg, world, expect), world, bus_cfg)
    stop = _stop_event()
    threading.Thread(target=lambda: (stop.wait(), node.stop()), daemon=True).start()
    if "recorder" in expect:
        node_ready = threading.Event()
        node.bus.watch_liveliness(node.keys.node_alive("recorder", "recorder"),
                                  lambda _k, alive: node_ready.set() if alive else None)
        if not node_ready.wait(cfg.clock.startup_timeout_s):
            log.warning("recorder did not come up; running without it")
    try:
        stats = node.run()
    finally:
        node.close()
    (run_dir / "sim_stats.json").write_text(json.dumps(dataclasses.asdict(stats), indent=2, default=str))
    return 0


def run_recorder(run_dir: Path, bus_cfg: BusConfig) -> int:
    from scenenav.app.recorder import RecorderNode
    cfg = load_scenario(run_dir / "scenario.yaml")
    node = RecorderNode(run_dir, cfg.recorder, bus_cfg)
    stop = _stop_event()
    stop.wait()
    info = node.close()
    (run_dir / "recorder_stats.json").write_text(json.dumps(info, indent=2))
    return 0


def _perception_weights(pcfg) -> str | None:
    """What the perception node loads: a CNN .pt (paper rule) or a decision model .json (combined
    rule; it names the CNN it was fitted with)."""
    if pcfg.decision_rule == "combined":
        if pcfg.decision_model:
            return pcfg.decision_model
        from perception.decision import DEFAULT_DECISION_MODEL
        return str(DEFAULT_DECISION_MODEL)
    return pcfg.weights or None


def run_perception(run_dir: Path | None, bus_cfg: BusConfig, method: str | None,
                   node_id: str, world_dir: str | None, assistant_map: str | None,
                   lockstep: bool | None) -> int:
    from perception.node import PerceptionNode
    cfg = load_scenario(run_dir / "scenario.yaml") if run_dir else ScenarioConfig()
    world = load_world_for(cfg) if not world_dir else __import__(
        "worlds.world", fromlist=["load_world"]).load_world(world_dir)
    pcfg = cfg.perception
    node = PerceptionNode(
        world, bus_cfg, node_id=node_id, method=method or pcfg.method,
        assistant_map_path=assistant_map if assistant_map is not None else (pcfg.assistant_map or None),
        lockstep=pcfg.lockstep if lockstep is None else lockstep,
        out_dir=run_dir, weights=_perception_weights(pcfg))
    stop = _stop_event()
    stop.wait()
    node.close()
    return 0


def run_guidance(run_dir: Path, bus_cfg: BusConfig) -> int:
    from guidance.node import GuidanceNode, node_config_from_scenario
    from guidance.route import load_world_manifest
    from scenenav.core.contracts import ClockMode
    from worlds.default import world_folder
    cfg = load_scenario(run_dir / "scenario.yaml")
    world = load_world_manifest(world_folder(cfg.world))
    node_cfg, planner_cfg = node_config_from_scenario(
        cfg, cfg.autopilot.mavlink_tcp_port, lockstep=cfg.clock.mode == ClockMode.LOCKSTEP)
    node = GuidanceNode(world, bus_cfg, node_cfg, planner_cfg, out_dir=run_dir)
    stop = _stop_event()
    threading.Thread(target=lambda: (stop.wait(), node.stop()), daemon=True).start()
    try:
        node.run()
        stop.wait()          # stay up (liveliness) until the launcher stops the run
    finally:
        stats = node.close()
        (run_dir / "guidance_stats.json").write_text(json.dumps(stats, indent=2))
    return 0
