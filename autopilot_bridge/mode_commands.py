"""Ground-station commands that steer the current mode (part of ``FlightCore``): CONDITION_YAW,
DO_SET_ROI / DO_SET_ROI_LOCATION / DO_SET_ROI_NONE and DO_PAUSE_CONTINUE, as ArduCopter handles
them (``GCS_MAVLINK_Copter::handle_MAV_CMD_CONDITION_YAW``, ``handle_command_do_set_roi``,
``handle_command_pause_continue``).

* CONDITION_YAW sets a fixed heading (absolute, or relative to the current heading target with
  param3 -1 counter-clockwise) in the modes that fly ArduCopter's auto-yaw: AUTO and GUIDED
  (elsewhere accepted without effect, as there). Differs: the turn rate (param2) and, for an
  absolute heading, the direction are not used: the controller turns the shorter way at its own
  yaw rate.
* An ROI turns the nose towards the location in AUTO and GUIDED until it is cleared (zero location,
  DO_SET_ROI_NONE, CONDITION_YAW or a mode change).
* DO_PAUSE_CONTINUE: param1 0 pauses (stops at the stopping point and holds) in AUTO while flying
  waypoints and in GUIDED; 1 continues the paused mission item or GUIDED destination. Elsewhere
  "Failed to pause" / "Failed to resume" (FAILED), as ArduCopter.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import numpy as np

from autopilot_bridge.auto_mission import AutoStage
from autopilot_bridge.control import stopping_point
from autopilot_bridge.flight_laws import Hold
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import AltFrame, MavSeverity, MissionState, Outcome

# Where ArduCopter's Mode::pause() works: AUTO flying to a waypoint (SubMode::WP), GUIDED.
PAUSABLE_AUTO_STAGES = frozenset({AutoStage.WAYPOINTS})


class ModeCommandsMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_mode_commands(self) -> None:
        self._pause_hold: Hold | None = None

    def condition_yaw(self, angle_deg: float, rate_deg_s: float, direction: int,
                      relative: bool) -> Outcome:
        if not self.nav.aligned:
            return Outcome(True)
        est = self.nav.state()
        if self._mode == CopterMode.GUIDED:
            self._set_fixed_heading(angle_deg, float(direction), relative, est)
            self._guided_heading = self._auto_heading
            self._guided_yaw_rate = None
        elif self._mode == CopterMode.AUTO:
            self._set_fixed_heading(angle_deg, float(direction), relative, est)
        return Outcome(True)

    def set_roi(self, lat_deg: float, lon_deg: float, alt_m: float, alt_frame: AltFrame) -> Outcome:
        """Face (lat, lon) in AUTO and GUIDED; lat = lon = 0 clears the ROI."""
        if lat_deg == 0.0 and lon_deg == 0.0:
            self._roi_enu = None
            return Outcome(True)
        x, y = self.geo.to_enu(lat_deg, lon_deg)
        self._roi_enu = np.array([x, y, self._alt_to_z(alt_m, alt_frame)])
        self._auto_heading = None
        return Outcome(True)

    def pause_continue(self, pause: bool) -> Outcome:
        if pause:
            can = self._armed and not self.fc.landed and self.nav.aligned and (
                self._mode == CopterMode.GUIDED or (
                    self._mode == CopterMode.AUTO and self._mission_state == MissionState.ACTIVE
                    and self._auto_stage in PAUSABLE_AUTO_STAGES))
            if not can:
                self._texts.append((MavSeverity.INFO, "Failed to pause"))
                return Outcome(False, "Failed to pause")
            if self._pause_hold is None:
                est = self.nav.state()
                stop = stopping_point(est.position_enu_m, est.velocity_enu_m_s, self._gcfg.wp_accel_m_s2)
                self._pause_hold = Hold(stop, float(est.heading_rad))
            return Outcome(True)
        if self._pause_hold is None or not self.nav.aligned:
            self._texts.append((MavSeverity.INFO, "Failed to resume"))
            return Outcome(False, "Failed to resume")
        self._pause_hold = None
        self._restart_mode_law(self.nav.state())
        return Outcome(True)
