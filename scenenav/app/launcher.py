"""``scenenav run``: start every node of a scenario as a child process, fly it, write the run folder.

Before any process starts, every input the run will read is checked with the nodes' own readers
(``scenenav.app.preflight``) and the run's disk must have ``recorder.min_free_disk_mb`` free: a bad
file or a full disk is one ``error: ...`` line and exit 2, and leaves nothing behind.

Children are started in their own process group so that Ctrl-C reaches only the launcher, which
then stops them in order (simulator first, recorder last) with SIGINT, escalating to SIGTERM and
SIGKILL after a grace period, and finally kills whatever is left in each child's process group
(a grandchild such as the camera render worker): no process outlives the run. A child that dies
on its own is reported once, with the last error line of its log, and lands in the summary
(``node_failures``); an unfinished ``bus.mcap`` (recorder killed) is recovered from its whole
chunks. See docs/faults.md.
"""

from __future__ import annotations

import dataclasses
import errno
import ipaddress
import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from scenenav.app.evaluation import NodeFailure, last_sim_time_s, last_status
from scenenav.app.mavlink_claim import DEFAULT_SYSID, SysidClaim, claim_sysid
from scenenav.app.nodes import EXIT_EXTERNAL_MISSING

LIVE_FILE = "live.json"           # written by the live node (scenenav.app.live): its port and URL
from scenenav.app.preflight import check_free_space, free_bytes, mount_point, validate_inputs
from scenenav.app.scenario import FlightMode, ScenarioConfig, load_scenario, scenario_to_dict
from scenenav.app.signals import interrupt_on_stop_signals, stop_signals_deferred, unblock_stop_signals
from scenenav.core.bus import EXIT_HUB_PORT_TAKEN, free_port
from scenenav.core.contracts import ClockMode, LockstepRole
from scenenav.core.errors import UserError
from scenenav.core.formats.atomic_file import write_atomic
from scenenav.core.formats.run_folder import HUB_FILE, MAVLINK_FILE
from scenenav.core.parent_death import set_parent_death_signal

log = logging.getLogger(__name__)

GRACE_S = 10.0
#: Space set aside in the run folder at start (``.disk_reserve``) and given back when the disk fills,
#: so the nodes' closing files, the summary and the plot still fit on a full disk.
DISK_RESERVE_MB = 8.0
#: Free space below which the launcher ends the run (the disk is full: nothing more is recorded).
DISK_LOW_WATER_MB = 1.0
RESERVE_FILE = ".disk_reserve"


def die_with_parent() -> None:
    """In the child, before exec: get SIGTERM if the parent (its thread) dies, even by SIGKILL (Linux);
    the stop signals the launcher blocked while spawning are unblocked."""
    unblock_stop_signals()
    set_parent_death_signal(signal.SIGTERM)   # not Linux: the launcher's own shutdown stops them


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log_file: object
    log_path: Path | None = None
    stopping: bool = False        # the launcher is stopping it: its exit is not a failure
    args: list[str] = field(default_factory=list)   # what ``Launch.spawn`` was given (a restart's)


RUN_FILE = "run.json"
#: The node id of the second perception node a swap starts.
SWAP_NODE_ID = "perception-2"
#: The order ``Launch.stop_all`` stops a run in: the simulator (the clock) first, then the nodes
#: together, the recorder last.
STOP_STAGES = [["sim"], ["guidance", "autopilot", "perception", SWAP_NODE_ID, "live"], ["recorder"]]


