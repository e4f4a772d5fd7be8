"""MAVProxy as a person at the ground station uses it, against ``scenenav sitl --lockstep`` (the
simulator waits for the autopilot, so the flight is the same on a loaded machine; MAVProxy and the
heartbeats run on the wall clock): ``guided LAT LON ALT`` (DO_REPOSITION), ``changealt``
(DO_CHANGE_ALTITUDE, UNSUPPORTED as in ArduCopter 4.5, and MISSION_ITEM current=3: accepted, nothing
moves, as ArduCopter), ``wp load`` + ``wp loop`` (DO_JUMP for ever: the mission comes round to item
1 again), ALT_HOLD with ``rc 3 1500`` (mid stick holds the altitude, RC_CHANNELS shows it),
``fence load`` of a polygon, ``fence enable`` (DO_FENCE_ENABLE; MAVProxy reads the SYS_STATUS
GEOFENCE bits), and a ``guided`` target outside it: "Fence Breached",
FENCE_ACTION 1 = RTL, landed within 2 m of home (truth.csv)."""

from __future__ import annotations

import math

from pymavlink import mavutil
from support.fake_vehicle import _backlog, wait_for
from support.lineproc import MavproxyProcess
from support.sitl_session import (
    TIMEOUT_S,
    SitlSession,
    enu_to_latlon,
    final_position,
    monitor_connection,
    world_origin,
    wpl_file,
    write_params,
)

SQUARE = [(30.0, 0.0), (30.0, 30.0), (0.0, 30.0), (-10.0, 10.0)]
FENCE_HALF_M = 45.0
PARAMS = {"RTL_LOIT_TIME": 0, "LAND_SPEED": 200, "WPNAV_SPEED_DN": 300, "DISARM_DELAY": 30,
          "RC_OVERRIDE_TIME": -1, "FENCE_TYPE": 4, "FENCE_ACTION": 1}


def fresh(conn, kind: str, timeout_s: float = TIMEOUT_S, condition=None):
    """The first ``kind`` from now on (the monitor's backlog holds everything since the start)."""
    _backlog(conn).clear()
    return wait_for(conn, kind, timeout_s, condition)


def rel_alt_m(conn) -> float:
    msg = fresh(conn, "GLOBAL_POSITION_INT", 10.0)
    return math.nan if msg is None else msg.relative_alt * 1e-3


def _fence_file(path) -> None:
    """MAVProxy's lat/lon fence file: return point, the polygon's vertices, the first one again."""
    corners = [(-FENCE_HALF_M, -FENCE_HALF_M), (FENCE_HALF_M, -FENCE_HALF_M),
               (FENCE_HALF_M, FENCE_HALF_M), (-FENCE_HALF_M, FENCE_HALF_M)]
    pts = [(0.0, 0.0), *corners, corners[0]]
    path.write_text("".join("%.7f %.7f\n" % enu_to_latlon(x, y) for x, y in pts))


