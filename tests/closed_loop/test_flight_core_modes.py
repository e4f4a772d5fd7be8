"""The autopilot's flight core (``FlightCore``: arming checks, modes, GUIDED setpoints, parameters,
position sources) flying the simulator's core in-process (``support.sim_flight.CoreFlight``: the
pybullet rigid body, the sensor models with their default noise and biases, GPS at 5 Hz, vision
fixes made from the truth every 10th tick when switched on). Truth is used only in the assertions.
"""

from __future__ import annotations

import math

import numpy as np
from support.sim_flight import CoreFlight


def test_core_prearm_checks_and_modes():
    from autopilot_bridge.modes import CopterMode
    f = CoreFlight(gps=False, EK3_SRC1_POSXY=6, SN_VIS_MIN_ALT=0)
    c = f.core
    assert c.arm(False) == (False, "PreArm: EKF not ready")
    assert not c.set_mode(CopterMode.GUIDED).ok
    f.run(1.5)
    assert c.aligned
    assert c.set_mode(CopterMode.GUIDED).ok
    assert c.arm(False) == (False, "PreArm: no position source")   # no perception node followed
    c.set_vision_available(True)
    assert c.set_mode(CopterMode.AUTO) == (False, "Mode change to AUTO failed: no mission")
    assert c.arm(False).ok and c.armed
    assert c.takeoff(10.0).ok
    f.vision = True
    assert f.run(15, lambda: f.p[2] > 9.5)
    for mode in (CopterMode.LOITER, CopterMode.ALT_HOLD, CopterMode.STABILIZE):
        assert c.set_mode(mode).ok
        z0 = f.p[2]
        f.run(3)
        assert abs(f.p[2] - z0) < 2.0, (mode, f.p)   # no RC: hover / hold
    assert not c.disarm(False).ok                                # flying
    assert c.set_mode(CopterMode.LAND).ok
    assert f.run(60, lambda: not c.armed)
    assert f.p[2] < 0.2
    texts = [t for _, t in c.drain_texts()]
    assert "PreArm: EKF not ready" in texts and "PreArm: no position source" in texts


def test_core_guided_velocity_live_wpnav_speed_and_source_switch():
    from autopilot_bridge.modes import CopterMode
    from autopilot_bridge.vehicle_interface import AltFrame, LocalPositionTarget, MavFrame, SetpointKind, setpoint_kind
    f = CoreFlight(gps=True, SN_VIS_MIN_ALT=0)
    c = f.core
    f.run(1.5)
    assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok and c.takeoff(15.0).ok
    assert f.run(20, lambda: f.p[2] > 14.5)
    # GUIDED velocity target (NED): 3 m/s east for 3 s, then GUID_TIMEOUT stops it
    mask = 0b110111000111
    assert setpoint_kind(mask) == SetpointKind.VELOCITY
    nan3 = (math.nan,) * 3
    c.set_position_target_local_ned(LocalPositionTarget(
        0, MavFrame.LOCAL_NED, mask, SetpointKind.VELOCITY, nan3, (0.0, 3.0, 0.0), nan3, None,
        None))
    f.run(2.5)
    assert abs(f.v[0] - 3.0) < 0.5 and abs(f.v[1]) < 0.5
    f.run(4.0)
    assert math.hypot(*f.v[:2]) < 0.3                     # GUID_TIMEOUT (3 s): stopped
    # WPNAV_SPEED changes the speed of the leg being flown
    lat, lon = c.geo.to_geodetic(f.p[0] + 200.0, f.p[1])
    assert c.reposition(lat, lon, 15.0, AltFrame.RELATIVE_HOME, None, None).ok
    f.run(8)
    assert 9.0 < math.hypot(*f.v[:2]) < 11.0
    assert c.params.set("WPNAV_SPEED", 400).ok
    f.run(6)
    assert 3.3 < math.hypot(*f.v[:2]) < 4.7
    # GPS -> external navigation in flight (EK3_SRC1_POSXY), no jump
    f.vision = True
    before = c.estimate().position_enu_m.copy()
    assert c.params.set("EK3_SRC1_POSXY", 6).ok
    f.gps = False
    f.run(0.5)
    assert np.linalg.norm(c.estimate().position_enu_m[:2] - before[:2]) < 3.0
    f.run(5)
    assert np.linalg.norm(c.estimate().position_enu_m[:2] - f.p[:2]) < 2.0
    assert c.stats["vision_fused"] > 20 and not c.gps_used


def test_core_takes_mavlink_external_nav():
    from autopilot_bridge.vehicle_interface import Odometry
    f = CoreFlight(gps=False, EK3_SRC1_POSXY=6, VISO_TYPE=1)
    c = f.core
    f.run(1.5)
    origin = c.home_enu_m
    nan21 = (math.nan,) + (0.0,) * 20
    for _ in range(20):
        c.vision_position_estimate(0, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0, nan21, 0)   # NED from origin
        c.odometry(Odometry(0, 20, 21, (1.0, 2.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0,) * 3,
                            (0.0,) * 3, nan21, nan21, 0, 0, 100))
        f.run(0.1)
    assert c.stats["ext_nav_mavlink"] == 40
    est = c.estimate().position_enu_m
    # a fix 1 m north, 2 m east of the origin pulls the landed estimate that way
    assert est[0] - origin[0] > 0.3 and est[1] - origin[1] > 0.1
