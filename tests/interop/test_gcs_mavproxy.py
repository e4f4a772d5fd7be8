"""MAVProxy flies ``scenenav sitl``: real processes, real bus, real MAVLink bytes.

A scripted MAVProxy session (stdin/stdout pipes) against ``scenenav sitl --speedup 3``: GUIDED, arm,
takeoff 20, ``wp load`` of a 4-waypoint QGC WPL 110 file, AUTO through the mission, RTL, and the
vehicle must land within 2 m of home -- measured from the run's ``truth.csv`` (ground truth), not
from the autopilot's own report. A pymavlink monitor on a second TCP link watches altitude and
MISSION_ITEM_REACHED. ``SitlSession`` is shared with test_gcs_mavsdk.py and test_failsafe.py.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pymavlink import mavutil
from support import REPO_ROOT
from support.lineproc import MavproxyProcess, wait_until

REPO = REPO_ROOT
from support.sitl_session import (  # noqa: F401
    STOP_TIMEOUT_S,
    TIMEOUT_S,
    SitlSession,
    _is_scenenav,
    enu_to_latlon,
    final_position,
    monitor_connection,
    read_columns,
    relative_alt_m,
    world_origin,
    wpl_file,
)

#: real-time SITL flights: `make test` runs them after the parallel part, apart from it
pytestmark = pytest.mark.realtime


def test_mavproxy_guided_takeoff_mission_and_rtl(tmp_path):
    from support.fake_vehicle import wait_for
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
            assert wait_until(lambda name=name, value=value: sitl.param(name) == value, 30), f"{name} not set"
        monitor = monitor_connection(sitl.port)
        # GUIDED needs a position, as in ArduCopter: wait for the EKF (parameters now arrive by
        # MAVFTP within a second, before the EKF has aligned). From its streamed EKF_STATUS_REPORT,
        # as a ground station does: the one-off "EKF3 IMU0 is using GPS" text is sent only to the
        # links connected at that moment, and a MAVProxy slow to start on a loaded machine missed it.
        ekf = wait_for(monitor, "EKF_STATUS_REPORT", timeout_s=TIMEOUT_S,
                       condition=lambda m: m.flags & mavutil.mavlink.EKF_POS_HORIZ_ABS)
        assert ekf is not None, "the EKF never reported a horizontal position"
        mark = mp.send("mode GUIDED")
        mp.expect("GUIDED>", mark)
        mark = mp.send("arm throttle")
        mp.expect("ARMED", mark)
        mp.send("takeoff 20")
        assert wait_until(lambda: (relative_alt_m(monitor) or 0.0) > 19.0), "takeoff never reached 19 m"

        mark = mp.send(f"wp load {wpl}")
        mp.expect("TYPE_MISSION: ACCEPTED", mark)
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