def test_mavproxy_guided_changealt_loop_rc_and_fence_breach_rtl(tmp_path):
    wpl = tmp_path / "square.txt"
    wpl_file(wpl, world_origin(), SQUARE, 20.0)
    fence = tmp_path / "fence.txt"
    _fence_file(fence)
    sitl = SitlSession(tmp_path, "--lockstep", "--perception", "off",
                       "--set", "autopilot.params_file=" + write_params(tmp_path, **PARAMS))
    mp = monitor = None
    try:
        sitl.wait_ready()
        mp = MavproxyProcess(sitl.port, tmp_path, timeout_s=TIMEOUT_S)
        mp.expect("parameters")
        monitor = monitor_connection(sitl.port)
        ekf = fresh(monitor, "EKF_STATUS_REPORT", TIMEOUT_S,
                    lambda m: m.flags & mavutil.mavlink.EKF_POS_HORIZ_ABS)
        assert ekf is not None, "the EKF never reported a horizontal position"
        mark = mp.send("mode GUIDED")
        mp.expect("GUIDED>", mark)
        mark = mp.send("arm throttle")
        mp.expect("ARMED", mark)
        mp.send("takeoff 20")
        assert fresh(monitor, "GLOBAL_POSITION_INT", TIMEOUT_S, lambda p: p.relative_alt > 19_000)

        lat, lon = enu_to_latlon(-10.0, 10.0)
        mp.send(f"guided {lat:.7f} {lon:.7f} 20")                        # DO_REPOSITION
        assert fresh(monitor, "LOCAL_POSITION_NED", TIMEOUT_S,
                     lambda p: p.x > 8.0 and p.y < -8.0), "guided never got there"
        mark = mp.send("changealt 30")
        mp.expect("Sent change altitude", mark)
        assert abs(rel_alt_m(monitor) - 20.0) < 2.0                      # ArduCopter: nothing moves

        # the mission uploads' own acknowledgements, not any "ACCEPTED": a COMMAND_ACK of the
        # commands above may print after the next command is sent (a loaded machine)
        mark = mp.send(f"wp load {wpl}")
        mp.expect("TYPE_MISSION: ACCEPTED", mark)
        mark = mp.send("wp loop")                                         # DO_JUMP to 1, for ever
        mp.expect("Closed loop on mission", mark)
        mp.expect("TYPE_MISSION: ACCEPTED", mp.expect("Sent all", mark))  # the looped mission's upload
        mark = mp.send("mode AUTO")
        mp.expect("AUTO>", mark)
        round_again = mp.expect("Reached command #1", mp.expect("Reached command #4", mark))
        assert round_again > mark

        mark = mp.send("mode ALT_HOLD")
        mp.expect("ALT_HOLD>", mark)
        mp.send("rc 3 1500")                                              # mid stick: hold
        monitor.mav.request_data_stream_send(1, 1, mavutil.mavlink.MAV_DATA_STREAM_RC_CHANNELS, 4, 1)
        assert fresh(monitor, "RC_CHANNELS", 30, lambda m: m.chan3_raw == 1500) is not None
        z0 = rel_alt_m(monitor)
        t0 = fresh(monitor, "SYSTEM_TIME", 10).time_boot_ms
        assert fresh(monitor, "SYSTEM_TIME", 60, lambda m: m.time_boot_ms > t0 + 5000)
        assert abs(rel_alt_m(monitor) - z0) < 1.5, "ALT_HOLD did not hold"
        mp.send("rc 3 0")                                                 # release the stick

        mark = mp.send("mode GUIDED")
        mp.expect("GUIDED>", mark)
        mark = mp.send(f"fence load {fence}")
        mp.expect("TYPE_FENCE: ACCEPTED", mark)
        mark = mp.send("fence enable")                                    # MAV_CMD_DO_FENCE_ENABLE 1
        mp.expect("fence enabled", mark)                                  # from SYS_STATUS's bits
        lat, lon = enu_to_latlon(FENCE_HALF_M + 30.0, 0.0)
        mark = mp.send(f"guided {lat:.7f} {lon:.7f} 20")                  # out through the fence
        mp.expect("Fence Breached", mark)
        mp.expect("RTL>", mark)                                           # FENCE_ACTION 1
        mp.expect("DISARMED", mark)
    finally:
        if monitor is not None:
            monitor.close()
        if mp is not None:
            mp.close()
        sitl.stop()

    truth = sitl.truth()
    assert max(truth["x_m"]) > FENCE_HALF_M - 5.0                     # it did fly to the fence
    assert max(truth["x_m"]) < FENCE_HALF_M + 25.0                    # RTL turned it back (a 10 m/s stop)
    end = final_position(truth)
    assert math.hypot(end[0], end[1]) < 2.0, f"landed {end} m from home (0, 0)"
    events = sitl.events()
    assert "Fence Breached" in events, events[-30:]
