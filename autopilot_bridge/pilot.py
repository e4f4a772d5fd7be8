"""Flying by hand (part of ``FlightCore``): the pilot's sticks from RC_CHANNELS_OVERRIDE /
MANUAL_CONTROL (``rc_input``) in STABILIZE, ALT_HOLD, LOITER and POSHOLD, and the radio failsafe
when those overrides stop (FS_THR_ENABLE, RC_OVERRIDE_TIME).

* STABILIZE: lean angles, yaw rate and ArduCopter's throttle curve; ALT_HOLD: lean angles, yaw
  rate and climb rate (takeoff on a climb demand from the ground, as ArduCopter);
* LOITER and POSHOLD: the sticks move the held point at up to LOIT_SPEED (roll right, pitch
  forward = nose down, in the vehicle's heading), the throttle climbs or descends, yaw turns;
  centred sticks hold the point. Differs: ArduCopter's loiter shapes the pilot's demand as an
  acceleration (LOIT_ACC_MAX, LOIT_BRK_*), and POSHOLD mixes lean angles with braking; both are
  the same velocity-to-point law here;
* without overrides (none yet, or expired) each mode flies as before: STABILIZE at the hover
  thrust, ALT_HOLD holding the altitude, LOITER / POSHOLD holding the point.

Radio failsafe: once overrides arrived while armed, RC_OVERRIDE_TIME without one triggers
"Radio Failsafe" with the FS_THR_ENABLE action (disarm when landed, as ArduCopter's
should_disarm_on_failsafe); new overrides clear it ("Radio Failsafe Cleared").

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot_bridge.control import ControlOutput, PositionTarget
from autopilot_bridge.ekf import NavState
from autopilot_bridge.flight_laws import Hold
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.rc_input import (
    ChannelCalibration,
    PilotSticks,
    RadioFailsafeAction,
    RcOverrides,
    climb_rate_m_s,
    lean_angles_rad,
    read_sticks,
    stabilize_throttle,
    yaw_rate_rad_s,
)
from autopilot_bridge.vehicle_interface import MavSeverity, MissionState, Outcome

# How far the pilot's held point may lead the vehicle horizontally (the loiter leash).
PILOT_LEASH_M = 5.0
RCMAP_PARAMS = ("RCMAP_ROLL", "RCMAP_PITCH", "RCMAP_THROTTLE", "RCMAP_YAW")
PILOT_MODES = frozenset({CopterMode.STABILIZE, CopterMode.ALT_HOLD, CopterMode.LOITER,
                         CopterMode.POSHOLD})
_TWO_PI = 2.0 * math.pi


class PilotMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_pilot(self) -> None:
        self.rc = RcOverrides()
        self._rc_seen_armed = False
        self._rc_failsafe = False
        self._pilot_point: np.ndarray | None = None
        self._pilot_heading: float | None = None

    # ------------------------------------------------------------------ Vehicle
    def rc_channels_override(self, channels: tuple[int, ...]) -> None:
        self.rc.rc_channels_override(channels, self._now_s)

    def manual_control(self, x: float, y: float, z: float, r: float) -> None:
        self.rc.manual_control(x, y, z, r, self._rcmap(), self._now_s)

    def rc_channels(self) -> tuple[int, ...]:
        """The channels as RC_CHANNELS reports them (0 = no input)."""
        return self.rc.channels if self._rc_active() else (0,) * len(self.rc.channels)

    # ------------------------------------------------------------------ sticks
    def _rcmap(self) -> tuple[int, int, int, int]:
        p = self.params
        roll, pitch, thr, yaw = (p.get_int(name) for name in RCMAP_PARAMS)
        return roll, pitch, thr, yaw

    def _calibration(self, channel: int) -> ChannelCalibration:
        p = self.params
        return ChannelCalibration(p.get(f"RC{channel}_MIN"), p.get(f"RC{channel}_TRIM"),
                                  p.get(f"RC{channel}_MAX"), p.get_int(f"RC{channel}_REVERSED") != 0,
                                  p.get(f"RC{channel}_DZ"))

    def _rc_active(self) -> bool:
        return self.rc.active(self._now_s, self.params.get("RC_OVERRIDE_TIME"))

    def _sticks(self) -> PilotSticks | None:
        if not self._rc_active() or self._rc_failsafe:
            return None
        return read_sticks(self.rc, self._rcmap(), self._calibration)

    def _pilot_climb_m_s(self, sticks: PilotSticks) -> float:
        p = self.params
        up = p.get("PILOT_SPEED_UP") / 100.0
        dn = (p.get("PILOT_SPEED_DN") or p.get("PILOT_SPEED_UP")) / 100.0
        return climb_rate_m_s(sticks, p.get("THR_DZ") / 1000.0, up, dn)

    def _pilot_control(self, est: NavState, gyro: np.ndarray, dt: float) -> ControlOutput | None:
        """The mode's output from the sticks, or None when there is no pilot input."""
        mode = self._mode
        if mode not in PILOT_MODES:
            self._pilot_point = None
            return None
        sticks = self._sticks()
        if sticks is None:
            if self._pilot_point is not None:
                # the pilot let go (overrides expired): hold where the sticks left the point
                self._law = Hold(self._pilot_point, self._pilot_heading)
                self._pilot_point = None
            return None
        fc = self.fc
        angle_max = math.radians(self.params.get("ANGLE_MAX") / 100.0)
        roll, pitch = lean_angles_rad(sticks, angle_max)
        yaw_rate = yaw_rate_rad_s(sticks, self.params.get("PILOT_Y_RATE"))
        if mode == CopterMode.STABILIZE:
            thrust = stabilize_throttle(sticks, self.airframe.hover_thrust_fraction)
            return fc.update_stabilize(est, gyro, roll, pitch, yaw_rate, thrust, dt)
        climb = self._pilot_climb_m_s(sticks)
        if mode == CopterMode.ALT_HOLD:
            climb = climb or self._alt_hold_takeoff_climb(est)
            return fc.update_alt_hold(est, gyro, roll, pitch, yaw_rate, climb, dt)
        return self._pilot_loiter(est, gyro, sticks, climb, yaw_rate, dt)

    def _pilot_loiter(self, est: NavState, gyro: np.ndarray, sticks: PilotSticks, climb: float,
                      yaw_rate: float, dt: float) -> ControlOutput:
        fc = self.fc
        pos = np.asarray(est.position_enu_m, dtype=float)
        if self._pilot_point is None:
            held = getattr(self._law, "position", None)
            self._pilot_point = np.array(held if held is not None and not fc.landed else pos, dtype=float)
            self._pilot_heading = float(est.heading_rad)
        if fc.landed and climb <= 0.0:
            self._pilot_point = pos.copy()
            self._pilot_heading = float(est.heading_rad)
            return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)   # ground idle
        speed = self.params.get("LOIT_SPEED") / 100.0
        heading = float(est.heading_rad)
        forward, right = -sticks.pitch * speed, sticks.roll * speed     # stick back = pitch up
        ve = forward * math.sin(heading) + right * math.cos(heading)
        vn = forward * math.cos(heading) - right * math.sin(heading)
        point = self._pilot_point + np.array([ve, vn, climb]) * dt
        lead = point[:2] - pos[:2]
        dist = float(np.hypot(lead[0], lead[1]))
        if dist > PILOT_LEASH_M:
            point[:2] = pos[:2] + lead * (PILOT_LEASH_M / dist)
        self._pilot_point = point
        assert self._pilot_heading is not None
        self._pilot_heading = (self._pilot_heading + yaw_rate * dt) % _TWO_PI
        target = PositionTarget(tuple(float(a) for a in point), (ve, vn, climb),
                                heading_rad=self._pilot_heading)
        self._last_target = target
        return fc.update_position(est, gyro, target, dt)

    # ------------------------------------------------------------------ radio failsafe
    def _radio_failsafe_check(self) -> None:
        active = self._rc_active()
        if not self._armed:
            self._rc_seen_armed = False
            self._rc_failsafe = False
            return
        if active:
            self._rc_seen_armed = True
            if self._rc_failsafe:
                self._rc_failsafe = False
                self._announce(MavSeverity.WARNING, "Radio Failsafe Cleared")
            return
        timeout = self.params.get("RC_OVERRIDE_TIME")
        if not self._rc_seen_armed or self._rc_failsafe or timeout <= 0.0:
            return
        try:
            action = RadioFailsafeAction(self.params.get_int("FS_THR_ENABLE"))
        except ValueError:
            action = RadioFailsafeAction.RTL
        if action == RadioFailsafeAction.DISABLED:
            return
        self._rc_failsafe = True
        self.stats["failsafe_radio"] += 1
        self._pilot_point = None
        if self.fc.landed:
            self._announce(MavSeverity.WARNING, "Radio Failsafe - Disarming")
            self._disarm("radio failsafe")
            return
        if action == RadioFailsafeAction.CONTINUE_MISSION and self._mode == CopterMode.AUTO \
                and self._mission_state == MissionState.ACTIVE:
            self._announce(MavSeverity.WARNING, "Radio Failsafe - Continuing Auto Mode")
            return
        self._announce(MavSeverity.WARNING, "Radio Failsafe")
        self._radio_failsafe_action(action)

    def _radio_failsafe_action(self, action: RadioFailsafeAction) -> None:
        def to(mode: CopterMode) -> Outcome:
            return self._enter_mode(mode, from_gcs=False)

        if action in (RadioFailsafeAction.SMARTRTL_OR_RTL, RadioFailsafeAction.SMARTRTL_OR_LAND):
            if to(CopterMode.SMART_RTL).ok:
                return
            land = action == RadioFailsafeAction.SMARTRTL_OR_LAND
            self._announce(MavSeverity.WARNING, "SmartRTL Unavailable, Using Land Mode" if land
                           else "SmartRTL Unavailable, Trying RTL Mode")
            if land:
                to(CopterMode.LAND)
                return
        if action == RadioFailsafeAction.AUTO_DO_LAND_START:
            self._land_start_or_rtl()
        elif action == RadioFailsafeAction.LAND:
            to(CopterMode.LAND)
        elif action == RadioFailsafeAction.BRAKE_OR_LAND:
            if not to(CopterMode.BRAKE).ok:
                to(CopterMode.LAND)
        elif not to(CopterMode.RTL).ok:
            to(CopterMode.LAND)
