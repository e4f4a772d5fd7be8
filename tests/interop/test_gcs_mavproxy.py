"""MAVProxy flies ``scenenav sitl``: real processes, real bus, real MAVLink bytes.

A scripted MAVProxy session (stdin/stdout pipes) against ``scenenav sitl --speedup 3``: GUIDED, arm,
takeoff 20, ``guided LAT LON ALT`` (DO_REPOSITION), ``changealt`` (accepted, no effect, as
ArduCopter), ``wp load`` of a 4-waypoint QGC WPL 110 file closed with ``wp loop`` (DO_JUMP, for
ever), AUTO through the mission and round the loop to item 1 again, ALT_HOLD with ``rc 3 1500``
holding the altitude, RTL, and the vehicle must land within 2 m of home -- measured from the run's
``truth.csv`` (ground truth), not from the autopilot's own report. A pymavlink monitor on a second TCP link watches altitude and
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

#: real-time SITL flights: `make test` runs them alone, after the parallel part
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
        # RC_OVERRIDE_TIME: MAVProxy repeats `rc` overrides once a wall second, 3 simulated s at 3x
        for name, value in (("RTL_LOIT_TIME", 1000), ("LAND_SPEED", 100), ("DISARM_DELAY", 30),
                            ("RC_OVERRIDE_TIME", 10)):
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
        lat, lon = enu_to_latlon(-10.0, 10.0)
        mp.send(f"guided {lat:.7f} {lon:.7f} 20")                 # DO_REPOSITION
        assert wait_until(lambda: (lambda p: p is not None and p.x > 7.0 and p.y < -7.0)(
            wait_for(monitor, "LOCAL_POSITION_NED", timeout_s=5)), 60), "guided never got there"
        mark = mp.send("changealt 30")                                # MISSION_ITEM current=3
        mp.expect("Sent change altitude", mark)

        mark = mp.send(f"wp load {wpl}")
        mp.expect("ACCEPTED", mark)
        mark = mp.send("wp loop")                                     # DO_JUMP to 1, for ever
        mp.expect("Closed loop on mission", mark)
        mp.expect("ACCEPTED", mark)
        mark = mp.send("mode AUTO")
        mp.expect("AUTO>", mark)
        looped = mp.expect("Reached command #1", mp.expect("Reached command #4", mark))
        reached = wait_for(monitor, "MISSION_ITEM_REACHED", timeout_s=30, condition=lambda m: m.seq == 1)
        assert reached is not None and looped > 0

        mark = mp.send("mode ALT_HOLD")
        mp.expect("ALT_HOLD>", mark)
        mp.send("rc 3 1500")                                          # throttle at mid stick: hold
        monitor.mav.request_data_stream_send(1, 1, mavutil.mavlink.MAV_DATA_STREAM_RC_CHANNELS, 4, 1)
        z0 = relative_alt_m(monitor) or 0.0
        rc = wait_for(monitor, "RC_CHANNELS", timeout_s=30, condition=lambda m: m.chan3_raw == 1500)
        assert rc is not None
        assert abs((relative_alt_m(monitor) or 0.0) - z0) < 1.5

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
