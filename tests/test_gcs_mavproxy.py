"""MAVProxy flies ``scenenav sitl``: real processes, real bus, real MAVLink bytes.

A scripted MAVProxy session (stdin/stdout pipes) against ``scenenav sitl --speedup 3``: GUIDED, arm,
takeoff 20, ``wp load`` of a 4-waypoint QGC WPL 110 file, AUTO through the mission, RTL, and the
vehicle must land within 2 m of home -- measured from the run's ``truth.csv`` (ground truth), not
from the autopilot's own report. A pymavlink monitor on a second TCP link watches altitude and
MISSION_ITEM_REACHED. ``SitlSession`` is shared with test_gcs_mavsdk.py and test_failsafe.py.
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from lineproc import LineProcess, MavproxyProcess, wait_until
from scenenav.bus import free_port

REPO = Path(__file__).resolve().parents[1]
TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 90.0


def world_origin() -> tuple[float, float]:
    from autopilot_bridge.node import world_origin as wo
    from scenenav.scenario import ScenarioConfig
    o = wo(ScenarioConfig())
    return o.lat_deg, o.lon_deg


def enu_to_latlon(x_m: float, y_m: float) -> tuple[float, float]:
    from worlds.frames import enu_to_geodetic
    lat0, lon0 = world_origin()
    return enu_to_geodetic(x_m, y_m, lat0, lon0)


class SitlSession:
    """``scenenav sitl`` as a subprocess on a free TCP port (UDP output off); stop() sends SIGINT."""

    def __init__(self, tmp_path: Path, *extra: str) -> None:
        self.port = free_port()
        self.run_dir = tmp_path / "run"
        cmd = [sys.executable, "-m", "scenenav.cli", "--log-level", "INFO", "sitl",
               "--out", str(self.run_dir), "--tcp-port", str(self.port), "--udp-out", "0", *extra]
        self.out = LineProcess(cmd, name="scenenav sitl", timeout_s=TIMEOUT_S, cwd=REPO,
                               stdin=subprocess.DEVNULL)
        self.proc, self.lines = self.out.proc, self.out.lines

    def wait_ready(self) -> None:
        ok = wait_until(lambda: any("Ctrl-C stops" in ln for ln in self.lines)
                        or self.proc.poll() is not None)
        assert ok and self.proc.poll() is None, "sitl did not start:\n" + "\n".join(self.lines[-40:])

    def child_pid(self, name: str) -> int | None:
        """PID of the sitl's child ``name`` (sim, autopilot, perception, recorder)."""
        try:
            return json.loads((self.run_dir / "logs" / "pids.json").read_text()).get(name)
        except (OSError, ValueError):
            return None

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                for kind in ("sim", "autopilot", "perception", "recorder"):
                    pid = self.child_pid(kind)
                    if pid is not None and _is_scenenav(pid):
                        os.kill(pid, signal.SIGKILL)
                self.proc.kill()
                self.proc.wait(10)
        self.out.join_reader()

    def param(self, name: str) -> float | None:
        """A parameter as the autopilot stored it (``<run>/params.json``, written on every change)."""
        try:
            return json.loads((self.run_dir / "params.json").read_text()).get(name)
        except (OSError, ValueError):
            return None

    def truth(self) -> dict[str, np.ndarray]:
        return read_columns(self.run_dir / "truth.csv")

    def events(self) -> list[str]:
        with (self.run_dir / "events.csv").open(newline="") as f:
            return [row["text"] for row in csv.DictReader(f)]


def _is_scenenav(pid: int) -> bool:
    try:
        return b"scenenav.cli" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


def read_columns(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in ("t_s", "x_m", "y_m", "z_m")}


def final_position(truth: dict[str, np.ndarray]) -> np.ndarray:
    return np.array([truth["x_m"][-1], truth["y_m"][-1], truth["z_m"][-1]])


def monitor_connection(port: int):
    """A pymavlink TCP client that only listens (system id 253, no heartbeats)."""
    from fake_vehicle import gcs_connection
    return gcs_connection(port, source_system=253)


def relative_alt_m(conn) -> float | None:
    from fake_vehicle import wait_for
    msg = wait_for(conn, "GLOBAL_POSITION_INT", timeout_s=10)
    return None if msg is None else msg.relative_alt * 1e-3


def wpl_file(path: Path, home: tuple[float, float], points_enu: list[tuple[float, float]],
             alt_m: float) -> None:
    """A QGC WPL 110 mission: home, then one NAV_WAYPOINT (GLOBAL_RELATIVE_ALT) per point."""
    lines = ["QGC WPL 110", f"0\t1\t0\t16\t0\t0\t0\t0\t{home[0]:.7f}\t{home[1]:.7f}\t0.000000\t1"]
    for i, (x, y) in enumerate(points_enu, start=1):
        lat, lon = enu_to_latlon(x, y)
        lines.append(f"{i}\t0\t3\t16\t0\t0\t0\t0\t{lat:.7f}\t{lon:.7f}\t{alt_m:.6f}\t1")
    path.write_text("\n".join(lines) + "\n")


def test_mavproxy_guided_takeoff_mission_and_rtl(tmp_path):
    from fake_vehicle import wait_for
    square = [(30.0, 0.0), (30.0, 30.0), (0.0, 30.0), (-10.0, 10.0)]
    wpl = tmp_path / "square.txt"
    wpl_file(wpl, world_origin(), square, 20.0)
    sitl = SitlSession(tmp_path, "--speedup", "3", "--perception", "off")
    mp = monitor = None
    try:
        sitl.wait_ready()
        mp = MavproxyProcess(sitl.port, tmp_path, timeout_s=TIMEOUT_S)
        mp.expect("parameters")
        for name, value in (("RTL_LOIT_TIME", 1000), ("LAND_SPEED", 100), ("DISARM_DELAY", 30)):
            mp.send(f"param set {name} {value}")
            assert wait_until(lambda: sitl.param(name) == value, 30), f"{name} not set"
        monitor = monitor_connection(sitl.port)
        mark = mp.send("mode GUIDED")
        mp.expect("GUIDED>", mark)
        mark = mp.send("arm throttle")
        mp.expect("ARMED", mark)
        mp.send("takeoff 20")
        assert wait_until(lambda: (relative_alt_m(monitor) or 0.0) > 19.0), "takeoff never reached 19 m"

        mark = mp.send(f"wp load {wpl}")
        mp.expect("ACCEPTED", mark)
        mark = mp.send("mode AUTO")
        mp.expect("AUTO>", mark)
        mp.expect("Reached command #4", mark)
        reached = wait_for(monitor, "MISSION_ITEM_REACHED", timeout_s=30, condition=lambda m: m.seq == 4)
        assert reached is not None

        mark = mp.send("mode RTL")
        mp.expect("RTL>", mark)
        mp.expect("DISARMED", mark)
    finally:
        if monitor is not None:
            monitor.close()
        if mp is not None:
            mp.close()
        sitl.stop()

    truth = sitl.truth()
    # the square was flown: the vehicle passed its far corner (30, 30) m
    assert np.min(np.hypot(truth["x_m"] - 30.0, truth["y_m"] - 30.0)) < 3.0
    end = final_position(truth)
    assert math.hypot(end[0], end[1]) < 2.0, f"landed {end} m from home (0, 0)"
    assert end[2] < 0.5
    events = sitl.events()
    assert "Reached command #4" in events
    assert any(t.startswith("disarmed") for t in events)
    summary = json.loads((sitl.run_dir / "summary.json").read_text())
    assert summary["flight_mode"] == "idle" and summary["end_reason"] == "interrupted"
