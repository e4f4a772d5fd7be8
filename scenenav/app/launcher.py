"""``scenenav run``: start every node of a scenario as a child process, fly it, write the run folder.

Children are started in their own process group so that Ctrl-C reaches only the launcher, which
then stops them in order (simulator first, recorder last) with SIGINT, escalating to SIGTERM and
SIGKILL after a grace period: no orphans, and the logs are closed properly.
"""

from __future__ import annotations

import json
import logging
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from scenenav.app.scenario import FlightMode, ScenarioConfig, load_scenario, scenario_to_dict
from scenenav.app.signals import interrupt_on_stop_signals
from scenenav.core.bus import free_port
from scenenav.core.contracts import ClockMode
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

GRACE_S = 10.0
_PR_SET_PDEATHSIG = 1   # linux/prctl.h


def die_with_parent() -> None:
    """In the child, before exec: get SIGTERM if the parent (its thread) dies, even by SIGKILL (Linux)."""
    try:
        import ctypes
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass   # not Linux: rely on the launcher's own shutdown


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log_file: object


@dataclass
class Launch:
    run_dir: Path
    namespace: str
    hub_port: int
    children: list[Child] = field(default_factory=list)

    def spawn(self, name: str, args: list[str]) -> Child:
        logs = self.run_dir / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        f = (logs / f"{name}.log").open("ab")
        cmd = [sys.executable, "-m", "scenenav.app.cli", "--log-level", "INFO", "node", *args,
               "--namespace", self.namespace, "--hub-port", str(self.hub_port)]
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True, preexec_fn=die_with_parent)
        child = Child(name, proc, f)
        self.children.append(child)
        pids = {c.name: c.proc.pid for c in self.children}
        (self.run_dir / "logs" / "pids.json").write_text(json.dumps(pids))
        log.info("started %s (pid %d)", name, proc.pid)
        return child

    def stop_all(self, order: list[str] | None = None) -> None:
        names = order or [c.name for c in self.children]
        for name in names:
            for c in self.children:
                if c.name == name:
                    _stop(c)
        for c in self.children:
            _stop(c)
            c.log_file.close()