@dataclass
class Launch:
    run_dir: Path
    namespace: str
    hub_port: int
    listen_host: str = "127.0.0.1"     # external.listen_host: every node listens there
    children: list[Child] = field(default_factory=list)
    #: what run.json holds; written only once the hub listens (``publish_run_json``)
    meta: dict = field(default_factory=dict)
    published: bool = False

    def update_meta(self, **fields) -> None:
        """Add ``fields`` to run.json's contents (and to the file, once it is published)."""
        self.meta.update(fields)
        if self.published:
            write_atomic(self.run_dir / RUN_FILE, json.dumps(self.meta, indent=2))

    def publish_run_json(self) -> None:
        """Write run.json: the hub listens on ``hub_port`` now, so a node may read it and join."""
        self.meta.update(hub_port=self.hub_port,
                         bus=bus_facts(self.namespace, self.hub_port, self.listen_host))
        write_atomic(self.run_dir / RUN_FILE, json.dumps(self.meta, indent=2))
        self.published = True

    def spawn(self, name: str, args: list[str]) -> Child:
        logs = self.run_dir / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        f = (logs / f"{name}.log").open("ab")
        cmd = [sys.executable, "-m", "scenenav.app.cli", "--log-level", "INFO", "node", *args,
               "--namespace", self.namespace, "--hub-port", str(self.hub_port),
               "--listen-host", self.listen_host, "--hub-host", hub_host(self.listen_host)]
        with stop_signals_deferred():     # a Ctrl-C now would leave a started child unrecorded
            proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True, preexec_fn=die_with_parent)
            child = Child(name, proc, f, logs / f"{name}.log", args=list(args))
            self.children.append(child)
        pids = {c.name: c.proc.pid for c in self.children}
        # atomic: tests, benchmarks and campaign clean-up read it while the next child starts
        write_atomic(self.run_dir / "logs" / "pids.json", json.dumps(pids))
        log.info("started %s (pid %d)", name, proc.pid)
        return child

    def stop_all(self, stages: list[list[str]] | None = None) -> None:
        """Stop the children stage by stage (``STOP_STAGES``: the simulator first, so nobody waits
        for a tick, the recorder last, so it records the others' last words), each stage's
        children together; then any child no stage named; then whatever their groups left."""
        for stage in stages or []:
            _stop_together([c for c in self.children if c.name in stage])
        _stop_together(self.children)
        for c in self.children:
            c.log_file.close()
        self.kill_groups()

    def kill_groups(self) -> None:
        """SIGKILL whatever is left in the children's process groups (each child leads its own)."""
        for c in self.children:
            try:
                os.killpg(c.proc.pid, 0)
            except (ProcessLookupError, PermissionError):
                continue
            log.warning("a process of %s's group outlived it: killed", c.name)
            try:
                os.killpg(c.proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass


def _stop_together(children: list[Child]) -> None:
    """SIGINT to all of ``children`` at once, then SIGTERM and SIGKILL to those still running after
    each grace time: stopping N nodes costs one grace time, not N."""
    for c in children:
        c.stopping = True
    for sig, wait_s in ((signal.SIGINT, GRACE_S), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        running = [c for c in children if c.proc.poll() is None]
        if not running:
            return
        if sig != signal.SIGINT:
            log.warning("%s did not stop: %s", ", ".join(c.name for c in running), sig.name)
        for c in running:
            try:
                c.proc.send_signal(sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + wait_s
        for c in running:
            try:
                c.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass


def _claim_sysid(cfg: ScenarioConfig, out_dir: Path) -> tuple[ScenarioConfig, SysidClaim | None]:
    """Claim the run's MAVLink system id on its UDP output (``scenenav.app.mavlink_claim``): a
    distinct id from every other live run sending there, written to the scenario."""
    a = cfg.autopilot
    if cfg.flight.mode != FlightMode.AUTOPILOT or a.udp_target is None:
        return cfg, None
    from autopilot_bridge.params import load_param_file
    file_params = load_param_file(Path(a.params_file)) if a.params_file else {}
    chosen = "SYSID_THISMAV" in a.params or "SYSID_THISMAV" in file_params
    wanted = int(a.params.get("SYSID_THISMAV", file_params.get("SYSID_THISMAV", DEFAULT_SYSID)))
    host, port = a.udp_target
    claim = claim_sysid(f"{host}:{port}", wanted, chosen, owner=str(Path(out_dir).absolute()))
    if claim.system_id == wanted:
        return cfg, claim
    log.warning("MAVLink system %d is used by another live run sending to UDP %s:%d: this run is "
                "system %d (SYSID_THISMAV)", wanted, host, port, claim.system_id)
    params = {**a.params, "SYSID_THISMAV": claim.system_id}
    return dataclasses.replace(cfg, autopilot=dataclasses.replace(a, params=params)), claim


#: Wall seconds the launcher waits for the autopilot to bind its MAVLink endpoints.
MAVLINK_READY_TIMEOUT_S = 90.0


def await_mavlink(launch: Launch, autopilot: Child, timeout_s: float = MAVLINK_READY_TIMEOUT_S
                  ) -> dict | None:
    """Wait for the autopilot's ``mavlink.json`` (the ports it bound) and write them into run.json,
    so that run.json names the true endpoints of this run. None if the autopilot died first."""
    path = launch.run_dir / MAVLINK_FILE
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            info = json.loads(path.read_text())
        except (OSError, ValueError):
            info = None
        if isinstance(info, dict):
            launch.update_meta(mavlink_tcp_port=info.get("tcp_port"),
                               mavlink_udp_port=info.get("udp_port"),
                               mavlink_udp_out=info.get("udp_out"),
                               mavlink_system_id=info.get("system_id"))
            return info
        if autopilot.proc.poll() is not None:
            return None
        time.sleep(0.05)
    log.warning("the autopilot did not report its MAVLink ports within %.0f s", timeout_s)
    return None


#: Starts of a run whose hub port another process took meanwhile, before giving up.
HUB_ATTEMPTS = 5


def await_hub(launch: Launch, sim: Child, timeout_s: float = MAVLINK_READY_TIMEOUT_S) -> bool:
    """Wait until the simulator's Zenoh hub listens (its ``hub.json``), then write run.json (it
    does not exist before: a node that sees run.json can join at once). False when the simulator exited because the port was taken meanwhile (the port
    was chosen free, but another process may bind it before the simulator does): the caller starts
    the run again on another port. True otherwise (a simulator that dies of something else is
    reported by the ChildWatch as usual)."""
    path = launch.run_dir / HUB_FILE
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.is_file():
            launch.publish_run_json()
            return True
        code = sim.proc.poll()
        if code is not None:
            return code != EXIT_HUB_PORT_TAKEN
        time.sleep(0.05)
    log.warning("the simulator did not report its Zenoh hub within %.0f s", timeout_s)
    launch.publish_run_json()
    return True


def restart_on_new_hub_port(launch: Launch) -> None:
    """Stop every child of a start whose hub port was taken, and choose a new port."""
    old = launch.hub_port
    launch.stop_all()
    launch.children.clear()
    for name in (MAVLINK_FILE, HUB_FILE):
        (launch.run_dir / name).unlink(missing_ok=True)
    launch.hub_port = free_port(launch.listen_host)
    log.warning("the Zenoh hub port %d was taken before the simulator could listen on it: starting "
                "the run again on port %d", old, launch.hub_port)


def resolve_guidance_map(cfg: ScenarioConfig, progress: bool) -> ScenarioConfig:
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
    folder = world_folder(cfg.world)
    stride_m = g.assistant_map_stride_m
    if g.assistant_map_stride_px > 0:     # the stride in pixels of this world (older scenarios)
        from scenenav.core.formats.world_manifest import read_manifest
        stride_m = g.assistant_map_stride_px * read_manifest(folder).m_per_px
    path = cached_assistant_map(folder, stride_m,
                                cfg.flight.altitude_m, cfg.sim.camera.fov_deg,
                                cfg.perception.weights if cfg.perception.weights.endswith(".pt") else None,
                                progress=progress and sys.stderr.isatty(),
                                relief=cfg.sim.camera.relief and g.assistant_map_source == "captures",
                                reference=cfg.perception.reference,
                                announce=(lambda text: print(text, file=sys.stderr, flush=True))
                                if progress else None)
    return dataclasses.replace(cfg, guidance=dataclasses.replace(g, assistant_map=str(path)))


def spawn_recorder_and_perception(launch: Launch, cfg: ScenarioConfig,
                                  live_port: int | None = None) -> list[str]:
    """Start the recorder, the live view (``live_port`` not None; never a lockstep member) and (if
    enabled, and no external node has the role) the perception node; returns the lockstep members
    they add (``camera`` for each lockstep perception node, the external ones included)."""
    launch.spawn("recorder", ["recorder", "--run-dir", str(launch.run_dir)])
    if live_port is not None:
        (launch.run_dir / LIVE_FILE).unlink(missing_ok=True)
        launch.spawn("live", ["live", "--run-dir", str(launch.run_dir), "--live-port", str(live_port)])
    external = cfg.external.of_role("perception")
    camera = [LockstepRole.CAMERA.value] if cfg.perception.lockstep else []
    if external:
        return camera * len(external)
    if not cfg.perception.enabled:
        return []
    launch.spawn("perception", ["perception", "--run-dir", str(launch.run_dir), "--node-id", "perception"])
    return camera


def hub_host(listen_host: str) -> str:
    """Where a node on this machine connects to a hub listening on ``listen_host``: loopback, unless
    the hub listens on one interface's address only (then nothing answers on 127.0.0.1)."""
    return "127.0.0.1" if listen_host == "0.0.0.0" or ipaddress.IPv4Address(listen_host).is_loopback \
        else listen_host


def bus_facts(namespace: str, hub_port: int, listen_host: str = "127.0.0.1") -> dict:
    """run.json's ``bus``: where a node connects and the key prefix of the run; with a
    ``listen_host`` other than loopback also ``listen_host`` and ``remote_endpoints`` (where a node
    on another machine connects: that address, or for 0.0.0.0 this machine's interface addresses)."""
    facts: dict = {"endpoint": f"tcp/{hub_host(listen_host)}:{hub_port}", "namespace": namespace,
                   "key_prefix": f"scenenav/{namespace}"}
    if not ipaddress.IPv4Address(listen_host).is_loopback:
        hosts = interface_addresses() if listen_host == "0.0.0.0" else [listen_host]
        facts.update(listen_host=listen_host, remote_endpoints=[f"tcp/{h}:{hub_port}" for h in hosts])
    return facts


def interface_addresses() -> list[str]:
    """This machine's IPv4 addresses other than loopback (``ip -4 addr``; [] if none or no ``ip``)."""
    try:
        out = subprocess.run(["ip", "-4", "-o", "addr", "show"], capture_output=True, text=True,
                             timeout=5, check=False).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    found = re.findall(r"\binet (\d+\.\d+\.\d+\.\d+)/", out)
    return [a for a in found if not ipaddress.IPv4Address(a).is_loopback]


def node_facts(cfg: ScenarioConfig, world) -> dict:
    """What a node needs to work in this run, for run.json: the world folder, the reference map it
    matches against, the assistant map if any, the camera (docs/interfaces.md section 1)."""
    from scenenav.core.camera_geometry import focal_length_px
    from scenenav.core.formats.world_manifest import ReferenceKind, reference_file
    from worlds.default import world_folder
    folder = world_folder(cfg.world).resolve()
    ref = cfg.perception.reference
    kind = world.manifest.reference.kind if ref == "default" else ReferenceKind(ref)
    reference = reference_file(world.manifest, kind)
    amap = cfg.perception.assistant_map or cfg.guidance.assistant_map
    cam = cfg.sim.camera
    f = focal_length_px(cam.width_px, cam.fov_deg)
    return {
        "world_dir": str(folder), "reference_map": str(folder / reference),
        "reference_kind": kind.value, "m_per_px": world.m_per_px,
        "assistant_map": str(Path(amap).resolve()) if amap else None,
        "camera": {"width_px": cam.width_px, "height_px": cam.height_px, "fov_deg": cam.fov_deg,
                   "fov_axis": "width", "fx_px": f, "fy_px": f,
                   "cx_px": (cam.width_px - 1) / 2.0, "cy_px": (cam.height_px - 1) / 2.0,
                   "rate_hz": cam.rate_hz, "latency_s": cam.latency_s, "mount": cam.mount.value},
        "clock_mode": cfg.clock.mode.value,
        "external": list(cfg.external.nodes),
        "external_join_timeout_s": cfg.external.join_timeout_s,
    }


def prepare_run(cfg: ScenarioConfig, world, run_dir: Path, label: str, prefix: str,
                reserve_mb: float = 0.0) -> Launch:
    """Create the run folder (must be new or empty) with scenario.yaml, and the Launch holding the
    run's own namespace, hub port and the contents of run.json (written once the hub listens). ``reserve_mb`` > 0: also set that much
    disk aside (``.disk_reserve``; the caller gives it back with ``DiskWatch.release``)."""
    if run_dir.exists() and any(run_dir.iterdir()):
        raise UserError(f"{run_dir}: run folder exists and is not empty (choose a new --out)")
    check_free_space(run_dir, cfg.recorder.min_free_disk_mb)
    created = not run_dir.exists()
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_atomic(run_dir / "scenario.yaml", yaml.safe_dump(scenario_to_dict(cfg), sort_keys=False))
        host = cfg.external.listen_host
        launch = Launch(run_dir, f"{prefix}-{uuid.uuid4().hex[:12]}", free_port(host), host)
        launch.meta = {"scenario": label, "namespace": launch.namespace, "hub_port": launch.hub_port,
                       "world": world.manifest.name, **node_facts(cfg, world),
                       "mavlink_tcp_port": cfg.autopilot.mavlink_tcp_port,
                       "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        if reserve_mb > 0:
            _reserve(run_dir / RESERVE_FILE, reserve_mb)
    except OSError as exc:
        for name in ("scenario.yaml", "run.json", RESERVE_FILE):
            (run_dir / name).unlink(missing_ok=True)
        if created:
            shutil.rmtree(run_dir, ignore_errors=True)
        raise UserError(disk_error_line(run_dir, exc)) from None
    return launch


#: Wall seconds the launcher waits for the live view to report its port.
LIVE_READY_TIMEOUT_S = 30.0


def announce_live(launch: Launch, announce: Callable[[str], None],
                  timeout_s: float = LIVE_READY_TIMEOUT_S) -> str | None:
    """Wait for the live node's ``live.json`` and ``announce`` its URL (one line); None (and a
    warning) when it did not come up (e.g. its port is taken: the run flies on without it)."""
    path = launch.run_dir / LIVE_FILE
    live = next((c for c in launch.children if c.name == "live"), None)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            url = json.loads(path.read_text())["url"]
        except (OSError, ValueError, KeyError):
            url = None
        if url:
            announce(f"live view: {url} (Foxglove or Lichtblick: Open connection > Foxglove "
                     "WebSocket; layout docs/foxglove-layout.json, Lichtblick docs/lichtblick-layout.json)")
            return url
        if live is None or live.proc.poll() is not None:
            break
        time.sleep(0.05)
    log.warning("the live view did not come up (see logs/live.log); flying without it")
    return None


def _reserve(path: Path, mb: float) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.posix_fallocate(fd, 0, int(mb * 1e6))
    finally:
        os.close(fd)


class DiskFull(Exception):
    """The run's disk filled during the run: the launcher ends it (message: one line)."""


class DiskWatch:
    """Ends the run when its disk fills, after giving back the reserve (docs/faults.md)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir

    def check(self) -> None:
        try:
            where, free = free_bytes(self.run_dir)
        except OSError:
            return
        if free < DISK_LOW_WATER_MB * 1e6:
            self.release()
            raise DiskFull(f"disk full: {free / 1e6:.1f} MB free on {mount_point(where)} "
                           f"(run folder {self.run_dir}): run stopped, what was written is kept")

    def release(self) -> None:
        (self.run_dir / RESERVE_FILE).unlink(missing_ok=True)


def disk_error_line(path: Path, exc: OSError) -> str:
    """One line for a failed write: the file, the error, the disk and its free space."""
    where, free = free_bytes(path)
    what = "no space left" if exc.errno == errno.ENOSPC else (exc.strerror or str(exc))
    return (f"{path}: cannot write the run folder: {what} ({free / 1e6:.1f} MB free on "
            f"{mount_point(where)}); free some space or choose another --out")


def resolve_world(cfg: ScenarioConfig):
    from scenenav.app.nodes import load_world_for
    return load_world_for(cfg)


def run(scenario_path: str | None, out_dir: str, overrides: tuple[str, ...] = (),
        progress: bool = True, live_port: int | None = None, external: tuple[str, ...] = (),
        announce: Callable[[str], None] | None = None) -> dict:
    """Fly one scenario into ``out_dir``; Ctrl-C and SIGTERM stop every node cleanly (the summary is
    still written, then KeyboardInterrupt is raised again). ``live_port``: also stream the run to
    Foxglove on that port (``scenenav run --live``); ``external``: ``ROLE:ID`` of nodes the user
    starts (added to ``external.nodes``); ``announce(text)`` tells the user the live view's URL and
    which nodes to start."""
    with interrupt_on_stop_signals():
        return _prepare_and_fly(scenario_path, out_dir, overrides, progress, live_port, external,
                                announce or (lambda text: log.warning("%s", text)))


def _prepare_and_fly(scenario_path: str | None, out_dir: str, overrides: tuple[str, ...],
                     progress: bool, live_port: int | None = None, external: tuple[str, ...] = (),
                     announce: Callable[[str], None] = print) -> dict:
    cfg = load_scenario(scenario_path, overrides, external)
    world = resolve_world(cfg)          # fail early, with a one-line error, on a bad world
    cfg = resolve_guidance_map(cfg, progress)
    validate_inputs(cfg, world)          # every file a node will read, before any node starts
    cfg, claim = _claim_sysid(cfg, Path(out_dir))
    try:
        return _fly(cfg, world, scenario_path, out_dir, progress, live_port, announce)
    finally:
        if claim is not None:
            claim.release()


def external_wait_text(cfg: ScenarioConfig, run_dir: Path) -> str:
    """What the user reads while the run waits for its external nodes."""
    specs = ", ".join(cfg.external.nodes)
    return (f"waiting up to {cfg.external.join_timeout_s:.0f} s for external node(s) {specs}: start "
            f"them now; they join with {run_dir / RUN_FILE} (docs/interfaces.md)")


def external_missing_text(cfg: ScenarioConfig, run_dir: Path) -> str:
    """One line for a run whose external node never joined (the simulator's external.json)."""
    from scenenav.app.nodes import EXTERNAL_FILE
    try:
        missing = json.loads((run_dir / EXTERNAL_FILE).read_text()).get("missing") or []
    except (OSError, ValueError, AttributeError):
        missing = list(cfg.external.nodes)
    return (f"external node {', '.join(missing)} did not join within "
            f"{cfg.external.join_timeout_s:g} s (external.join_timeout_s): start it with the bus "
            f"endpoint and namespace of {run_dir / RUN_FILE} and declare its liveliness token "
            f"nodes/<role>/<id> (docs/interfaces.md), or raise external.join_timeout_s")


def _fly(cfg: ScenarioConfig, world, scenario_path: str | None, out_dir: str, progress: bool,
         live_port: int | None = None, announce: Callable[[str], None] = print) -> dict:
    launch = prepare_run(cfg, world, Path(out_dir), scenario_path or "(defaults)", "run",
                         reserve_mb=DISK_RESERVE_MB)
    run_dir = launch.run_dir

    expect = ["recorder"]
    interrupted = False
    abort: str | None = None
    wall0 = time.time()
    watch = ChildWatch(launch, wall0)
    restarter = NodeRestarter(launch, cfg.perception.max_restarts, wall0)
    disk = DiskWatch(run_dir)
    try:
        for attempt in range(HUB_ATTEMPTS):
            # every node starts at once (their imports overlap on the two cores); the simulator
            # waits on the bus for the members it expects
            expect = ["recorder"] + spawn_recorder_and_perception(launch, cfg, live_port)
            autopilot = None
            if cfg.flight.mode == FlightMode.AUTOPILOT:
                expect.append("tick")
                if not cfg.external.of_role("autopilot"):
                    autopilot = launch.spawn("autopilot", ["autopilot", "--run-dir", str(run_dir)])
            if cfg.guidance.enabled and not cfg.external.of_role("guidance"):
                launch.spawn("guidance", ["guidance", "--run-dir", str(run_dir)])
                if cfg.clock.mode == ClockMode.LOCKSTEP:
                    expect.append("tick")
            sim = launch.spawn("sim", ["sim", "--run-dir", str(run_dir), "--expect", ",".join(expect)])
            if autopilot is not None:
                await_mavlink(launch, autopilot)     # run.json names the ports it bound
            if await_hub(launch, sim) or attempt == HUB_ATTEMPTS - 1:
                break
            restart_on_new_hub_port(launch)
        if live_port is not None:
            announce_live(launch, announce)
        if cfg.external.nodes and launch.published:
            announce(external_wait_text(cfg, run_dir))
        swap = PerceptionSwap(launch, cfg) if cfg.perception.enabled and cfg.perception.swap_at_s > 0 \
            and not cfg.external.of_role("perception") else None
        abort = _wait_sim(sim, launch, cfg, progress, swap, watch, disk, restarter)
        if abort:
            log.error("%s", abort)
        elif sim.proc.returncode == EXIT_EXTERNAL_MISSING:
            abort = external_missing_text(cfg, run_dir)
            log.error("%s", abort)
    except KeyboardInterrupt:
        interrupted = True
        log.warning("interrupted: stopping every node")
    except DiskFull as exc:
        abort = str(exc)
        log.error("%s", abort)
    finally:
        disk.release()
        watch.poll()     # a death seen only now is still a death, not a stop
        launch.stop_all(STOP_STAGES)
    wall = time.time() - wall0
    return _finish(launch, cfg, world, wall, interrupted, watch, abort, restarter.restarts)


def _finish(launch: Launch, cfg: ScenarioConfig, world, wall: float, interrupted: bool,
            watch: "ChildWatch", abort: str | None = None,
            restarts: list[NodeRestart] | None = None) -> dict:
    """After every child stopped: recover bus.mcap if needed, write the summary and the plot."""
    from scenenav.app.evaluation import evaluate_run
    from scenenav.app.recorder import recover_mcap
    run_dir = launch.run_dir
    recorder_early = watch.failed("recorder")
    try:
        kept = recover_mcap(run_dir / "bus.mcap")
        if kept is not None:
            log.warning("bus.mcap was not finished (recorder stopped early): recovered %d messages",
                        kept)
            recorder_early = True
        summary = evaluate_run(run_dir, cfg, world, wall_time_s=wall, interrupted=interrupted,
                               failures=tuple(watch.failures), recorder_stopped_early=recorder_early,
                               abort_reason=abort)
        if add_node_outcomes(summary, [f.node for f in watch.failures], restarts or []):
            write_atomic(run_dir / "summary.json", json.dumps(summary, indent=2))
    except OSError as exc:
        raise UserError(disk_error_line(run_dir, exc)) from None
    if interrupted:
        raise KeyboardInterrupt
    return summary


#: Return codes of a child that stopped because it was asked to (SIGINT handled, or killed by it).
_CLEAN_EXITS = (0, -signal.SIGINT, 130)


class ChildWatch:
    """Sees children die on their own, once each: one log line with the reason (the last error
    line of the child's log) and a ``NodeFailure`` for the summary."""

    def __init__(self, launch: Launch, wall0: float) -> None:
        self.launch = launch
        self.wall0 = wall0
        self.failures: list[NodeFailure] = []
        self._seen: set[int] = set()

    def poll(self) -> None:
        for c in self.launch.children:
            code = c.proc.poll()
            if code is None or c.proc.pid in self._seen or c.stopping:
                continue
            self._seen.add(c.proc.pid)
            if code in _CLEAN_EXITS and c.name != "sim":
                continue
            if c.name == "sim" and code in (0, EXIT_EXTERNAL_MISSING):
                continue      # the launcher reports a missing external node itself
            f = NodeFailure(c.name, int(code), round(time.time() - self.wall0, 3),
                            last_sim_time_s(self.launch.run_dir),
                            last_error_line(c.log_path) if c.log_path else "")
            self.failures.append(f)
            log.error("%s (see logs/%s.log)", f.describe(), c.name)

    def failed(self, name: str) -> bool:
        return any(f.node == name for f in self.failures)


def add_node_outcomes(summary: dict, failed: list[str], restarts: list["NodeRestart"]) -> bool:
    """Add ``failed_nodes`` (each name once) and ``node_restarts`` to a run's summary when there
    are any; True when the summary changed (the caller writes it again)."""
    names = list(dict.fromkeys(failed))
    if names:
        summary["failed_nodes"] = names
    if restarts:
        summary["node_restarts"] = [dataclasses.asdict(r) | {"what": r.describe()} for r in restarts]
    return bool(names or restarts)


@dataclass(frozen=True)
class NodeRestart:
    """A perception node the launcher started again after it failed (``perception.max_restarts``)."""

    node: str
    wall_time_s: float            # since the launch
    sim_time_s: float | None      # newest simulated time in truth.csv when it was restarted

    def describe(self) -> str:
        at = f" at t={self.sim_time_s:.1f} s" if self.sim_time_s is not None else ""
        return f"{self.node} restarted{at}"


#: The children the launcher starts again when they fail in flight: our perception nodes. What they
#: hold (a track, a learnt heading offset) is rebuilt from the next frames and the autopilot's
#: estimate; an autopilot, a guidance node or the recorder cannot be restarted without losing the
#: mission, its plan or the recording.
RESTARTABLE = ("perception", SWAP_NODE_ID)


class NodeRestarter:
    """Starts a perception node again (same node id, same arguments, its log appended to) when it
    failed after the simulator's first tick and no other perception node of the run is running
    (a swap's other node serves then), at most ``max_restarts`` times in a run. A companion
    computer's supervisor does the same; without it a GPS-denied vehicle whose perception died would
    never get another fix. A death before the first tick is not restarted: the launcher stops that
    run (``startup_death_text``). Poll it after ``ChildWatch.poll``, which reports the failure."""

    def __init__(self, launch: Launch, max_restarts: int, wall0: float) -> None:
        self.launch = launch
        self.left = max_restarts
        self.max_restarts = max_restarts
        self.wall0 = wall0
        self.restarts: list[NodeRestart] = []
        self._handled: set[int] = set()

    def poll(self) -> None:
        for c in list(self.launch.children):
            if c.name not in RESTARTABLE or c.stopping or c.proc.pid in self._handled:
                continue
            code = c.proc.poll()
            if code is None:
                continue
            self._handled.add(c.proc.pid)
            sim_t = last_sim_time_s(self.launch.run_dir)
            if code in _CLEAN_EXITS or sim_t is None:
                continue
            if any(o.name in RESTARTABLE and not o.stopping and o.proc.poll() is None
                   for o in self.launch.children):
                log.warning("%s not restarted: another perception node of the run is running", c.name)
                continue
            if self.left <= 0:
                log.error("%s not restarted: perception.max_restarts (%d) used up; the run goes on "
                          "without perception", c.name, self.max_restarts)
                continue
            self.left -= 1
            self.launch.spawn(c.name, c.args)
            r = NodeRestart(c.name, round(time.time() - self.wall0, 3), sim_t)
            self.restarts.append(r)
            log.warning("%s (restart %d of perception.max_restarts %d)", r.describe(),
                        len(self.restarts), self.max_restarts)


_ERROR_LINE = re.compile(r"\b(ERROR|CRITICAL|FATAL)\b|^error: |^\w+(Error|Exception): ")


def last_error_line(path: Path, n_bytes: int = 64_000) -> str:
    """The last line of a log that reads as an error (an ERROR record, ``error: ...``, the last
    line of a traceback); "" if there is none."""
    lines = _tail(path, n_bytes).decode("utf-8", "replace").splitlines()
    for line in reversed(lines):
        line = line.strip()
        if line and _ERROR_LINE.search(line):
            return line[:300]
    return ""


#: Wall seconds the first perception node is kept after the swap started when the second one has
#: not produced a fix yet (it is stopped anyway then, with a warning).
SWAP_HANDOVER_TIMEOUT_S = 60.0


class PerceptionSwap:
    """``perception.swap_at_s``: start a second perception node (``perception-2``, method
    ``perception.swap_method``) on the live bus at that simulated time, and stop the first one as soon
    as the second has published a fix (make-before-break, as an operator would swap nodes by hand).
    With ``perception.swap_every_s`` the swap repeats every that many simulated seconds, back and
    forth between ``perception`` (its method) and ``perception-2`` (``swap_method``), each time a new
    process."""

    def __init__(self, launch: Launch, cfg: ScenarioConfig) -> None:
        self.launch = launch
        self.cfg = cfg
        self.started_wall: float | None = None
        self.done = False
        self.swaps = 0                           # swaps started
        self._next_at_s = cfg.perception.swap_at_s
        self._active = "perception"              # the node now in charge
        self._incoming = SWAP_NODE_ID
        self._fixes_offset = 0

    def poll(self, sim_t_s: float | None) -> None:
        if self.done:
            return
        p = self.cfg.perception
        if self.started_wall is None:
            if sim_t_s is not None and sim_t_s >= self._next_at_s:
                method = p.swap_method if self._incoming == SWAP_NODE_ID else p.method
                self._fixes_offset = _size(self.launch.run_dir / "fixes.csv")
                self.launch.spawn(self._incoming, ["perception", "--run-dir", str(self.launch.run_dir),
                                                   "--node-id", self._incoming, "--method", method])
                self.started_wall = time.monotonic()
                self.swaps += 1
                log.info("perception swap %d at %.1f s: %s -> %s (%s)", self.swaps, sim_t_s,
                         self._active, self._incoming, method)
            return
        incoming = [c for c in self.launch.children if c.name == self._incoming]
        if incoming and incoming[-1].proc.poll() is not None and not incoming[-1].stopping:
            # it died before taking over: the node in charge stays (stopping it would leave none)
            log.warning("swap %d abandoned: %s exited before its first fix; %s stays in charge",
                        self.swaps, self._incoming, self._active)
            self._schedule_next()
            return
        answered = _fixes_from(self.launch.run_dir, self._incoming, self._fixes_offset)
        late = time.monotonic() - self.started_wall > SWAP_HANDOVER_TIMEOUT_S
        if answered or late:
            if late and not answered:
                log.warning("%s produced no fix within %.0f s; stopping %s anyway", self._incoming,
                            SWAP_HANDOVER_TIMEOUT_S, self._active)
            _stop_together([c for c in self.launch.children
                            if c.name == self._active and c.proc.poll() is None])
            self._active, self._incoming = self._incoming, self._active
            self._schedule_next()

    def _schedule_next(self) -> None:
        """This swap is over (done or abandoned): the next one after ``swap_every_s``, or none."""
        self.started_wall = None
        if self.cfg.perception.swap_every_s > 0:
            self._next_at_s += self.cfg.perception.swap_every_s
        else:
            self.done = True


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _tail(path: Path, n_bytes: int) -> bytes:
    """The last ``n_bytes`` of a file being written by another process (b"" if unreadable)."""
    try:
        with path.open("rb") as f:
            f.seek(max(0, path.stat().st_size - n_bytes))
            return f.read()
    except OSError:
        return b""


def _fixes_from(run_dir: Path, node_id: str, since_offset: int = 0) -> bool:
    """Has fixes.csv a row from ``node_id`` after byte ``since_offset`` (read from the end)?"""
    path = run_dir / "fixes.csv"
    size = _size(path)
    return f",{node_id},".encode() in _tail(path, min(20000, max(0, size - since_offset)))


#: The nodes without which a mission cannot start: the autopilot flies it, the guidance node plans,
#: uploads and starts it.
MISSION_STARTERS = ("autopilot", "guidance")


def grounded_death_text(failures: list[NodeFailure]) -> str:
    """Why the launcher stopped an autopilot run whose node died with the vehicle never armed."""
    names = ", ".join(f.node for f in failures)
    return (f"stopped the run before take-off: {names} failed with the vehicle still disarmed on the "
            "ground (see " + ", ".join(f"logs/{f.node}.log" for f in failures) + "); its mission could "
            "not start, and the run would only have idled to its duration")


def startup_death_text(failures: list[NodeFailure]) -> str:
    """Why the launcher stopped a run whose nodes died before the simulator's first tick."""
    names = ", ".join(f.node for f in failures)
    return (f"stopped the run before take-off: {names} died while the run was starting (see "
            + ", ".join(f"logs/{f.node}.log" for f in failures) + "); the simulator would have waited "
            "clock.startup_timeout_s for it and flown without it")


def autopilot_death_text(failure: NodeFailure) -> str:
    """Why the launcher stopped an autopilot flight whose autopilot died after take-off had begun:
    nothing flies the vehicle any more (the simulator would step it on the last motor commands),
    and the guidance and perception nodes would wait out their timeouts on every tick for a
    controller that never answers, so the run would crawl to its duration."""
    at = f" at t={failure.sim_time_s:.1f} s" if failure.sim_time_s is not None else ""
    return (f"stopped the run: the autopilot died{at} (see logs/autopilot.log); nothing flies the "
            "vehicle any more, so the rest of the flight would mean nothing")


def _wait_sim(sim: Child, launch: Launch, cfg: ScenarioConfig, progress: bool,
              swap: PerceptionSwap | None = None, watch: ChildWatch | None = None,
              disk: DiskWatch | None = None, restarter: NodeRestarter | None = None) -> str | None:
    """Wait for the simulator to end; show progress from its log of simulated time. Returns why the
    run was ended early, else None: a node the simulator waits for died before its first tick
    (flying without it is not what the scenario asked for), or, in an autopilot flight, one of the
    ``MISSION_STARTERS`` died while the vehicle had never armed (a guidance node without a route,
    say: the mission cannot start, and the simulator would idle on the ground to the duration), or
    the autopilot died later (``autopilot_death_text``)."""
    bar = None
    if progress and sys.stderr.isatty():
        from tqdm import tqdm
        bar = tqdm(total=round(cfg.duration_s), unit="sim s", desc=cfg.name, leave=False)
    watch = watch or ChildWatch(launch, time.time())
    autopilot_flight = cfg.flight.mode == FlightMode.AUTOPILOT
    ever_armed = False
    while sim.proc.poll() is None:
        watch.poll()
        if restarter is not None:
            restarter.poll()
        status = last_status(launch.run_dir) if autopilot_flight else None
        ever_armed = ever_armed or (status is not None and (status.armed or not status.landed))
        grounded = status is not None and not ever_armed
        if watch.failures:
            dead = [f for f in watch.failures if f.node not in ("sim", "live")]
            why = None
            if dead and last_sim_time_s(launch.run_dir) is None:
                why = startup_death_text(dead)
            elif grounded and not watch.failed("recorder"):     # status.csv is the recorder's
                blocking = [f for f in dead if f.node in MISSION_STARTERS]
                why = grounded_death_text(blocking) if blocking else None
            if why is None and autopilot_flight:
                pilot = [f for f in dead if f.node == "autopilot"]
                why = autopilot_death_text(pilot[0]) if pilot else None
            if why is not None:
                if bar is not None:
                    bar.close()
                return why
        if disk is not None:
            disk.check()
        time.sleep(0.25)
        if swap is not None:
            swap.poll(last_sim_time_s(launch.run_dir))
        if bar is not None:
            t = last_sim_time_s(launch.run_dir)
            if t is not None:
                bar.n = min(round(t), bar.total)
                bar.refresh()
    if bar is not None:
        bar.close()
    watch.poll()        # the simulator's own exit, if it failed
    return None
