"""``scenenav sitl``: a simulated vehicle waiting on the ground for a ground station, like
ArduPilot's ``sim_vehicle.py``.

Starts the simulator (flight mode ``idle``, realtime clock at ``--speedup``, or lockstep), the
autopilot (MAVLink on TCP 127.0.0.1:5760 and UDP out to 127.0.0.1:14550 by default), optionally a
perception node, and the recorder, as child processes through ``scenenav.app.launcher``; prints how to
connect; runs until Ctrl-C (or SIGTERM); stops every child in order and writes the run folder
(``summary.json`` etc. through ``scenenav.app.evaluation``).

Parameters persist from one start to the next, per vehicle instance, as ``sim_vehicle.py`` keeps
``eeprom.bin``: the parameters a ground station sets are kept in
``runs/sitl-params/instance<N>.json`` (``--instance N``, default 0; the autopilot's
``autopilot.params_store``) and applied over the defaults at the next start; ``--wipe`` deletes the
file first (sim_vehicle.py ``-w``).
"""

from __future__ import annotations

import json
import logging
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from scenenav.app.evaluation import last_sim_time_s
from scenenav.app.launcher import (
    HUB_ATTEMPTS,
    STOP_STAGES,
    Launch,
    NodeRestarter,
    add_node_outcomes,
    announce_live,
    await_hub,
    external_wait_text,
    interface_addresses,
    prepare_run,
    resolve_world,
    restart_on_new_hub_port,
    spawn_recorder_and_perception,
)
from scenenav.app.preflight import check_listen_hosts
from scenenav.app.realism import apply_realism
from scenenav.app.scenario import ScenarioConfig, scenario_yaml, with_external
from scenenav.app.signals import interrupt_on_stop_signals
from scenenav.core.config import apply_overrides, load_config, set_dotted
from scenenav.core.errors import UserError
from scenenav.core.formats.atomic_file import write_atomic
from scenenav.core.formats.run_folder import MAVLINK_FILE

log = logging.getLogger(__name__)

PERCEPTION_OFF = "off"
PERCEPTION_CHOICES = ("cnn", "assistant-map", "statistical", "none", PERCEPTION_OFF)
SITL_DURATION_S = 7 * 24 * 3600.0     # "until Ctrl-C"
READY_TIMEOUT_S = 120.0
PARAMS_STORE_DIR = Path("runs") / "sitl-params"
MAX_INSTANCE = 255


@dataclass(frozen=True)
class SitlOptions:
    scenario: str | None = None        # optional scenario YAML to start from
    world: str | None = None           # world folder (default: the scenario's)
    gps: bool = True
    speedup: float = 1.0               # realtime clock: simulated seconds per wall second
    out: str | None = None             # run folder (default runs/sitl-<time>)
    tcp_port: int = 5760               # MAVLink TCP server port (0: off)
    tcp_host: str | None = None        # the address it listens on (None: the scenario's, 127.0.0.1)
    udp_out: str = "127.0.0.1:14550"   # MAVLink UDP output HOST:PORT (0: off)
    perception: str | None = None      # method, "off" for no perception node, None: the scenario's
    lockstep: bool = False             # lockstep clock (as fast as the nodes allow) instead of realtime
    overrides: tuple[str, ...] = ()    # --set KEY=VALUE, applied last
    instance: int = 0                  # vehicle instance: which kept parameter file
    wipe: bool = False                 # delete the instance's kept parameters before starting
    live_port: int | None = None       # --live: stream to Foxglove on this port (0: any free port)
    external: tuple[str, ...] = ()     # --external ROLE:ID: nodes the user starts (perception, guidance)


def params_store_path(instance: int) -> Path:
    """The parameter file kept between starts of a vehicle instance (absolute)."""
    return (PARAMS_STORE_DIR / f"instance{instance}.json").resolve()


