"""Waypoint following and the takeoff / RTL / LAND helpers (pure), producing ``PositionTarget``s.

Waypoint following (AUTO / GUIDED-to-a-point): a target point (the "carrot") moves along the straight
segment from the previous waypoint to the next one, with a trapezoidal along-track speed profile:
it accelerates at WPNAV_ACCEL up to WPNAV_SPEED (a waypoint's own speed when given), and slows on the
braking curve v = sqrt(v_end^2 + 2 a d) so that it arrives at the final waypoint at rest (at an
intermediate waypoint it arrives at a corner speed that is zero for turns of 90 degrees or more and the
full speed for straight continuations). On 3-D segments the along-track speed and acceleration are
reduced so that the climb / descent components respect WPNAV_SPEED_UP / WPNAV_SPEED_DN and
WPNAV_ACCEL_Z. The target carries the carrot's velocity as a feed-forward, and the position controller's
P term supplies the cross-track (and along-track) correction. The carrot may lead the vehicle's
along-track position by at most ``wp_leash_m``; when the vehicle lags (headwind, saturation) the carrot
waits, so the controller never chases a runaway target.

Waypoint reached: an intermediate waypoint when the carrot reaches it (the vehicle then cuts the
corner within its acceptance radius); the final waypoint when the carrot has stopped on it and the
vehicle is within the acceptance radius (WPNAV_RADIUS by default). Each produces a
``GuidanceEvent(WAYPOINT_REACHED, index)``; the final one also ``MISSION_COMPLETE``. After completion
the target holds the final waypoint.

Heading (WP_YAW_BEHAVIOR): FACE_NEXT_WAYPOINT points the nose along each leg longer than
``min_yaw_leg_m`` horizontally; NEVER_CHANGE (and short or vertical legs) keep the current heading.

After an EKF horizontal position reset (``NavFilter.position_reset_count`` increments) the node calls
``handle_position_reset(delta_xy)``: the carrot moves with the estimate, so the vehicle is not jerked,
and the remaining track re-converges on the (world-fixed) waypoint.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import Enum
from typing import Sequence

import numpy as np

from autopilot_bridge.config import GuidanceConfig, YawBehaviour
from autopilot_bridge.control import PositionTarget, VerticalMode, stopping_point
from autopilot_bridge.ekf import NavState

logger = logging.getLogger(__name__)

_EPS = 1e-6


class GuidanceEventKind(Enum):
    WAYPOINT_REACHED = "waypoint_reached"
    MISSION_COMPLETE = "mission_complete"
    PHASE_CHANGED = "phase_changed"


@dataclass(frozen=True)
class GuidanceEvent:
    kind: GuidanceEventKind
    index: int = -1          # waypoint index for WAYPOINT_REACHED / MISSION_COMPLETE
    detail: str = ""         # e.g. the new RTL phase name


@dataclass(frozen=True)
class Waypoint:
    position_enu_m: tuple[float, float, float]
    acceptance_radius_m: float | None = None   # None: GuidanceConfig.wp_radius_m
    speed_m_s: float | None = None             # horizontal speed on the leg to this waypoint; None: wp_speed_m_s


class GuidanceLaw:
    """What every guidance law has: the events of its last updates (``pop_events``) and whether it
    is done (``complete``; False for laws that end only by a mode change or a touchdown)."""

    _events: list[GuidanceEvent]

    @property
    def complete(self) -> bool:
        return False

    def pop_events(self) -> list[GuidanceEvent]:
        events, self._events = self._events, []
        return events


class WaypointTracker(GuidanceLaw):
    """Follows a list of 3-D waypoints from ``start_enu_m``; ``update`` once per control tick."""

    def __init__(self, cfg: GuidanceConfig, waypoints: Sequence[Waypoint], start_enu_m, *,
                 climb_speed_m_s: float | None = None) -> None:
        if not waypoints:
            raise ValueError("WaypointTracker needs at least one waypoint")
        self._cfg = cfg
        self._wps = [Waypoint(tuple(float(a) for a in wp.position_enu_m), wp.acceptance_radius_m, wp.speed_m_s)
                     for wp in waypoints]
        self._climb_speed = climb_speed_m_s if climb_speed_m_s is not None else cfg.wp_speed_up_m_s
        self._index = 0
        self._origin = np.asarray(start_enu_m, dtype=float)[:3].copy()
        self._s = 0.0
        self._v = 0.0
        self._events: list[GuidanceEvent] = []
        self._complete = False
        self._heading: float | None = None
        self._setup_segment()

    # ------------------------------------------------------------------ public
    @property
    def complete(self) -> bool:
        return self._complete

    @property
    def current_index(self) -> int:
        """Index of the waypoint being flown to (the last one once complete)."""
        return self._index

    def leg(self) -> tuple[np.ndarray, np.ndarray]:
        """The current leg (start, waypoint) in ENU metres, copies (telemetry only)."""
        return self._origin.copy(), np.array(self._wps[self._index].position_enu_m, dtype=float)

    def handle_position_reset(self, delta_xy_m) -> None:
        """Shift the carrot with an EKF position reset (restarts the current leg from the shifted carrot)."""
        carrot = self._carrot()
        carrot[0] += float(delta_xy_m[0])
        carrot[1] += float(delta_xy_m[1])
        v = self._v
        self._origin = carrot
        self._s = 0.0
        self._setup_segment()
        self._v = min(v, self._v_max)

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        if self._complete:
            return self._target(np.array(self._wps[-1].position_enu_m), 0.0)
        p = np.asarray(nav.position_enu_m, dtype=float)
        last = self._index == len(self._wps) - 1
        remaining = self._length - self._s
        # Braking curve for steps of dt: stopping distance v^2 / 2a + v dt / 2 (the continuous curve
        # sqrt(2 a d) would leave a small velocity step on the last tick).
        half_adt = 0.5 * self._a_max * dt_s
        v_lim = -half_adt + math.sqrt(half_adt * half_adt + self._v_end * self._v_end
                                      + 2.0 * self._a_max * max(remaining, 0.0))
        v_des = min(self._v_max, v_lim)
        if self._v < v_des:
            self._v = min(v_des, self._v + self._a_max * dt_s)
        else:
            self._v = v_des
        s_new = self._s + self._v * dt_s
        s_vehicle = float(np.dot(p - self._origin, self._u)) if self._length > _EPS else 0.0
        s_leash = s_vehicle + self._cfg.wp_leash_m
        if s_new > s_leash:
            s_new = max(self._s, s_leash)
            self._v = min(self._v, (s_new - self._s) / dt_s)
        self._s = s_new
        if self._s >= self._length:
            wp_pos = np.array(self._wps[self._index].position_enu_m)
            if last:
                self._s = self._length
                self._v = 0.0
                radius = self._radius(self._index)
                if float(np.linalg.norm(p - wp_pos)) <= radius:
                    self._events.append(GuidanceEvent(GuidanceEventKind.WAYPOINT_REACHED, self._index))
                    self._events.append(GuidanceEvent(GuidanceEventKind.MISSION_COMPLETE, self._index))
                    self._complete = True
                    logger.info("WaypointTracker: final waypoint %d reached", self._index)
                return self._target(wp_pos, 0.0)
            # Intermediate waypoint: the carrot carries on along the next leg.
            excess = self._s - self._length
            self._events.append(GuidanceEvent(GuidanceEventKind.WAYPOINT_REACHED, self._index))
            logger.info("WaypointTracker: waypoint %d reached", self._index)
            v = self._v
            self._origin = wp_pos
            self._index += 1
            self._setup_segment()
            self._v = min(v, self._v_max)
            self._s = min(excess, self._length)
        # the carrot (origin + u s) and its velocity (u v), element by element as numpy would
        o, u, s, v = self._origin.tolist(), self._u.tolist(), self._s, self._v
        return PositionTarget(position_enu_m=(o[0] + u[0] * s, o[1] + u[1] * s, o[2] + u[2] * s),
                              velocity_enu_m_s=(u[0] * v, u[1] * v, u[2] * v),
                              heading_rad=self._heading, vertical_mode=VerticalMode.POSITION)

    # ------------------------------------------------------------------ internals
    def _radius(self, i: int) -> float:
        r = self._wps[i].acceptance_radius_m
        return float(r) if r is not None else self._cfg.wp_radius_m

    def _leg_limits(self, u: np.ndarray, speed_xy: float) -> tuple[float, float]:
        cfg = self._cfg
        h = math.hypot(float(u[0]), float(u[1]))
        uz = float(u[2])
        v_max = math.inf
        a_max = math.inf
        if h > _EPS:
            v_max = speed_xy / h
            a_max = cfg.wp_accel_m_s2 / h
        if abs(uz) > _EPS:
            vz_lim = self._climb_speed if uz > 0.0 else cfg.wp_speed_down_m_s
            v_max = min(v_max, vz_lim / abs(uz))
            a_max = min(a_max, cfg.wp_accel_z_m_s2 / abs(uz))
        if not math.isfinite(v_max):
            v_max, a_max = 0.0, cfg.wp_accel_m_s2
        return v_max, a_max

    def _setup_segment(self) -> None:
        cfg = self._cfg
        wp = self._wps[self._index]
        dest = np.array(wp.position_enu_m)
        d = dest - self._origin
        self._length = float(np.linalg.norm(d))
        if self._length <= _EPS:
            # a leg shorter than the tolerance is no leg: length 0, so the carrot is at its end at once
            # (a leg of 1e-7 m, left by rounding between a target and the next item, had no
            # direction to advance along and never ended: a NAV_LAND that hovered for ever)
            self._length = 0.0
        self._u = d / self._length if self._length > _EPS else np.zeros(3)
        speed = wp.speed_m_s if wp.speed_m_s is not None else cfg.wp_speed_m_s
        self._v_max, self._a_max = self._leg_limits(self._u, speed)
        self._v_end = 0.0
        if self._index + 1 < len(self._wps) and self._length > _EPS:
            nxt = self._wps[self._index + 1]
            d2 = np.array(nxt.position_enu_m) - dest
            n2 = float(np.linalg.norm(d2))
            if n2 > _EPS:
                u2 = d2 / n2
                v2_max, _ = self._leg_limits(u2, nxt.speed_m_s if nxt.speed_m_s is not None else cfg.wp_speed_m_s)
                cos_turn = float(np.dot(self._u, u2))
                self._v_end = min(self._v_max, v2_max) * max(0.0, cos_turn) ** 2
        horizontal = math.hypot(float(d[0]), float(d[1]))
        if cfg.yaw_behaviour == YawBehaviour.FACE_NEXT_WAYPOINT and horizontal >= cfg.min_yaw_leg_m:
            self._heading = math.atan2(float(d[0]), float(d[1])) % (2.0 * math.pi)

    def _carrot(self) -> np.ndarray:
        return self._origin + self._u * self._s

    def _target(self, position: np.ndarray, speed: float) -> PositionTarget:
        vel = self._u * speed
        return PositionTarget(position_enu_m=(float(position[0]), float(position[1]), float(position[2])),
                              velocity_enu_m_s=(float(vel[0]), float(vel[1]), float(vel[2])),
                              heading_rad=self._heading, vertical_mode=VerticalMode.POSITION)


def make_takeoff(cfg: GuidanceConfig, start_enu_m, climb_m: float) -> WaypointTracker:
    """Vertical takeoff to ``climb_m`` above ``start_enu_m`` at ``takeoff_speed_m_s``; heading unchanged."""
    start = np.asarray(start_enu_m, dtype=float)[:3]
    goal = (float(start[0]), float(start[1]), float(start[2]) + float(climb_m))
    return WaypointTracker(cfg, [Waypoint(goal, acceptance_radius_m=cfg.takeoff_radius_m)], start,
                           climb_speed_m_s=cfg.takeoff_speed_m_s)


class Lander(GuidanceLaw):
    """LAND: hold x, y and descend at WPNAV_SPEED_DN (or LAND_SPEED_HIGH) down to LAND_ALT_LOW above the
    ground reference, then at LAND_SPEED. Touchdown is detected by the controller (``ControlOutput.touchdown``)."""

    def __init__(self, cfg: GuidanceConfig, position_enu_m, ground_z_m: float, heading_rad: float | None = None) -> None:
        self._cfg = cfg
        p = np.asarray(position_enu_m, dtype=float)
        self._xy = (float(p[0]), float(p[1]))
        self._ground_z = float(ground_z_m)
        self._heading = heading_rad
        self._vz = 0.0
        self._events: list[GuidanceEvent] = []

    def handle_position_reset(self, delta_xy_m) -> None:
        self._xy = (self._xy[0] + float(delta_xy_m[0]), self._xy[1] + float(delta_xy_m[1]))

    def descent_speed_m_s(self, height_m: float) -> float:
        cfg = self._cfg
        if height_m > cfg.land_alt_low_m:
            return cfg.land_speed_high_m_s if cfg.land_speed_high_m_s > 0.0 else cfg.wp_speed_down_m_s
        return cfg.land_speed_m_s

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        z = float(nav.position_enu_m[2])
        want = -self.descent_speed_m_s(z - self._ground_z)
        step = self._cfg.wp_accel_z_m_s2 * dt_s
        self._vz += min(max(want - self._vz, -step), step)
        return PositionTarget(position_enu_m=(self._xy[0], self._xy[1], z), velocity_enu_m_s=(0.0, 0.0, self._vz),
                              heading_rad=self._heading, vertical_mode=VerticalMode.VELOCITY)


# ArduCopter mode_rtl.cpp: RTL_ALT_MIN_M, the lowest return height; RTL_MIN_CONE_SLOPE, below which
# the cone is off.
RTL_ALT_MIN_M = 2.0
RTL_MIN_CONE_SLOPE = 0.5


def rtl_return_height_m(cfg: GuidanceConfig, height_m: float, distance_home_m: float) -> float:
    """RTL's return height above home, as ArduCopter's ``ModeRTL::compute_return_target``: at
    least RTL_ALT and the current height + RTL_CLIMB_MIN (and 2 m), but within the cone
    RTL_CONE_SLOPE x the horizontal distance home (never below the climb minimum)."""
    min_height = max(RTL_ALT_MIN_M, height_m + max(0.0, cfg.rtl_climb_min_m))
    target = max(cfg.rtl_alt_m, min_height)
    if cfg.rtl_cone_slope >= RTL_MIN_CONE_SLOPE:
        target = min(target, max(distance_home_m * cfg.rtl_cone_slope, min_height))
    return max(target, height_m)


class RtlPhase(Enum):
    CLIMB = "climb"
    RETURN = "return"
    LOITER = "loiter"
    LAND = "land"


class ReturnToLaunch(GuidanceLaw):
    """RTL: climb to the return height (``rtl_return_height_m``) where it is, fly home at that height, loiter
    RTL_LOIT_TIME, then LAND on home (descent speeds as ``Lander``)."""

    def __init__(self, cfg: GuidanceConfig, home_enu_m, nav: NavState) -> None:
        self._cfg = cfg
        self._home = np.asarray(home_enu_m, dtype=float)[:3].copy()
        start = stopping_point(nav.position_enu_m, nav.velocity_enu_m_s, cfg.wp_accel_m_s2)
        self._rtl_z = float(self._home[2]) + rtl_return_height_m(
            cfg, float(start[2]) - float(self._home[2]),
            float(np.hypot(*(start[:2] - self._home[:2]))))
        self._phase = RtlPhase.CLIMB
        self._events: list[GuidanceEvent] = []
        self._tracker: WaypointTracker | Lander = WaypointTracker(
            cfg, [Waypoint((float(start[0]), float(start[1]), self._rtl_z), acceptance_radius_m=1.0)], start)
        self._loiter_s = 0.0
        self._hold_target: PositionTarget | None = None

    @property
    def phase(self) -> RtlPhase:
        return self._phase

    def handle_position_reset(self, delta_xy_m) -> None:
        self._tracker.handle_position_reset(delta_xy_m)

    def _enter(self, phase: RtlPhase) -> None:
        logger.info("RTL: %s -> %s", self._phase.value, phase.value)
        self._phase = phase
        self._events.append(GuidanceEvent(GuidanceEventKind.PHASE_CHANGED, detail=phase.value))

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        cfg = self._cfg
        target = self._tracker.update(nav, dt_s)
        if self._phase == RtlPhase.CLIMB and self._tracker.complete:
            start = np.array(target.position_enu_m)
            home_at_alt = (float(self._home[0]), float(self._home[1]), self._rtl_z)
            self._tracker = WaypointTracker(cfg, [Waypoint(home_at_alt)], start)
            self._enter(RtlPhase.RETURN)
        elif self._phase == RtlPhase.RETURN and self._tracker.complete:
            self._loiter_s = 0.0
            self._enter(RtlPhase.LOITER)
        elif self._phase == RtlPhase.LOITER:
            self._loiter_s += dt_s
            if self._loiter_s >= cfg.rtl_loiter_s:
                self._tracker = Lander(cfg, self._home, float(self._home[2]), heading_rad=target.heading_rad)
                self._enter(RtlPhase.LAND)
        return target
