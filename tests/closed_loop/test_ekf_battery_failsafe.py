"""EKF and battery failsafes on the in-process flight (``CoreFlight``: the flight core on the
simulator's core), one short flight: in GUIDED at 8 m, FS_EKF_THRESH below the EKF's real variances
with FS_EKF_ACTION 2 -> "EKF variance" and ALT_HOLD; then the EKF failsafe off and BATT_LOW_VOLT
above the power module's voltage with BATT_FS_LOW_ACT 2 -> "Battery 1 is low ..." after
BATT_LOW_TIMER and RTL. Each announced as a CRITICAL STATUSTEXT, HEARTBEAT CRITICAL."""

from __future__ import annotations

import pytest
from support.sim_flight import CoreFlight

from autopilot_bridge.config import PositionSource
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    HomeLocation,
    MavSeverity,
    StatusTextEvent,
    SystemStatus,
)


def _texts(core) -> list[tuple[MavSeverity, str]]:
    return [(e.severity, e.text) for e in core.drain_events() if isinstance(e, StatusTextEvent)]


def test_ekf_then_battery_failsafe_in_flight():
    f = CoreFlight(7, gps=True, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=3, EK3_SRC1_VELXY=3)
    c = f.core
    try:
        f.run(3.0)
        assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok and c.takeoff(8.0).ok
        assert f.run(25.0, until=lambda: f.p[2] > 7.5)
        _texts(c)
        tel = c.telemetry()      # RAW_IMU / VIBRATION / POSITION_TARGET_* data in flight
        assert tel.imu_accel_frd_m_s2[2] == pytest.approx(-9.8, abs=1.5)     # FRD: z down
        assert all(0.0 <= v < 3.0 for v in tel.vibration_m_s2)
        assert tel.target_position_ned_m is not None
        assert tel.target_position_ned_m[2] == pytest.approx(-8.0, abs=1.0)  # the take-off height
        assert abs(tel.target_alt_amsl_m - c.geo.origin_alt_amsl_m - 8.0) < 1.0
        f.params.set("FS_EKF_ACTION", 2)
        f.params.set("FS_EKF_THRESH", 0.001)      # below any real variance: "bad" at once
        assert f.run(0.8, until=lambda: c.mode != CopterMode.GUIDED) is False   # needs 1 s
        assert f.run(1.0, until=lambda: c.mode == CopterMode.ALT_HOLD)
        assert (MavSeverity.CRITICAL, "EKF variance") in _texts(c)
        assert c.telemetry().system_status == SystemStatus.CRITICAL

        f.params.set("FS_EKF_THRESH", 0.0)        # EKF failsafe off
        f.params.set("BATT_LOW_TIMER", 1)
        f.params.set("BATT_FS_LOW_ACT", 2)        # RTL
        f.params.set("BATT_LOW_VOLT", 99.0)       # above the power module's voltage
        assert f.run(3.0, until=lambda: c.mode == CopterMode.RTL)
        texts = _texts(c)
        assert any(sev == MavSeverity.CRITICAL and t.startswith("Battery 1 is low ")
                   for sev, t in texts), texts
        assert c.telemetry().system_status == SystemStatus.CRITICAL
        assert c.stats["failsafe_battery_rtl"] == 1 and c.stats["failsafe_ekf_alt_hold"] == 1
    finally:
        f.close()


def test_do_set_home_on_the_flight_core_is_kept_at_arming():
    f = CoreFlight(8, gps=True, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=3, EK3_SRC1_VELXY=3)
    c = f.core
    try:
        assert not c.set_home(None).ok                       # before the EKF is aligned
        f.run(3.0)
        lat, lon = c.geo.to_geodetic(30.0, -20.0)
        assert c.set_home(HomeLocation(lat, lon, c.geo.origin_alt_amsl_m + 2.0, AltFrame.AMSL)).ok
        assert c.home_enu_m == pytest.approx([30.0, -20.0, 2.0], abs=1e-6)
        far_lat, far_lon = c.geo.to_geodetic(60_000.0, 0.0)
        assert not c.set_home(HomeLocation(far_lat, far_lon, 0.0, AltFrame.AMSL)).ok
        assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok
        assert c.home_enu_m == pytest.approx([30.0, -20.0, 2.0], abs=1e-6)   # locked: kept
        assert c.telemetry().home_set
    finally:
        f.close()


def test_ekf_source_set_switches_the_position_source():
    f = CoreFlight(8, gps=True, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=3, EK3_SRC1_VELXY=3,
                   EK3_SRC2_POSXY=6)
    c = f.core
    try:
        assert c.position_source == PositionSource.GPS
        assert c.set_ekf_source_set(2).ok and c.position_source == PositionSource.EXTNAV
        f.params.set("EK3_SRC2_POSXY", 3)              # the active set's parameter applies at once
        assert c.position_source == PositionSource.GPS
        assert c.set_ekf_source_set(1).ok and c.position_source == PositionSource.GPS
        assert not c.set_ekf_source_set(4).ok
    finally:
        f.close()
