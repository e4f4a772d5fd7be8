"""``scenenav bench sim``: simulator real-time factor, headless, lockstep, camera at 10 Hz.

The simulator node runs in this process with its real bus; a second process joins as the lockstep
members an autopilot and a perception node would be (it answers every tick with a hover motor
command and every camera frame with an ack, doing no work of its own), so the figure includes the
real bus round trips but not the cost of the other nodes' algorithms. Reported per world size: the
real-time factor and the share of wall time in physics, rendering, publishing and waiting on the bus,
and the CPU milliseconds per tick of the simulator process (all its threads, Zenoh's included), its
render worker and the stand-in (``cpu_ms_per_tick``): on a loaded machine the wall figures follow
the load, the CPU figures much less.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np

from scenenav.core.bus import Bus, BusConfig, free_port
from scenenav.core.clock import ClockConfig
from scenenav.core.contracts import (
    CameraFrame,
    ClockTick,
    LockstepAck,
    LockstepRole,
    MotorCommand,
)
from scenenav.core.errors import UserError
from scenenav.core.keys import Keys

log = logging.getLogger(__name__)


def synthetic_world(width_px: int, height_px: int, m_per_px: float = 0.53, seed: int = 0):
    """A textured map of the given size (content does not change the rendering cost)."""
    import cv2
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, size=(max(8, height_px // 8), max(8, width_px // 8), 3), dtype=np.uint8)
    img = cv2.resize(small, (width_px, height_px), interpolation=cv2.INTER_LINEAR)
    manifest = SimpleNamespace(name=f"synthetic-{width_px}x{height_px}", width_px=width_px,
                               height_px=height_px, m_per_px=m_per_px,
                               origin_lat_deg=48.0, origin_lon_deg=11.0)
    return SimpleNamespace(orthophoto=img, reference=img, dsm_m=None, facade_rgb=None, m_per_px=m_per_px,
                           manifest=manifest, width_px=width_px, height_px=height_px)


def responder(namespace: str, hub_port: int, hover: float) -> None:
    """Lockstep members standing in for the autopilot (tick) and perception (camera)."""
    keys = Keys(namespace)
    bus = Bus(BusConfig(namespace, hub_port))

    def on_tick(m: ClockTick, _k: str) -> None:
        # the motor command is the tick's answer (MotorCommand.node_id), as the autopilot's is
        bus.publish(keys.motors, MotorCommand(m.timestamp_us, m.tick, (hover,) * 4, True, "bench-ap"))

    def on_frame(m: CameraFrame, _k: str) -> None:
        bus.publish(keys.lockstep_ack("bench-cam"), LockstepAck(m.timestamp_us, "bench-cam", "camera", m.seq))

    bus.subscribe(keys.clock, ClockTick, on_tick)
    bus.subscribe(keys.camera, CameraFrame, on_frame)
    bus.declare_token(keys.lockstep_member(LockstepRole.TICK, "bench-ap"))
    bus.declare_token(keys.lockstep_member(LockstepRole.CAMERA, "bench-cam"))
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        bus.close()


def _cpu_s(pid: int | None) -> float | None:
    """CPU seconds (user + system, all threads) a live process has used, from /proc; None if unknown."""
    if pid is None:
        return None
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measure(width_px: int, height_px: int, seconds: float) -> dict:
    from sitl.config import SimNodeConfig
    from sitl.node import SimulatorNode
    from sitl.physics import hover_motor_command
    from sitl.vehicle import VehicleParams
    world = synthetic_world(width_px, height_px)
    ns = f"bench-{width_px}x{height_px}-{int(time.time() * 1000) % 10**8}"
    port = free_port()
    cfg = SimNodeConfig(duration_s=seconds, clock=ClockConfig(), expected_tick_members=1,
                        expected_camera_members=1)
    hover = float(np.mean(hover_motor_command(VehicleParams())))
    node = SimulatorNode(cfg, world, BusConfig(ns, port, listen_hub=True))
    node.core.start_at(np.array([0.0, 0.0, 100.0]), 0.0)
    proc = subprocess.Popen([sys.executable, "-m", "scenenav.app.bench.sim", ns, str(port), repr(hover)],
                            stdin=subprocess.DEVNULL)
    # the stand-in's start-up (imports, joining) is not the loop's: wait for it before counting CPU
    node.barrier.wait_members({LockstepRole.TICK: 1, LockstepRole.CAMERA: 1}, cfg.clock.startup_timeout_s)
    render_pid = node.camera._proc.pid if node.camera._proc is not None else None
    cpu0 = {"sim": time.process_time(), "responder": _cpu_s(proc.pid), "render_worker": _cpu_s(render_pid)}
    try:
        stats = node.run()
        cpu1 = {"sim": time.process_time(), "responder": _cpu_s(proc.pid), "render_worker": _cpu_s(render_pid)}
    finally:
        proc.terminate()
        proc.wait(10)
        node.close()
    ticks = max(1, stats.ticks)
    cpu_ms = {k: round(1e3 * (cpu1[k] - cpu0[k]) / ticks, 3) for k in cpu0
              if cpu0[k] is not None and cpu1[k] is not None}
    wall = stats.wall_time_s
    share = {"physics": stats.time_physics_s / wall, "render": stats.time_render_s / wall,
             "publish": stats.time_publish_s / wall, "bus_wait": stats.time_bus_wait_s / wall}
    return {
        "world_px": f"{width_px}x{height_px}",
        "sim_time_s": stats.sim_time_s,
        "wall_time_s": round(wall, 3),
        "real_time_factor": round(stats.real_time_factor, 2),
        "camera_frames": stats.camera_frames,
        "ms_render_wait_per_frame": round(1000 * stats.time_render_s / max(1, stats.camera_frames), 2),
        "us_per_physics_step": round(1e6 * stats.time_physics_s / max(1, stats.ticks * node.core.substeps), 1),
        "share": {k: round(v, 3) for k, v in share.items()},
        "ack_timeouts": stats.ack_timeouts,
        "cpu_ms_per_tick": cpu_ms,
    }


def run_sim_bench(seconds: float = 20.0, sizes: str = "900x1000,2000x2000,8000x8000") -> dict:
    parsed = []
    for item in sizes.split(","):
        try:
            w, h = (int(x) for x in item.lower().split("x"))
        except ValueError:
            raise UserError(f"--sizes {item!r}: expected WIDTHxHEIGHT in pixels, e.g. 900x1000") from None
        if not (64 <= w <= 20000 and 64 <= h <= 20000):
            raise UserError(f"--sizes {item!r}: each side must be 64 to 20000 px")
        parsed.append((w, h))
    if seconds <= 0:
        raise UserError(f"--seconds {seconds}: expected a positive number of simulated seconds")
    rows = [measure(w, h, seconds) for w, h in parsed]
    default = next((r for r in rows if r["world_px"] == "900x1000"), rows[0])
    return {"real_time_factor": default["real_time_factor"], "sizes": rows,
            "config": dataclasses.asdict(ClockConfig())}


def format_table(result: dict) -> str:
    """The figures of ``run_sim_bench`` as a table (text, newline-terminated)."""
    lines = [f"{'world px':>12} {'RTF':>6} {'ms wait/frame':>10} {'us/step':>8} "
             f"{'physics':>8} {'render':>7} {'publish':>8} {'bus wait':>9} {'CPU ms/tick sim+render+stand-in':>32}"]
    for r in result["sizes"]:
        s = r["share"]
        lines.append(f"{r['world_px']:>12} {r['real_time_factor']:>6.1f} {r['ms_render_wait_per_frame']:>10.2f} "
                     f"{r['us_per_physics_step']:>8.1f} {s['physics']:>8.0%} {s['render']:>7.0%} "
                     f"{s['publish']:>8.0%} {s['bus_wait']:>9.0%} "
                     f"{' + '.join(f'{c:.3f}' for c in r['cpu_ms_per_tick'].values()):>32}")
    lines.append("lockstep, control tick 100 Hz, physics 400 Hz, camera 200x200 at 10 Hz, flat world; "
                 "target >= 15x real time, issue 13 (gym-pybullet-drones: 1.3x with TinyRenderer, 10.8x with OpenGL)")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    responder(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]))
