"""``scenenav sitl`` as a subprocess, and a pymavlink ground station with a heartbeat thread.

Shared by the MAVLink, interop and fuzz tests.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from scenenav.core.bus import free_port
from support import REPO_ROOT
from support.lineproc import LineProcess, MavproxyProcess, wait_until  # noqa: F401 (re-exported)

REPO = REPO_ROOT
COPTER_RTL = 6
COPTER_LAND = 9
COPTER_GUIDED = 4
MAV_MODE_FLAG_SAFETY_ARMED = 128
TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 90.0


def world_origin() -> tuple[float, float]:
    from scenenav.app.nodes import world_manifest
    from scenenav.app.scenario import ScenarioConfig
    m = world_manifest(ScenarioConfig())
    return m.origin_lat_deg, m.origin_lon_deg


def enu_to_latlon(x_m: float, y_m: float) -> tuple[float, float]:
    from scenenav.core.frames import enu_to_geodetic
    lat0, lon0 = world_origin()
    return enu_to_geodetic(x_m, y_m, lat0, lon0)


class SitlSession:
    """``scenenav sitl`` as a subprocess on a free TCP port (UDP output off); stop() sends SIGINT.

    The parameters it keeps between starts go to ``params_store`` (default: a file in
    ``tmp_path``), never to the shared ``runs/sitl-params`` of the working copy."""

    def __init__(self, tmp_path: Path, *extra: str, params_store: Path | None = None,
                 run_name: str = "run") -> None:
        self.port = free_port()
        self.run_dir = tmp_path / run_name
        self.params_store = params_store or tmp_path / "params-store.json"
        cmd = [sys.executable, "-m", "scenenav.app.cli", "--log-level", "INFO", "sitl",
               "--out", str(self.run_dir), "--tcp-port", str(self.port), "--udp-out", "0",
               "--set", f"autopilot.params_store={self.params_store}", *extra]
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
        return b"scenenav.app.cli" in Path(f"/proc/{pid}/cmdline").read_bytes()
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
    from support.fake_vehicle import gcs_connection
    return gcs_connection(port, source_system=253)


def relative_alt_m(conn) -> float | None:
    from support.fake_vehicle import wait_for
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


class Gcs:
    """pymavlink ground station (system 255 = SYSID_MYGCS) with a heartbeat thread."""

    def __init__(self, port: int) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        from support.fake_vehicle import gcs_connection
        self.m = mavlink2
        self.conn = gcs_connection(port, source_system=255)
        self._lock = threading.Lock()
        self.beating = threading.Event()
        self.beating.set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)
        self._thread.start()

    def _beat(self) -> None:
        while not self._stop.is_set():
            if self.beating.is_set():
                self.send("heartbeat_send", self.m.MAV_TYPE_GCS, self.m.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            time.sleep(0.25)

    def send(self, name: str, *args) -> None:
        with self._lock:
            getattr(self.conn.mav, name)(*args)

    def command(self, command: int, *params: float, timeout_s: float = 10.0) -> int | None:
        from support.fake_vehicle import command_ack
        p = list(params) + [0.0] * (7 - len(params))
        self.send("command_long_send", 1, 1, command, 0, *p)
        ack = command_ack(self.conn, command, timeout_s)
        return None if ack is None else ack.result

    def wait(self, kind: str, condition=None, timeout_s: float = 60.0, fresh: bool = False):
        """The first ``kind`` message meeting ``condition``; ``fresh``: ignore the ones already
        received (stale state such as an old disarmed HEARTBEAT)."""
        from support.fake_vehicle import _backlog, wait_for
        if fresh:
            _backlog(self.conn).clear()
        return wait_for(self.conn, kind, timeout_s, condition)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.conn.close()


def arm_in_guided_and_take_off(gcs: Gcs, alt_m: float) -> None:
    m = gcs.m
    # GUIDED needs a position estimate: the EKF aligns about a second after start-up
    assert wait_until(lambda: gcs.command(m.MAV_CMD_DO_SET_MODE, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                          COPTER_GUIDED) == m.MAV_RESULT_ACCEPTED, 60,
                      period_s=0.5), "GUIDED refused"
    assert wait_until(lambda: gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) ==
                      m.MAV_RESULT_ACCEPTED, 60, period_s=0.5), "could not arm"
    assert gcs.command(m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m) == m.MAV_RESULT_ACCEPTED
    assert gcs.wait("GLOBAL_POSITION_INT", lambda p: p.relative_alt > (alt_m - 1.5) * 1000,
                    timeout_s=120, fresh=True) is not None, "takeoff never reached its altitude"


def statustext(gcs: Gcs, text: str, timeout_s: float = 60.0):
    return gcs.wait("STATUSTEXT", lambda s: text in s.text, timeout_s)


def write_params(tmp_path, **params) -> str:
    path = tmp_path / "params.json"
    path.write_text(json.dumps(params))
    return str(path)
