"""SN_VIS_MAX_SD on the in-process flight (``CoreFlight``: the flight core on the simulator's core,
GPS off, EK3_SRC1_POSXY 6, fixes from truth + 0.7 m noise every 0.1 s).

Cruising north on good fixes, the fixes turn into a consistent false lock 150 m east published with
a covariance as wide as a search area (1-sigma 79 m, what perception publishes for an ambiguous
match). Each fix passes the EKF's gate and moves the estimate a little; at ten a second they walk it
away while the filter's own 1-sigma stays small, and the vision failsafe never hears of it. With
SN_VIS_MAX_SD below their width one of them is fused every 5 s (the others only tell the vision
failsafe that perception is matching): the estimate dead-reckons, nearly unmoved by them. Truth is
used only in the assertions."""

from __future__ import annotations

import numpy as np
from support.sim_flight import CoreFlight

from autopilot_bridge.failsafe import VisionFailsafeState
from autopilot_bridge.vehicle_interface import AltFrame

FALSE_LOCK_OFFSET_M = np.array([150.0, 0.0])
WIDE_COV_M2 = np.eye(2) * 79.0 ** 2


def _false_lock_after_cruise(max_sd_m: float) -> CoreFlight:
    f = CoreFlight(6, gps=False, EK3_SRC1_POSXY=6, EK3_SRC1_VELXY=0, SN_VIS_MIN_ALT=10,
                   SN_VIS_TIMEOUT=3, SN_VIS_FS_LAND=5, SN_VIS_DR_MAX=8, WPNAV_SPEED=1000,
                   SN_VIS_MAX_SD=max_sd_m)
    f.vision = True
    c = f.core
    c.set_vision_available(True)
    f.arm_in_guided()
    assert c.takeoff(20.0).ok
    assert f.run(40.0, until=lambda: f.p[2] > 19.0), "the climb did not reach 19 m"
    est = c.estimate()
    lat, lon = c.geo.to_geodetic(float(est.position_enu_m[0]), float(est.position_enu_m[1]) + 600.0)
    assert c.reposition(lat, lon, 20.0, AltFrame.RELATIVE_HOME, None, None).ok
    f.run(15.0)
    f.vision_offset_m = FALSE_LOCK_OFFSET_M
    f.vision_cov_m2 = WIDE_COV_M2
    f.run(15.0)
    return f


def _error_m(f: CoreFlight) -> float:
    return float(np.linalg.norm(np.asarray(f.core.estimate().position_enu_m[:2]) - f.p[:2]))


def test_wide_false_fixes_walk_the_estimate_away_when_every_fix_is_fused():
    f = _false_lock_after_cruise(0.0)
    assert _error_m(f) > 30.0, _error_m(f)
    assert f.core.failsafe.vision_state == VisionFailsafeState.NORMAL     # nobody noticed
    f.close()


def test_sn_vis_max_sd_fuses_one_wide_fix_in_five_seconds():
    f = _false_lock_after_cruise(30.0)
    assert _error_m(f) < 8.0, _error_m(f)
    assert f.core.failsafe.vision_state == VisionFailsafeState.NORMAL     # fixes keep coming
    assert f.core.stats["vision_wide_fused"] in (3, 4), f.core.stats     # 15 s at one per 5 s
    assert f.core.stats["vision_wide_skipped"] > 100
    f.close()