def sitl_scenario(opts: SitlOptions) -> ScenarioConfig:
    """The scenario of a SITL session: the options over the (optional) scenario file, then --set."""
    if not (opts.speedup > 0):
        raise UserError(f"--speedup {opts.speedup}: expected a positive number")
    if not 0 <= opts.instance <= MAX_INSTANCE:
        raise UserError(f"--instance {opts.instance}: expected 0..{MAX_INSTANCE}")
    if opts.perception is not None and opts.perception not in PERCEPTION_CHOICES:
        raise UserError(f"--perception {opts.perception}: expected one of "
                        f"{', '.join(PERCEPTION_CHOICES)}")
    data = scenario_yaml(opts.scenario) if opts.scenario else {}
    data.setdefault("name", "sitl")
    set_dotted(data, "flight.mode", "idle")
    set_dotted(data, "duration_s", SITL_DURATION_S)
    set_dotted(data, "clock.mode", "lockstep" if opts.lockstep else "realtime")
    set_dotted(data, "clock.speed_factor", float(opts.speedup))
    set_dotted(data, "sim.gps.enabled", bool(opts.gps))
    set_dotted(data, "autopilot.mavlink_tcp_port", int(opts.tcp_port))
    if opts.tcp_host is not None:
        set_dotted(data, "autopilot.mavlink_tcp_host", opts.tcp_host)
    set_dotted(data, "autopilot.mavlink_udp_out", opts.udp_out)
    set_dotted(data, "autopilot.params_store", str(params_store_path(opts.instance)))
    if opts.world:
        set_dotted(data, "world", opts.world)
    if opts.perception == PERCEPTION_OFF:
        set_dotted(data, "perception.enabled", False)
    elif opts.perception is not None:
        set_dotted(data, "perception.enabled", True)
        set_dotted(data, "perception.method", opts.perception)
    source = opts.scenario or "sitl options"
    if opts.overrides:
        data = apply_overrides(data, list(opts.overrides))
        source += " (with --set overrides)"
    if opts.external:
        data = with_external(data, opts.external)
        source += " (with --external)"
    cfg = load_config(ScenarioConfig, apply_realism(data, source), source)
    if cfg.external.of_role("autopilot"):
        raise UserError("--external autopilot:...: scenenav sitl's own autopilot is the vehicle ground "
                        "stations connect to; an outside autopilot joins a `scenenav run --external "
                        "autopilot:ID` instead")
    return cfg


def _check_tcp_port(host: str, port: int) -> None:
    if port == 0:
        return
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            raise UserError(f"--tcp-port {port}: {host}:{port} is not free ({exc.strerror}); "
                            f"is another SITL running? choose another port") from None


def _check_params_store(path: Path, wipe: bool) -> None:
    """Delete the kept parameters for ``--wipe``; a file that cannot be read is a user error now,
    before any process starts (the autopilot would fail on it)."""
    if wipe:
        from autopilot_bridge.signing import key_path_beside
        try:
            path.unlink(missing_ok=True)
            key_path_beside(path).unlink(missing_ok=True)     # SETUP_SIGNING's key, as -w in SITL
        except OSError as exc:
            raise UserError(f"--wipe: cannot delete {path}: {exc.strerror}") from None
        log.info("parameters wiped: %s", path)
        return
    from autopilot_bridge.signing import key_path_beside, load_key_file
    key_path = key_path_beside(path)
    if key_path.exists():
        try:
            load_key_file(key_path)
        except UserError as exc:
            raise UserError(f"{exc} (--wipe resets it)") from None
    if path.exists():
        from autopilot_bridge.param_specs import PARAM_SPECS
        from autopilot_bridge.params import ParameterStore
        try:
            ParameterStore(PARAM_SPECS, persist_path=path)
        except UserError as exc:
            raise UserError(f"{exc} (the parameters kept by an earlier scenenav sitl; "
                            f"--wipe resets them)") from None


def _connect_text(cfg: ScenarioConfig, run_dir: Path, mavlink: dict) -> str:
    tcp = mavlink.get("tcp_port")
    udp = mavlink.get("udp_out")
    clock = ("lockstep (as fast as the nodes allow)" if cfg.clock.mode.value == "lockstep"
             else f"realtime x{cfg.clock.speed_factor:g}")
    lines = [f"scenenav sitl: world {cfg.world}, GPS {'on' if cfg.sim.gps.enabled else 'off'}, "
             f"clock {clock}, perception "
             f"{cfg.perception.method if cfg.perception.enabled else 'off'}",
             f"run folder: {run_dir}"]
    if cfg.autopilot.params_store:
        lines.append(f"parameters kept in {cfg.autopilot.params_store} (--wipe resets them)")
    host = mavlink.get("tcp_host") or "127.0.0.1"
    local = "127.0.0.1" if host in ("127.0.0.1", "0.0.0.0") else host    # where a client here connects
    if tcp:
        lines += [f"MAVLink TCP server: {host}:{tcp}",
                  f"  MAVProxy:       mavproxy.py --master tcp:{local}:{tcp}",
                  f"  MAVSDK:         tcpout://{local}:{tcp}",
                  f"  QGroundControl: Application Settings > Comm Links > TCP {local}:{tcp}"]
        if host != "127.0.0.1":
            others = interface_addresses() if host == "0.0.0.0" else [host]
            lines.append("  from another machine: " + (" or ".join(f"{a}:{tcp}" for a in others)
                                                       or f"this machine's address, port {tcp}"))
    if udp:
        lines += [f"MAVLink UDP out:    {udp} (QGroundControl listens on 14550 by default; "
                  f"MAVSDK udpin://0.0.0.0:{udp.rsplit(':', 1)[-1]})"]
    lines.append("Ctrl-C stops the simulation.")
    return "\n".join(lines)


