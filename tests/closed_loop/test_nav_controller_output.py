"""NAV_CONTROLLER_OUTPUT's data from the flight core (ArduCopter's send_nav_controller_output): the
attitude target, the bearing and distance to the waypoint, the vertical position error and the
cross-track error, on the in-process flight (``CoreFlight``: the flight core on the simulator's core)."""

from __future__ import annotations

import math

from support.sim_flight import CoreFlight

from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import AltFrame


def test_nav_controller_output_follows_the_guided_target():
    f = CoreFlight(3, gps=True, SN_VIS_TIMEOUT=0)
    c = f.core
    for _ in range(150):
        f.tick()
    tel = c.telemetry()
    assert (tel.wp_dist_m, tel.alt_error_m, tel.xtrack_error_m) == (0.0, 0.0, 0.0)  # disarmed
    assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok and c.takeoff(10.0).ok
    climbing = []
    while f.t < 40.0 and f.p[2] < 9.5:
        f.tick()
        if f.p[2] > 1.0:
            climbing.append(c.telemetry().alt_error_m)
    assert f.p[2] >= 9.5 and climbing and max(climbing) > 0.2     # the target leads the climb
    for _ in range(200):
        f.tick()
    est = c.estimate()
    east, north = float(est.position_enu_m[0]), float(est.position_enu_m[1]) + 30.0
    lat, lon = c.geo.to_geodetic(east, north)
    assert c.reposition(lat, lon, 10.0, AltFrame.RELATIVE_HOME, None, None).ok
    f.tick()
    tel = c.telemetry()
    assert abs(tel.wp_dist_m - 30.0) < 1.5
    assert min(tel.target_bearing_deg, 360.0 - tel.target_bearing_deg) < 5.0      # due north
    assert tel.xtrack_error_m < 1.0
    for _ in range(300):
        f.tick()
    tel = c.telemetry()
    assert tel.wp_dist_m < 25.0                                   # on its way
    assert tel.nav_pitch_deg < -1.0 or tel.wp_dist_m < 5.0        # nose down to accelerate north
    assert math.isfinite(tel.nav_roll_deg) and 0.0 <= tel.nav_bearing_deg < 360.0
