"""Arming, disarming, pre-arm checks (also on RUN_PREARM_CHECKS), DO_SET_HOME and auto-disarm (part of ``FlightCore``), as ArduCopter:
GCS arming only in the armable modes, ARMING_CHECK 0 skips the checks, LAND disarms at touchdown,
other modes DISARM_DELAY s after landing.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import numpy as np

from autopilot_bridge.config import PositionSource
from autopilot_bridge.flight_laws import LawKind
from autopilot_bridge.modes import ARMABLE_MODES, NEEDS_POSITION, POSITION_MODES, CopterMode
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    HomeChangedEvent,
    HomeLocation,
    MavSeverity,
    Outcome,
)
from scenenav.core.contracts import GpsFixType

GPS_FRESH_S = 2.0
HOME_MAX_FROM_ORIGIN_M = 50_000.0   # ArduPilot AP_AHRS EKF_ORIGIN_MAX_DIST_M


class ArmingMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def arm(self, force: bool) -> Outcome:
        if self._armed:
            return Outcome(True)
        if not self.nav.aligned:
            return self._refuse("PreArm: EKF not ready")
        if self.motor_test_state.running:
            return self._refuse("Arm: Motor test running")
        if not force and self.params.get_int("ARMING_CHECK") != 0:
            failures = self._prearm_failures()
            if failures:
                for text in failures[1:]:
                    self._texts.append((MavSeverity.CRITICAL, text))
                return self._refuse(failures[0])
        est = self.nav.state()
        self._armed = True
        self._tel = None
        self.fc.reset(est, landed=True)
        self._landed_since_s = self._now_s
        if not self._home_locked:   # ArduCopter keeps a home set by DO_SET_HOME (locked)
            self._home = np.array([float(est.position_enu_m[0]), float(est.position_enu_m[1]),
                                   self._home_z()])
            self._events.append(HomeChangedEvent())
        if self._mode in POSITION_MODES:
            self._law = None
            self._start_mode_law(est)
        self._bus_text(MavSeverity.INFO, f"armed in {self._mode.name}" + (" (forced)" if force else ""))
        return Outcome(True)

    def disarm(self, force: bool) -> Outcome:
        if not self._armed:
            return Outcome(True)
        if not force and not self.fc.landed:
            return self._refuse("Disarm: vehicle is flying")
        self._disarm("forced" if force else "command")
        return Outcome(True)

    def _disarm(self, why: str) -> None:
        if not self._armed:
            return
        self._armed = False
        self._tel = None
        self._motors = np.zeros(4)
        self._vision_hold = None
        self.failsafe.reset()
        self._landed_since_s = None
        if self.nav.aligned:
            est = self.nav.state()
            self._ground_xy = np.array(est.position_enu_m[:2], dtype=float)
            self.fc.reset(est, landed=True)
        self._bus_text(MavSeverity.INFO, f"disarmed ({why})")

    def run_prearm_checks(self) -> list[str]:
        """RUN_PREARM_CHECKS: the texts of every failing check (ArduCopter runs them all)."""
        return self._prearm_failures()

    def set_home(self, home: HomeLocation | None) -> Outcome:
        """DO_SET_HOME: at the current position (None) or at ``home``; ArduPilot refuses a home
        more than 50 km from the EKF origin (``AP_AHRS::set_home``, far_from_EKF_origin)."""
        if not self.nav.aligned or self._origin is None:
            return self._refuse("Set home failed: no position estimate")
        if home is None:
            est = self.nav.state()
            new = np.asarray(est.position_enu_m, dtype=float).copy()
        else:
            x, y = self.geo.to_enu(home.lat_deg, home.lon_deg)
            if home.alt_frame == AltFrame.RELATIVE_HOME:
                z = (float(self._home[2]) if self._home is not None else self._home_z()) + home.alt_m
            else:
                z = home.alt_m - self.geo.origin_alt_amsl_m
            new = np.array([x, y, z])
        if float(np.linalg.norm(new[:2] - self._origin[:2])) > HOME_MAX_FROM_ORIGIN_M:
            return self._refuse("Set home failed: too far from EKF origin")
        self._home = new
        self._home_locked = True
        self._tel = None
        self._events.append(HomeChangedEvent())
        self._bus_text(MavSeverity.INFO, f"home set at ({new[0]:.1f}, {new[1]:.1f}, {new[2]:.1f}) m")
        return Outcome(True)

    def _prearm_failures(self) -> list[str]:
        if not self.nav.aligned or not self.nav.is_healthy():
            return ["PreArm: EKF not ready"]
        out = []
        if self._mode not in ARMABLE_MODES:
            out.append("Arm: Mode not armable")
        if self._mode in NEEDS_POSITION:
            source = self.nav.position_source
            if source == PositionSource.NONE:
                out.append("PreArm: no position source")
            elif source == PositionSource.GPS and not self._gps_fix_fresh():
                out.append("PreArm: Need 3D Fix")
            elif source == PositionSource.EXTNAV and not self._ext_nav_available():
                out.append("PreArm: no position source")
            elif self._climb_dead_reckoned() and not self.nav.gyro_bias_learned():
                out.append("PreArm: gyro bias not learned yet (keep still)")
            elif not self.nav.position_ok():
                out.append("PreArm: Need Position Estimate")
        return out

    def _gps_fix_fresh(self) -> bool:
        g = self._last_gps
        return (g is not None and g.fix_type >= GpsFixType.FIX_3D
                and self._now_s - g.t_s <= GPS_FRESH_S)

    def _climb_dead_reckoned(self) -> bool:
        """Scene-matching fixes as the position source, used only above SN_VIS_MIN_ALT, and no
        MAVLink external navigation: the climb to SN_VIS_MIN_ALT has no horizontal aiding, and a
        residual x, y gyro bias eps drifts it by g eps t^3 / 6 (38 m for a 30 s climb with the 0.85
        mrad/s a 1 s alignment left: issue 12). Such a take-off waits at rest until the zero-rate
        update has learnt the bias (``NavFilter.gyro_bias_learned``)."""
        mavlink = (self._last_ext_nav_s is not None
                   and self._now_s - self._last_ext_nav_s <= self.cfg.ext_nav_fresh_s)
        return (self.nav.position_source == PositionSource.EXTNAV and not mavlink
                and self.params.get("SN_VIS_MIN_ALT") > 0.0)

    def _ext_nav_available(self) -> bool:
        mavlink = (self._last_ext_nav_s is not None
                   and self._now_s - self._last_ext_nav_s <= self.cfg.ext_nav_fresh_s)
        return self._vision_available or mavlink

    def _auto_disarm_check(self) -> None:
        if not self._armed:
            self._landed_since_s = None
            return
        if not self.fc.landed or self._law_kind() == LawKind.TAKEOFF or self._climb_demanded():
            self._landed_since_s = None
            return
        if self._mode == CopterMode.LAND:
            self._disarm("landed")
            return
        if self._landed_since_s is None:
            self._landed_since_s = self._now_s
        delay = self.params.get("DISARM_DELAY")
        if delay > 0 and self._now_s - self._landed_since_s >= delay:
            self._announce(MavSeverity.INFO, "Auto disarm: landed")
            self._disarm("auto disarm")

    def _climb_demanded(self) -> bool:
        g = self._guided
        return (self._mode == CopterMode.GUIDED and g is not None and g.velocity_enu_m_s is not None
                and float(g.velocity_enu_m_s[2]) > self.fc.config.takeoff_min_climb_m_s)