def run_sitl(opts: SitlOptions, announce: Callable[[str], None]) -> dict:
    """Run a SITL session until Ctrl-C or SIGTERM (SIGINT explicitly: a shell may start us with it
    ignored, e.g. as a background job); returns the run summary."""
    with interrupt_on_stop_signals():
        return _run_sitl(opts, announce)


def _run_sitl(opts: SitlOptions, announce: Callable[[str], None]) -> dict:
    cfg = sitl_scenario(opts)
    world = resolve_world(cfg)
    check_listen_hosts(cfg)
    _check_tcp_port(cfg.autopilot.mavlink_tcp_host, cfg.autopilot.mavlink_tcp_port)
    store = Path(cfg.autopilot.params_store) if cfg.autopilot.params_store else None
    if store is not None:
        _check_params_store(store, wipe=opts.wipe)
    run_dir = Path(opts.out) if opts.out else Path("runs") / time.strftime("sitl-%Y%m%d-%H%M%S")
    launch = prepare_run(cfg, world, run_dir, opts.scenario or "(sitl)", "sitl")

    interrupted = False
    reason = "stopped"
    restarter: NodeRestarter | None = None
    wall0 = time.time()
    try:
        for attempt in range(HUB_ATTEMPTS):
            expect = ["recorder", "tick", *spawn_recorder_and_perception(launch, cfg, opts.live_port)]
            autopilot = launch.spawn("autopilot", ["autopilot", "--run-dir", str(run_dir)])
            sim = launch.spawn("sim", ["sim", "--run-dir", str(run_dir), "--expect", ",".join(expect)])
            if await_hub(launch, sim) or attempt == HUB_ATTEMPTS - 1:
                break
            restart_on_new_hub_port(launch)
        mavlink = _wait_ready(run_dir, autopilot)
        meta = json.loads((run_dir / "run.json").read_text())
        meta["mavlink"] = mavlink
        write_atomic(run_dir / "run.json", json.dumps(meta, indent=2))
        announce(_connect_text(cfg, run_dir, mavlink))
        if cfg.external.nodes:
            announce(external_wait_text(cfg, run_dir))
        if opts.live_port is not None:
            announce_live(launch, announce)
        restarter = NodeRestarter(launch, cfg.perception.max_restarts, wall0)
        reason = _supervise(launch, restarter)
        if reason:
            announce(f"scenenav sitl: {reason}; stopping")
    except KeyboardInterrupt:
        interrupted = True
        log.info("interrupted: stopping every node")
    finally:
        launch.stop_all(STOP_STAGES)
    from scenenav.app.evaluation import evaluate_run
    summary = evaluate_run(run_dir, cfg, world, wall_time_s=time.time() - wall0,
                           interrupted=interrupted)
    failed = [c.name for c in launch.children if c.proc.returncode not in (0, None, -2, 130)]
    if add_node_outcomes(summary, failed, restarter.restarts if restarter is not None else []):
        write_atomic(run_dir / "summary.json", json.dumps(summary, indent=2))
    return summary


def _wait_ready(run_dir: Path, autopilot) -> dict:
    """The autopilot's MAVLink endpoints, once it has opened them (it writes mavlink.json)."""
    path = run_dir / MAVLINK_FILE
    deadline = time.monotonic() + READY_TIMEOUT_S
    while time.monotonic() < deadline:
        if path.is_file():
            try:
                return json.loads(path.read_text())
            except (OSError, json.JSONDecodeError):
                pass
        if autopilot.proc.poll() is not None:
            raise UserError(f"the autopilot exited with code {autopilot.proc.returncode} "
                            f"(see {run_dir / 'logs' / 'autopilot.log'})")
        time.sleep(0.1)
    raise UserError(f"the autopilot did not open its MAVLink endpoints within "
                    f"{READY_TIMEOUT_S:.0f} s (see {run_dir / 'logs' / 'autopilot.log'})")


def _supervise(launch: Launch, restarter: NodeRestarter) -> str:
    """Wait until the simulator or the autopilot ends; return why. A perception node that fails in
    flight is started again (``NodeRestarter``)."""
    reported: set[int] = set()
    while True:
        for c in list(launch.children):
            code = c.proc.poll()
            if code is None:
                continue
            if c.name in ("sim", "autopilot"):
                return f"{c.name} exited with code {code}"
            if code != 0 and c.name != "live" and last_sim_time_s(launch.run_dir) is None:
                # before the first tick: the simulator would wait for it, then fly without it
                return (f"{c.name} exited with code {code} while the run was starting "
                        f"(see logs/{c.name}.log)")
            if code != 0 and c.proc.pid not in reported and not c.stopping:
                reported.add(c.proc.pid)
                log.error("%s exited with code %s (see logs/%s.log)", c.name, code, c.name)
        restarter.poll()
        time.sleep(0.25)
