"""What ground stations (QGC, MAVProxy, MAVSDK) meet first (issue 15), against the real server.

* the link clock: HEARTBEAT on the wall clock while the simulated clock stands still (a lockstep
  wait), on a server with a frozen caller clock and end to end on ``scenenav sitl`` with the
  simulator stopped.
"""

from __future__ import annotations

import os
import signal
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import FakeVehicle, gcs_connection, server_config
from support.sitl_session import SitlSession, monitor_connection

from autopilot_bridge.mavlink_server import MavlinkServer
from autopilot_bridge.params import ParameterStore

M = mavlink2
# QGC declares the link lost after ~3.5 s without a heartbeat, MAVSDK after 3 s; ArduPilot sends
# one per second. 1.5 s leaves room for a loaded machine and still fails a starved link.
MAX_HEARTBEAT_GAP_S = 1.5


def heartbeat_times(conn, duration_s: float, kinds=("HEARTBEAT",)) -> dict[str, list[float]]:
    """Arrival times (monotonic) of each kind of message during ``duration_s``."""
    out: dict[str, list[float]] = {k: [] for k in kinds}
    deadline = time.monotonic() + duration_s
    while (now := time.monotonic()) < deadline:
        msg = conn.recv_match(blocking=True, timeout=min(0.1, deadline - now))
        if msg is not None and msg.get_type() in out and msg.get_srcSystem() == 1:
            out[msg.get_type()].append(time.monotonic())
    return out


def gaps(times: list[float], start: float, end: float) -> list[float]:
    points = [start, *times, end]
    return [b - a for a, b in zip(points, points[1:])]


# ----------------------------------------------------------------------------- item 8: link clock


def test_heartbeat_keeps_the_wall_clock_while_the_caller_clock_is_frozen():
    """The poller's (simulated) clock stands at 42 s for 4.5 wall seconds: heartbeats go on at
    1 Hz, while the telemetry that follows simulated time (ATTITUDE) does not advance."""
    server = MavlinkServer(FakeVehicle(), ParameterStore(), server_config())
    conn = gcs_connection(server.tcp_port)
    stop = threading.Event()

    def poll_frozen() -> None:
        while not stop.is_set():
            server.poll(42.0)
            time.sleep(0.005)

    poller = threading.Thread(target=poll_frozen, daemon=True)
    poller.start()
    try:
        start = time.monotonic()
        got = heartbeat_times(conn, 4.5, ("HEARTBEAT", "ATTITUDE"))
        end = time.monotonic()
        beats = got["HEARTBEAT"]
        assert len(beats) >= 4, beats
        assert max(gaps(beats, start, end)) < MAX_HEARTBEAT_GAP_S, gaps(beats, start, end)
        assert len(got["ATTITUDE"]) <= 1          # sent once at connect, then the clock froze
    finally:
        stop.set()
        poller.join(5)
        conn.close()
        server.close()


def test_heartbeat_schedule_uses_the_injected_wall_clock():
    """Deterministic: a fake wall clock advanced 0.1 s per poll, the caller's clock frozen. Ten
    wall seconds give ten heartbeats; the 4 Hz ATTITUDE stream stays at its first message."""
    wall = [1000.0]
    server = MavlinkServer(FakeVehicle(), ParameterStore(), server_config(),
                           monotonic_s=lambda: wall[0])
    conn = gcs_connection(server.tcp_port)
    try:
        deadline = time.monotonic() + 10
        while server.tcp_client_count == 0 and time.monotonic() < deadline:
            server.poll(7.0)
        for _ in range(100):
            server.poll(7.0)
            wall[0] += 0.1
        server.poll(7.0)
        counts = {"HEARTBEAT": 0, "ATTITUDE": 0}
        while (msg := conn.recv_match(blocking=True, timeout=0.5)) is not None:
            if msg.get_type() in counts:
                counts[msg.get_type()] += 1
        assert counts["HEARTBEAT"] in (10, 11), counts
        assert counts["ATTITUDE"] == 1, counts
    finally:
        conn.close()
        server.close()


def test_sitl_heartbeats_go_on_while_the_simulator_stands_still(tmp_path):
    """End to end: ``scenenav sitl --lockstep``; the simulator process is stopped (SIGSTOP) for
    4.5 s, so no clock tick reaches the autopilot, as in a long lockstep wait. A ground station
    still gets a heartbeat every second."""
    sitl = SitlSession(tmp_path, "--lockstep", "--perception", "off")
    conn = None
    sim_pid = None
    try:
        sitl.wait_ready()
        conn = monitor_connection(sitl.port)
        assert heartbeat_times(conn, 2.0)["HEARTBEAT"], "no heartbeat at all"
        sim_pid = sitl.child_pid("sim")
        assert sim_pid is not None
        os.kill(sim_pid, signal.SIGSTOP)
        while conn.recv_match(blocking=True, timeout=0.05) is not None:
            pass                                  # what was sent before the stop
        start = time.monotonic()
        beats = heartbeat_times(conn, 4.5)["HEARTBEAT"]
        end = time.monotonic()
        os.kill(sim_pid, signal.SIGCONT)
        sim_pid = None
        assert len(beats) >= 3, beats
        assert max(gaps(beats, start, end)) < MAX_HEARTBEAT_GAP_S, gaps(beats, start, end)
    finally:
        if sim_pid is not None:
            os.kill(sim_pid, signal.SIGCONT)
        if conn is not None:
            conn.close()
        sitl.stop()
