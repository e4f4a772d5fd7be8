"""External vision the ArduPilot way (autopilot_bridge.external_vision) and its use in the flight
core: timestamps, lever arm, position and yaw error, reset_counter, quality, height and yaw from
external navigation with EK3_SRC1_POSZ / EK3_SRC1_YAW = 6."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.sim_flight import CoreFlight

from autopilot_bridge.external_vision import (
    JitterCorrection,
    ResetCounter,
    angle_error_rad,
    attitude_matrix,
    body_origin_ned,
    heading_of,
    position_error_m,
)
from autopilot_bridge.geo_frame import enu_to_ned
from autopilot_bridge.vehicle_interface import Odometry

NAN_COV = (math.nan,) + (0.0,) * 20


def test_jitter_correction_keeps_the_smallest_lag():
    j = JitterCorrection()
    assert j.local_time_s(1000.0, 5.05) == pytest.approx(5.05)     # first: offset from it
    assert j.local_time_s(1000.1, 5.20) == pytest.approx(5.15)     # 50 ms lag kept
    assert j.local_time_s(1000.2, 5.21) == pytest.approx(5.21)     # a smaller lag wins
    assert j.local_time_s(2000.0, 5.30) == pytest.approx(5.30)     # remote clock jump: reset


def test_position_error_and_floor():
    cov = [0.0] * 21
    cov[0], cov[6], cov[11] = 1.0, 1.0, 1.0
    assert position_error_m(cov, 0.2) == pytest.approx(3 ** (1 / 3))
    assert position_error_m(NAN_COV, 0.3) == 0.3
    small = [0.0] * 21
    small[0] = small[6] = small[11] = 0.01
    assert position_error_m(small, 0.2) == 0.2


def test_lever_arm_and_reset_counter():
    pos = body_origin_ned((10.0, 0.0, -5.0), attitude_matrix(0.0, 0.0, math.pi / 2), (1.0, 0.0, 0.0))
    assert pos == pytest.approx([10.0, -1.0, -5.0])       # facing east: the camera is 1 m east
    r = ResetCounter()
    assert [r.changed(c) for c in (3, 3, 4, 4)] == [False, False, True, False]


def test_flight_core_fuses_mavlink_vision_with_lever_arm_and_resets_on_counter():
    f = CoreFlight(11, gps=False, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=6, EK3_SRC1_VELXY=0,
                   VISO_TYPE=1, VISO_POS_X=1.0, VISO_QUAL_MIN=50)
    c = f.core
    try:
        f.run(3.0)
        assert c.aligned
        origin = c.estimate().position_enu_m.copy()
        start = np.asarray(enu_to_ned(c.estimate().position_enu_m - c._origin_enu()))
        heading = float(c.estimate().heading_rad)
        target = start + np.array([6.0, -4.0, 0.0])
        sensor = target + attitude_matrix(0.0, 0.0, heading) @ np.array([1.0, 0.0, 0.0])
        t0_us = 123_456_789
        c.vision_position_estimate(t0_us, *sensor, 0.0, 0.0, heading, NAN_COV, 0)
        c.vision_position_estimate(t0_us + 10_000, *sensor, 0.0, 0.0, heading, NAN_COV, 1)
        f.run(0.05)
        est = c.estimate().position_enu_m
        assert c.stats["ext_nav_resets"] == 1 and c.nav.position_reset_count >= 1
        moved = enu_to_ned(est - origin)
        assert moved[0] == pytest.approx(6.0, abs=0.3) and moved[1] == pytest.approx(-4.0, abs=0.3)
        bad = c.stats["ext_nav_low_quality"]
        c.odometry(Odometry(t0_us, 1, 8, tuple(sensor), (1.0, 0.0, 0.0, 0.0), (0.0,) * 3,
                            (0.0,) * 3, NAN_COV, NAN_COV, 1, 0, 10))
        assert c.stats["ext_nav_low_quality"] == bad + 1
    finally:
        f.close()


def test_yaw_error_from_the_attitude_covariance_and_heading_of_the_attitude():
    cov = [0.0] * 21
    cov[15], cov[18], cov[20] = 0.5, 0.5, 0.5                   # roll, pitch, yaw variances
    assert angle_error_rad(cov, 0.2) == pytest.approx(0.75 ** (1 / 3))
    assert angle_error_rad(NAN_COV[:15] + (math.nan,) * 6, 0.3) == 0.3
    assert angle_error_rad([0.0] * 21, 0.2) == 0.2               # VISO_YAW_M_NSE is the floor
    assert heading_of(attitude_matrix(0.1, -0.05, math.radians(250.0))) == pytest.approx(
        math.radians(250.0), abs=1e-9)


def _ext_nav_on_the_ground(posz: int, yaw: int) -> tuple[float, float]:
    """(estimated height change, heading change) after 4 s of external navigation on the ground
    that puts the vehicle 1 m higher and turned 0.3 rad clockwise."""
    f = CoreFlight(13, gps=False, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=6, EK3_SRC1_VELXY=0,
                   EK3_SRC1_POSZ=posz, EK3_SRC1_YAW=yaw, VISO_TYPE=1)
    c = f.core
    try:
        f.run(3.0)
        assert c.aligned
        est = c.estimate()
        z0, h0 = float(est.position_enu_m[2]), float(est.heading_rad)
        ned = np.asarray(enu_to_ned(est.position_enu_m - c._origin_enu()))
        pose = ned + np.array([0.0, 0.0, -1.0])
        for k in range(120):                                       # 30 Hz
            c.vision_position_estimate(5_000_000 + k * 33_333, *pose, 0.0, 0.0, h0 + 0.3, NAN_COV, 0)
            f.run(1.0 / 30.0)
        est = c.estimate()
        return float(est.position_enu_m[2]) - z0, math.remainder(float(est.heading_rad) - h0, 2 * math.pi)
    finally:
        f.close()


def test_ext_nav_height_and_yaw_used_only_when_the_source_set_says_so():
    dz, dh = _ext_nav_on_the_ground(posz=6, yaw=6)
    assert dz == pytest.approx(1.0, abs=0.25) and dh == pytest.approx(0.3, abs=0.08), (dz, dh)
    dz, dh = _ext_nav_on_the_ground(posz=1, yaw=1)                 # baro and compass
    assert abs(dz) < 0.3 and abs(dh) < 0.05, (dz, dh)


def test_set_gps_global_origin_before_alignment_moves_the_ekf_origin_not_the_vehicle():
    f = CoreFlight(17, gps=False, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=6, EK3_SRC1_VELXY=0, VISO_TYPE=1)
    c = f.core
    try:
        lat, lon = c.geo.to_geodetic(100.0, -50.0)
        alt = c.geo.origin_alt_amsl_m + 2.0
        assert c.set_gps_global_origin(lat, lon, alt).ok
        f.run(3.0)
        assert c.aligned
        tel = c.telemetry()
        assert tel.origin_set and (tel.origin_lat_deg, tel.origin_lon_deg) == pytest.approx((lat, lon))
        assert tel.origin_alt_amsl_m == pytest.approx(alt)
        pos = c.estimate().position_enu_m                      # still at the known take-off point
        assert tel.position_ned_m == pytest.approx(enu_to_ned(pos - np.array([100.0, -50.0, 2.0])), abs=1e-6)
        assert not c.set_gps_global_origin(0.0, 0.0, 0.0).ok    # set once: it stays
    finally:
        f.close()
