"""BRAKE (QGC's Pause) and POSHOLD (MAVSDK's hold / position control) on the in-process flight
(``CoreFlight``: the flight core on the simulator's core): BRAKE stops at ArduCopter's 7.5 m/s/s, sooner than LOITER's WPNAV_ACCEL stop,
then holds; POSHOLD without pilot input holds; arming is allowed in POSHOLD, not in BRAKE."""

from __future__ import annotations

import math

import numpy as np
from support.sim_flight import CoreFlight

from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import AltFrame

GPS_EVERY_TICKS = 20          # 5 Hz at the 100 Hz control rate


class GpsFlight(CoreFlight):
    """CoreFlight navigating on the simulator's GPS (EK3_SRC1_POSXY/VELXY 3), vision failsafe off."""

    def __init__(self, seed: int) -> None:
        super().__init__(seed, gps=True, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=3, EK3_SRC1_VELXY=3)


def _cruise_then(mode: CopterMode) -> tuple[float, float]:
    """Fly north in GUIDED at cruise speed, switch to ``mode``; (metres flown after the switch,
    drift over the 8 s after that) from the truth."""
    f = GpsFlight(5)
    c = f.core
    for _ in range(300):
        f.tick()
    assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok and c.takeoff(10.0).ok
    while f.p[2] < 9.5:
        f.tick()
        assert f.t < 40.0
    est = c.estimate()
    lat, lon = c.geo.to_geodetic(float(est.position_enu_m[0]), float(est.position_enu_m[1]) + 200.0)
    assert c.reposition(lat, lon, 10.0, AltFrame.RELATIVE_HOME, None, None).ok
    t0 = f.t
    while f.t < t0 + 12.0:
        f.tick()
    assert math.hypot(float(f.v[0]), float(f.v[1])) > 4.0         # cruising
    start = np.array(f.p[:2])
    assert c.set_mode(mode).ok
    t1 = f.t
    while f.t < t1 + 10.0:
        f.tick()
    stopped = np.array(f.p[:2])
    t2 = f.t
    while f.t < t2 + 8.0:
        f.tick()
    return float(np.linalg.norm(stopped - start)), float(np.linalg.norm(np.array(f.p[:2]) - stopped))


def test_brake_stops_sooner_than_loiter_and_holds():
    brake_m, brake_drift = _cruise_then(CopterMode.BRAKE)
    loiter_m, _ = _cruise_then(CopterMode.LOITER)
    assert brake_m < loiter_m - 1.0, (brake_m, loiter_m)
    assert brake_drift < 1.0


def test_poshold_holds_and_arming_rules():
    held_m, drift = _cruise_then(CopterMode.POSHOLD)
    assert held_m < 30.0 and drift < 1.0
    f = GpsFlight(7)
    c = f.core
    for _ in range(300):
        f.tick()
    assert c.set_mode(CopterMode.BRAKE).ok
    assert not c.arm(False).ok                     # ArduCopter: BRAKE does not allow arming
    assert c.set_mode(CopterMode.POSHOLD).ok and c.arm(False).ok
