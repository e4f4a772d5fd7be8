"""GUIDED mode (part of ``FlightCore``): take-off, DO_REPOSITION, SET_POSITION_TARGET_LOCAL_NED /
_GLOBAL_INT setpoints (position, position+velocity, velocity, acceleration; yaw and yaw rate), and
the control of velocity / acceleration setpoints with GUID_TIMEOUT.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot_bridge.control import ControlOutput, PositionTarget
from autopilot_bridge.ekf import NavState
from autopilot_bridge.flight_laws import LawKind, Tracker
from autopilot_bridge.geo_frame import ned_to_enu
from autopilot_bridge.guidance_law import Waypoint, make_takeoff
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    GlobalPositionTarget,
    LocalPositionTarget,
    MavFrame,
    MavSeverity,
    Outcome,
    SetpointKind,
    SpeedType,
)
from scenenav.core.numeric import all_finite

_TWO_PI = 2.0 * math.pi


SAME_TARGET_M = 0.01


MAX_VELOCITY_TARGET_M_S = 30.0

# Modes that take off on NAV_TAKEOFF (ArduCopter's has_user_takeoff; ALT_HOLD only with param3 != 0).
TAKEOFF_MODES = frozenset({CopterMode.GUIDED, CopterMode.LOITER, CopterMode.POSHOLD})
# ALT_HOLD's takeoff ends this close to the target height (the takeoff tolerance of AUTO).
ALT_HOLD_TAKEOFF_DONE_M = 0.5


@dataclass
class GuidedCommand:
    """A GUIDED velocity / position+velocity / acceleration setpoint and when it arrived."""

    kind: SetpointKind
    position_enu_m: np.ndarray | None
    velocity_enu_m_s: np.ndarray | None
    accel_enu_m_s2: np.ndarray | None
    t_s: float


class GuidedMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_guided(self) -> None:
        """The GUIDED setpoint and yaw target."""
        self._guided: GuidedCommand | None = None
        self._guided_heading: float | None = None
        self._guided_yaw_rate: float | None = None
        self._guided_yaw_until_s = 0.0
        self._alt_hold_takeoff_z: float | None = None

    def takeoff(self, alt_m: float, must_navigate: bool = True) -> Outcome:
        # ArduCopter Mode::has_user_takeoff: GUIDED, LOITER, POSHOLD; ALT_HOLD only when the pilot
        # navigates (NAV_TAKEOFF param3 != 0)
        if self._mode not in TAKEOFF_MODES and not (self._mode == CopterMode.ALT_HOLD
                                                    and not must_navigate):
            return self._refuse(f"Takeoff: not supported in {self._mode.name}")
        if not self._armed:
            return self._refuse("Takeoff: motors not armed")
        if not self.fc.landed:
            return self._refuse("Takeoff: already flying")
        if not (math.isfinite(alt_m) and alt_m > 0):
            return self._refuse("Takeoff: bad altitude")
        est = self.nav.state()
        start = np.array(est.position_enu_m, dtype=float)
        climb = max(self._home_z() + float(alt_m) - float(start[2]), 1.0)
        if self._mode == CopterMode.ALT_HOLD:
            self._alt_hold_takeoff_z = float(start[2]) + climb
            self._landed_since_s = None
            self._bus_text(MavSeverity.INFO, f"takeoff to {alt_m:.1f} m")
            return Outcome(True)
        law = make_takeoff(self._gcfg, start, climb)
        law.kind = LawKind.TAKEOFF
        self._law = law
        self._guided = None
        self._landed_since_s = None
        self._tel = None
        self._bus_text(MavSeverity.INFO, f"takeoff to {alt_m:.1f} m")
        return Outcome(True)

    def reposition(self, lat_deg: float, lon_deg: float, alt_m: float, alt_frame: AltFrame,
                   speed_m_s: float | None, yaw_deg: float | None) -> Outcome:
        if self._mode != CopterMode.GUIDED:
            return self._refuse("Reposition: mode must be GUIDED")
        if not self._position_ok():
            return self._refuse("Reposition: no position estimate")
        x, y = self.geo.to_enu(lat_deg, lon_deg)
        z = self._alt_to_z(alt_m, alt_frame)
        if yaw_deg is not None:
            self._guided_heading = math.radians(yaw_deg) % _TWO_PI
            self._guided_yaw_rate = None
        self._guided_goto((x, y, z), speed_m_s)
        return Outcome(True)

    def change_speed(self, speed_type: SpeedType, speed_m_s: float) -> Outcome:
        if not (math.isfinite(speed_m_s) and speed_m_s > 0):
            return self._refuse("Change speed: bad speed")
        kind = SpeedType(speed_type)
        self._apply_speed(kind, self._speed_limit(kind, float(speed_m_s)))
        return Outcome(True)

    def set_position_target_local_ned(self, target: LocalPositionTarget) -> None:
        if not self.nav.aligned:
            return
        est = self.nav.state()
        heading = float(est.heading_rad)
        body = target.frame in (MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED)

        def rotate(v) -> np.ndarray:
            n, e = float(v[0]), float(v[1])
            if body:
                n, e = n * math.cos(heading) - e * math.sin(heading), \
                    n * math.sin(heading) + e * math.cos(heading)
            return ned_to_enu((n, e, float(v[2])))

        pos = vel = acc = None
        if target.kind in (SetpointKind.POSITION, SetpointKind.POSITION_VELOCITY):
            if target.frame == MavFrame.LOCAL_NED:
                pos = self._origin_enu() + ned_to_enu(target.position_m)
            else:
                pos = np.array(est.position_enu_m, dtype=float) + rotate(target.position_m)
        if target.kind in (SetpointKind.POSITION_VELOCITY, SetpointKind.VELOCITY) or \
                (target.kind == SetpointKind.ACCELERATION and all_finite(*target.velocity_m_s)):
            if all_finite(*target.velocity_m_s):
                vel = rotate(target.velocity_m_s)
        if all_finite(*target.acceleration_m_s2):
            acc = rotate(target.acceleration_m_s2)
        yaw = target.yaw_rad
        if yaw is not None and body:
            yaw = heading + yaw
        self._guided_setpoint(target.kind, pos, vel, acc, yaw, target.yaw_rate_rad_s)

    def set_position_target_global_int(self, target: GlobalPositionTarget) -> None:
        if not self.nav.aligned:
            return
        pos = vel = acc = None
        if target.kind in (SetpointKind.POSITION, SetpointKind.POSITION_VELOCITY):
            x, y = self.geo.to_enu(target.lat_deg, target.lon_deg)
            pos = np.array([x, y, self._alt_to_z(target.alt_m, target.alt_frame)])
        if all_finite(*target.velocity_m_s):
            vel = ned_to_enu(target.velocity_m_s)
        if all_finite(*target.acceleration_m_s2):
            acc = ned_to_enu(target.acceleration_m_s2)
        self._guided_setpoint(target.kind, pos, vel, acc, target.yaw_rad, target.yaw_rate_rad_s)

    def _guided_heading_now(self, dt: float) -> float | None:
        if self._guided_yaw_rate is not None and self._guided_heading is not None:
            if self._now_s <= self._guided_yaw_until_s:
                self._guided_heading = (self._guided_heading + self._guided_yaw_rate * dt) % _TWO_PI
        return self._guided_heading

    def _guided_control(self, est: NavState, gyro: np.ndarray, dt: float) -> ControlOutput:
        g = self._guided
        assert g is not None
        timeout = self.params.get("GUID_TIMEOUT")
        fresh = self._now_s - g.t_s <= timeout
        heading = self._guided_heading_now(dt)
        fc = self.fc
        if g.kind == SetpointKind.POSITION_VELOCITY and g.position_enu_m is not None:
            vel = g.velocity_enu_m_s if g.velocity_enu_m_s is not None else np.zeros(3)
            moved = min(self._now_s - g.t_s, timeout)
            pos = g.position_enu_m + vel * moved
            if fc.landed and pos[2] - float(est.position_enu_m[2]) < 0.5:
                return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)
            target = PositionTarget(tuple(float(a) for a in pos),
                                    tuple(float(a) for a in (vel if fresh else np.zeros(3))),
                                    heading_rad=heading)
            self._last_target = target
            return fc.update_position(est, gyro, target, dt)
        if g.kind == SetpointKind.ACCELERATION and g.accel_enu_m_s2 is not None:
            if g.velocity_enu_m_s is None:
                g.velocity_enu_m_s = np.array(est.velocity_enu_m_s, dtype=float)
            if fresh:
                g.velocity_enu_m_s = np.clip(g.velocity_enu_m_s + g.accel_enu_m_s2 * dt,
                                             -MAX_VELOCITY_TARGET_M_S, MAX_VELOCITY_TARGET_M_S)
            else:
                g.velocity_enu_m_s = np.zeros(3)
        vel = g.velocity_enu_m_s if (g.velocity_enu_m_s is not None and fresh) else np.zeros(3)
        accel = g.accel_enu_m_s2 if (g.accel_enu_m_s2 is not None and fresh) else np.zeros(3)
        if fc.landed and float(vel[2]) <= fc.config.takeoff_min_climb_m_s:
            return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)
        return fc.update_velocity(est, gyro, vel, dt, heading_rad=heading,
                                  accel_enu_m_s2=tuple(float(a) for a in accel))

    def _alt_hold_takeoff_climb(self, est: NavState) -> float:
        """ALT_HOLD's takeoff: climb at the takeoff speed to the target height, then hold it."""
        if self._alt_hold_takeoff_z is None:
            return 0.0
        left = self._alt_hold_takeoff_z - float(est.position_enu_m[2])
        if left <= ALT_HOLD_TAKEOFF_DONE_M:
            self._alt_hold_takeoff_z = None
            return 0.0
        return min(self._gcfg.takeoff_speed_m_s, left)

    def _alt_to_z(self, alt_m: float, alt_frame: AltFrame) -> float:
        if alt_frame == AltFrame.AMSL:
            return float(alt_m) - self.geo.origin_alt_amsl_m
        return self._home_z() + float(alt_m)

    def _origin_enu(self) -> np.ndarray:
        return self._origin.copy() if self._origin is not None else np.zeros(3)

    def _guided_setpoint(self, kind: SetpointKind, pos, vel, acc, yaw, yaw_rate) -> None:
        self._tel = None
        if yaw is not None and math.isfinite(yaw):
            self._guided_heading = float(yaw) % _TWO_PI
            self._guided_yaw_rate = None
        elif yaw_rate is not None and math.isfinite(yaw_rate):
            if self._guided_heading is None:
                self._guided_heading = float(self.nav.state().heading_rad)
            self._guided_yaw_rate = float(yaw_rate)
            self._guided_yaw_until_s = self._now_s + self.params.get("GUID_TIMEOUT")
        if kind == SetpointKind.POSITION and pos is not None:
            self._guided = None
            self._guided_goto(tuple(float(a) for a in pos), None)
            return
        if kind in (SetpointKind.POSITION_VELOCITY, SetpointKind.VELOCITY,
                    SetpointKind.ACCELERATION):
            if vel is not None:
                vel = np.clip(vel, -MAX_VELOCITY_TARGET_M_S, MAX_VELOCITY_TARGET_M_S)
            keep_vel = (kind == SetpointKind.ACCELERATION and vel is None
                        and self._guided is not None and self._guided.velocity_enu_m_s is not None)
            if keep_vel:
                vel = self._guided.velocity_enu_m_s
            self._guided = GuidedCommand(kind, pos, vel, acc, self._now_s)
            self.stats[f"guided_{kind.name.lower()}"] += 1

    def _guided_goto(self, dest: tuple[float, float, float], speed_m_s: float | None) -> None:
        est = self.nav.state()
        self._guided = None
        wp = Waypoint(dest, speed_m_s=speed_m_s if speed_m_s is not None else self._speed_xy)
        law = self._law
        if isinstance(law, Tracker) and law.kind == LawKind.TRACK and not self.fc.landed:
            if float(np.linalg.norm(law.destination - np.array(dest))) < SAME_TARGET_M \
                    and not law.complete:
                return
            law.redirect([wp])
        elif self._law_kind() == LawKind.TAKEOFF and self.fc.landed:
            return
        else:
            start = self._last_target_position(est) if not self.fc.landed else est.position_enu_m
            self._law = Tracker(self._gcfg, [wp], start)
        self.stats["guided_position"] += 1