def _stop(c: Child) -> None:
    if c.proc.poll() is not None:
        return
    for sig, wait in ((signal.SIGINT, GRACE_S), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        try:
            c.proc.send_signal(sig)
        except ProcessLookupError:
            return
        try:
            c.proc.wait(wait)
            return
        except subprocess.TimeoutExpired:
            log.warning("%s did not stop on %s", c.name, sig.name)


def _port_free(port: int) -> bool:
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _free_mavlink_port(cfg: ScenarioConfig) -> ScenarioConfig:
    """Scenario runs are independent: if the autopilot's MAVLink TCP port is taken (another run,
    a real SITL), use a free one instead (written to scenario.yaml and run.json)."""
    import dataclasses
    port = cfg.autopilot.mavlink_tcp_port
    if cfg.flight.mode != FlightMode.AUTOPILOT or port == 0 or _port_free(port):
        return cfg
    new = free_port()
    log.warning("MAVLink TCP port %d is in use: this run serves MAVLink on %d", port, new)
    return dataclasses.replace(cfg, autopilot=dataclasses.replace(cfg.autopilot, mavlink_tcp_port=new))


def _resolve_guidance_map(cfg: ScenarioConfig, progress: bool) -> ScenarioConfig:
    """Guidance without a named assistant map plans over the world's map built with the CNN
    (cached); the run's scenario.yaml records which file was used."""
    import dataclasses
    g = cfg.guidance
    if not g.enabled:
        return cfg
    if g.assistant_map:
        if not Path(g.assistant_map).is_file():
            raise UserError(f"guidance.assistant_map = {g.assistant_map!r}: no such file; expected an "
                            "assistant map .npz (scenenav assistant-map build), or empty to build one")
        return cfg
    from perception.map_cache import cached_assistant_map
    from worlds.default import world_folder
    path = cached_assistant_map(world_folder(cfg.world), g.assistant_map_stride_px,
                                cfg.flight.altitude_m, cfg.sim.camera.fov_deg,
                                cfg.perception.weights if cfg.perception.weights.endswith(".pt") else None,
                                progress=progress and sys.stderr.isatty())
    return dataclasses.replace(cfg, guidance=dataclasses.replace(g, assistant_map=str(path)))


def spawn_recorder_and_perception(launch: Launch, cfg: ScenarioConfig) -> list[str]:
    """Start the recorder and (if enabled) the perception node; returns the lockstep members they
    add (``camera`` for a lockstep perception node)."""
    launch.spawn("recorder", ["recorder", "--run-dir", str(launch.run_dir)])
    if not cfg.perception.enabled:
        return []
    launch.spawn("perception", ["perception", "--run-dir", str(launch.run_dir), "--node-id", "perception"])
    return ["camera"] if cfg.perception.lockstep else []


def prepare_run(cfg: ScenarioConfig, world, run_dir: Path, label: str, prefix: str) -> Launch:
    """Create the run folder (must be new or empty) with scenario.yaml and run.json, and the
    Launch holding the run's own namespace and hub port."""
    if run_dir.exists() and any(run_dir.iterdir()):
        raise UserError(f"{run_dir}: run folder exists and is not empty (choose a new --out)")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "scenario.yaml").write_text(yaml.safe_dump(scenario_to_dict(cfg), sort_keys=False))
    launch = Launch(run_dir, f"{prefix}-{uuid.uuid4().hex[:12]}", free_port())
    meta = {"scenario": label, "namespace": launch.namespace, "hub_port": launch.hub_port,
            "world": world.manifest.name, "mavlink_tcp_port": cfg.autopilot.mavlink_tcp_port,
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    (run_dir / "run.json").write_text(json.dumps(meta, indent=2))
    return launch


def resolve_world(cfg: ScenarioConfig):
    from scenenav.app.nodes import load_world_for
    return load_world_for(cfg)


def run(scenario_path: str | None, out_dir: str, overrides: tuple[str, ...] = (),
        progress: bool = True) -> dict:
    """Fly one scenario into ``out_dir``; Ctrl-C and SIGTERM stop every node cleanly (the summary is
    still written, then KeyboardInterrupt is raised again)."""
    with interrupt_on_stop_signals():
        return _run(scenario_path, out_dir, overrides, progress)


def _run(scenario_path: str | None, out_dir: str, overrides: tuple[str, ...], progress: bool) -> dict:
    cfg = load_scenario(scenario_path, overrides)
    world = resolve_world(cfg)          # fail early, with a one-line error, on a bad world
    cfg = _free_mavlink_port(cfg)
    cfg = _resolve_guidance_map(cfg, progress)
    launch = prepare_run(cfg, world, Path(out_dir), scenario_path or "(defaults)", "run")
    run_dir = launch.run_dir

    expect = ["recorder"]
    interrupted = False
    wall0 = time.time()
    try:
        expect += spawn_recorder_and_perception(launch, cfg)
        if cfg.flight.mode == FlightMode.AUTOPILOT:
            launch.spawn("autopilot", ["autopilot", "--run-dir", str(run_dir)])
            expect.append("tick")
        if cfg.guidance.enabled:
            launch.spawn("guidance", ["guidance", "--run-dir", str(run_dir)])
            if cfg.clock.mode == ClockMode.LOCKSTEP:
                expect.append("tick")
        sim = launch.spawn("sim", ["sim", "--run-dir", str(run_dir), "--expect", ",".join(expect)])
        swap = PerceptionSwap(launch, cfg) if cfg.perception.enabled and cfg.perception.swap_at_s > 0 \
            else None
        _wait_sim(sim, launch, cfg, progress, swap)
    except KeyboardInterrupt:
        interrupted = True
        log.warning("interrupted: stopping every node")
    finally:
        launch.stop_all(order=["sim", "guidance", "autopilot", "perception", SWAP_NODE_ID,
                               "recorder"])
    wall = time.time() - wall0
    from scenenav.app.evaluation import evaluate_run
    summary = evaluate_run(run_dir, cfg, world, wall_time_s=wall, interrupted=interrupted)
    failed = [c.name for c in launch.children if c.proc.returncode not in (0, None, -2, 130)]
    if failed:
        summary["failed_nodes"] = failed
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    if interrupted:
        raise KeyboardInterrupt
    return summary


SWAP_NODE_ID = "perception-2"
#: Wall seconds the first perception node is kept after the swap started when the second one has
#: not produced a fix yet (it is stopped anyway then, with a warning).
SWAP_HANDOVER_TIMEOUT_S = 60.0


class PerceptionSwap:
    """``perception.swap_at_s``: start a second perception node (``perception-2``, method
    ``perception.swap_method``) on the live bus at that simulated time, and stop the first one as soon
    as the second has published a fix (make-before-break, as an operator would swap nodes by hand)."""

    def __init__(self, launch: Launch, cfg: ScenarioConfig) -> None:
        self.launch = launch
        self.cfg = cfg
        self.started_wall: float | None = None
        self.done = False

    def poll(self, sim_t_s: float | None) -> None:
        if self.done:
            return
        p = self.cfg.perception
        if self.started_wall is None:
            if sim_t_s is not None and sim_t_s >= p.swap_at_s:
                self.launch.spawn(SWAP_NODE_ID, ["perception", "--run-dir", str(self.launch.run_dir),
                                                 "--node-id", SWAP_NODE_ID, "--method", p.swap_method])
                self.started_wall = time.monotonic()
                log.info("perception swap at %.1f s: %s -> %s", sim_t_s, p.method, p.swap_method)
            return
        answered = _fixes_from(self.launch.run_dir, SWAP_NODE_ID)
        late = time.monotonic() - self.started_wall > SWAP_HANDOVER_TIMEOUT_S
        if answered or late:
            if late and not answered:
                log.warning("%s produced no fix within %.0f s; stopping the first node anyway",
                            SWAP_NODE_ID, SWAP_HANDOVER_TIMEOUT_S)
            for c in self.launch.children:
                if c.name == "perception":
                    _stop(c)
            self.done = True


def _tail(path: Path, n_bytes: int) -> bytes:
    """The last ``n_bytes`` of a file being written by another process (b"" if unreadable)."""
    try:
        with path.open("rb") as f:
            f.seek(max(0, path.stat().st_size - n_bytes))
            return f.read()
    except OSError:
        return b""


def _fixes_from(run_dir: Path, node_id: str) -> bool:
    """Has fixes.csv a row from ``node_id`` (read from the end of the file)?"""
    return f",{node_id},".encode() in _tail(run_dir / "fixes.csv", 20000)


def _wait_sim(sim: Child, launch: Launch, cfg: ScenarioConfig, progress: bool,
              swap: PerceptionSwap | None = None) -> None:
    """Wait for the simulator to end; show progress from its log of simulated time."""
    bar = None
    if progress and sys.stderr.isatty():
        from tqdm import tqdm
        bar = tqdm(total=round(cfg.duration_s), unit="sim s", desc=cfg.name, leave=False)
    while sim.proc.poll() is None:
        for c in launch.children:
            if c is not sim and c.proc.poll() is not None and c.proc.returncode not in (0, -2, 130):
                log.error("%s exited with code %s (see logs/%s.log)", c.name, c.proc.returncode, c.name)
        time.sleep(0.25)
        if swap is not None:
            swap.poll(_sim_progress(launch.run_dir))
        if bar is not None:
            t = _sim_progress(launch.run_dir)
            if t is not None:
                bar.n = min(round(t), bar.total)
                bar.refresh()
    if bar is not None:
        bar.close()
    if sim.proc.returncode != 0:
        log.error("simulator exited with code %s (see %s)", sim.proc.returncode,
                  launch.run_dir / "logs" / "sim.log")


def _sim_progress(run_dir: Path) -> float | None:
    try:
        return float(_tail(run_dir / "truth.csv", 400).splitlines()[-1].split(b",")[0])
    except (IndexError, ValueError):
        return None
