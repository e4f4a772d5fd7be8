"""Cascaded multirotor flight control in the ArduCopter style (pure: numpy + math only).

Cascade (each stage's output is the next stage's target; all on the navigation filter's estimates):

    position (P, sqrt-limited)          -> velocity target   (+ feed-forward, max speed, climb/descent rates)
    velocity (PID, anti-windup)         -> acceleration target (+ feed-forward, accel limit)
    acceleration -> thrust vector       -> attitude target (lean-limited, heading) + collective thrust
    attitude (P on the quaternion error, tilt before yaw) -> body-rate target (rate limits)
    body rate (PID, D on measurement)   -> angular acceleration -> torque = I alpha + w x I w

Frames: world ENU, body FLU, q_wxyz body -> world, heading compass (clockwise from north).

The sqrt controller used by the position loops is linear (gain p) for small errors and, beyond
e_lin = a_max / p^2, follows the braking curve v = sqrt(2 a_max (|e| - e_lin / 2)), so the commanded
velocity can always be stopped within the acceleration limit (continuous in value and slope).

Collective thrust is altitude-priority: T = m (g + a_z) / cos(current tilt) (the boost capped at
``max_tilt_compensation_deg``), bounded by ``thrust_min_fraction`` / ``thrust_max_fraction`` of the
vehicle's maximum thrust. The horizontal acceleration target is limited so the thrust vector stays within
``max_lean_angle_deg`` of vertical.

Attitude error: the tilt error is the shortest rotation taking the current body z onto the target body z;
the yaw error is what remains about body z. Roll/pitch rates come from the tilt error (gain ang_rp_p),
the yaw rate from the yaw error (gain ang_yaw_p, limited to max_rate_yaw), so a large heading change never
disturbs the thrust direction.

Anti-windup: integrators are clamped to their IMAX, frozen while the stage's output is limited in the
direction of the error (lean/accel limit for velocity xy, thrust limits for velocity z, the mixer's
roll/pitch and yaw limits for the rate loop; the mixer flags come in through ``set_mixer_limits``), and
cleared while landed.

Landed state: the controller starts landed. While landed with no climb demand it outputs zero thrust and
torque and holds its integrators at zero; a climb target above ``takeoff_min_climb_m_s`` (or, in
STABILIZE, a thrust demand above hover) leaves the landed state. In flight, the land detector declares a
touchdown when the thrust demand stays below ``land_detect_thrust_fraction`` of hover with low vertical and
horizontal speed and no climb demand for ``land_detect_time_s``; ``ControlOutput.touchdown`` is then true
for that one tick (the node disarms in LAND/RTL).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from autopilot_bridge.airframe import Airframe
from autopilot_bridge.config import ControlConfig
from autopilot_bridge.ekf import NavState
from autopilot_bridge.mixer import MixerLimits
from scenenav.core.frames import wrap_pi
from scenenav.core.rotations import (
    heading_from_quat,
    quat_conjugate,
    quat_from_aviation_euler,
    quat_from_euler_zyx,
    quat_from_rotation_vector,
    quat_multiply,
    quat_normalise,
    quat_rotate,
)

logger = logging.getLogger(__name__)

_TWO_PI = 2.0 * math.pi
ALT_HOLD_LEASH_M = 2.0              # ALT_HOLD altitude target stays within this of the current altitude
PILOT_HEADING_LEASH_RAD = math.radians(30.0)   # pilot heading target stays within this of the heading
MIN_VERTICAL_SPECIFIC_FORCE_G = 0.2  # the thrust vector keeps at least this much upward specific force
TRACK_PRIORITY_MIN_SPEED_M_S = 0.5   # below this velocity target the accel limit scales uniformly


class VerticalMode(Enum):
    """How a PositionTarget's vertical axis is controlled."""

    POSITION = "position"   # track position_enu_m[2] with velocity_enu_m_s[2] as feed-forward
    VELOCITY = "velocity"   # follow velocity_enu_m_s[2] only (climb/descent rate), e.g. landing


class LandState(Enum):
    LANDED = "landed"
    AIRBORNE = "airborne"


@dataclass(frozen=True)
class PositionTarget:
    """Target for ``FlightController.update_position`` (position hold, GUIDED, AUTO, RTL, LAND)."""

    position_enu_m: tuple[float, float, float]
    velocity_enu_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)   # feed-forward
    accel_enu_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)     # feed-forward
    heading_rad: float | None = None     # compass; None keeps the current heading target
    vertical_mode: VerticalMode = VerticalMode.POSITION


@dataclass(frozen=True)
class ControlOutput:
    """Demands for the mixer plus the intermediate targets (for logging and the node)."""

    thrust_n: float                      # collective, along body +z
    torque_flu_n_m: np.ndarray           # (3,)
    q_target_wxyz: np.ndarray            # (4,)
    rate_target_flu_rad_s: np.ndarray    # (3,)
    accel_target_enu_m_s2: np.ndarray    # (3,) (zeros in STABILIZE / attitude modes)
    velocity_target_enu_m_s: np.ndarray  # (3,) (zeros where not used)
    heading_target_rad: float
    lean_limited: bool
    land_state: LandState
    touchdown: bool                      # the land detector fired on this tick: disarm in LAND / RTL


def _floats(x) -> list[float]:
    """The entries of a vector as Python floats (``tolist`` for an ndarray: one call)."""
    return x.tolist() if type(x) is np.ndarray else [float(a) for a in x]


def sqrt_controller(error: float, p_gain: float, accel_max: float) -> float:
    """Velocity for a position error: p * e near zero, a braking-distance curve beyond a_max / p^2."""
    if accel_max <= 0.0 or p_gain <= 0.0:
        return p_gain * error
    linear = accel_max / (p_gain * p_gain)
    mag = abs(error)
    if mag <= linear:
        return p_gain * error
    return math.copysign(math.sqrt(2.0 * accel_max * (mag - 0.5 * linear)), error)


def stopping_point(position_enu_m, velocity_enu_m_s, accel_m_s2: float) -> np.ndarray:
    """Where the vehicle stops when braking horizontally at ``accel_m_s2`` (z unchanged): for mode changes."""
    p = np.asarray(position_enu_m, dtype=float).copy()
    v = np.asarray(velocity_enu_m_s, dtype=float)
    speed = math.hypot(float(v[0]), float(v[1]))
    if speed > 1e-6 and accel_m_s2 > 0.0:
        dist = speed * speed / (2.0 * accel_m_s2)
        p[0] += float(v[0]) / speed * dist
        p[1] += float(v[1]) / speed * dist
    return p


def limit_accel_xy(ax: float, ay: float, vx_target: float, vy_target: float,
                   accel_max: float) -> tuple[float, float]:
    """Horizontal acceleration cut to ``accel_max`` with cross-track priority.

    The component across the velocity target is kept (up to ``accel_max``) and the along-track one
    gives way, so a vehicle at its lean limit slows down instead of drifting off the track (a
    uniform cut scales the crosswind-holding part down with the rest). ArduPilot does the same
    (``AC_PosControl::limit_accel_corner_xy``). Below ``TRACK_PRIORITY_MIN_SPEED_M_S`` of velocity
    target there is no track: uniform cut.
    """
    a = math.hypot(ax, ay)
    if a <= accel_max:
        return ax, ay
    speed = math.hypot(vx_target, vy_target)
    if speed < TRACK_PRIORITY_MIN_SPEED_M_S:
        k = accel_max / a
        return ax * k, ay * k
    ux, uy = vx_target / speed, vy_target / speed
    along = ax * ux + ay * uy
    cross = -ax * uy + ay * ux
    if abs(cross) >= accel_max:
        cross, along = math.copysign(accel_max, cross), 0.0
    else:
        along = math.copysign(min(abs(along), math.sqrt(accel_max * accel_max - cross * cross)), along)
    return along * ux - cross * uy, along * uy + cross * ux


def _lpf_alpha(cutoff_hz: float, dt_s: float) -> float:
    rc = 1.0 / (_TWO_PI * cutoff_hz)
    return dt_s / (dt_s + rc)


class FlightController:
    """ArduCopter-style cascaded controller. One instance per vehicle; call one ``update_*`` per tick."""

    def __init__(self, cfg: ControlConfig | None = None, airframe: Airframe | None = None) -> None:
        self._cfg = cfg if cfg is not None else ControlConfig()
        c = self._cfg
        # rate loop gains per body axis (roll, pitch, yaw): kp, ki, kd, imax
        rp = (c.rate_rp_p_1_s, c.rate_rp_i_1_s2, c.rate_rp_d_unitless, c.rate_rp_imax_rad_s2)
        self._rate_gains = (rp, rp, (c.rate_yaw_p_1_s, c.rate_yaw_i_1_s2, 0.0, c.rate_yaw_imax_rad_s2))
        self._airframe = airframe if airframe is not None else Airframe()
        c, v = self._cfg, self._airframe
        self._mass = v.thrust_mass_kg
        self._g = v.gravity_m_s2
        self._inertia = tuple(float(i) for i in v.inertia_kg_m2)
        self._hover_thrust = self._mass * v.gravity_m_s2
        self._thrust_max = c.thrust_max_fraction * v.max_thrust_n
        self._thrust_min = c.thrust_min_fraction * v.max_thrust_n
        self._tan_lean = math.tan(c.max_lean_angle_rad)
        self._min_cos_tilt = math.cos(math.radians(c.max_tilt_compensation_deg))
        self._rate_rp_max = math.radians(c.max_rate_rp_deg_s)
        self._rate_yaw_max = math.radians(c.max_rate_yaw_deg_s)
        self._limits = MixerLimits()
        self._landed = True
        self._land_timer_s = 0.0
        self._heading_target = 0.0
        self._z_target = 0.0
        self._reset_integrators()

    # ------------------------------------------------------------------ state management
    @property
    def config(self) -> ControlConfig:
        return self._cfg

    @property
    def hover_thrust_n(self) -> float:
        return self._hover_thrust

    @property
    def landed(self) -> bool:
        return self._landed

    @property
    def heading_target_rad(self) -> float:
        return self._heading_target

    def _reset_integrators(self) -> None:
        self._vel_xy_i = [0.0, 0.0]
        self._vel_z_i = 0.0
        self._vel_xy_d = [0.0, 0.0]
        self._prev_vel_xy: tuple[float, float] | None = None
        self._rate_i = [0.0, 0.0, 0.0]
        self._rate_d = [0.0, 0.0, 0.0]
        self._prev_rate: tuple[float, float, float] | None = None
        self._lean_limited_xy = False
        self._limited_track_u: tuple[float, float] | None = None   # track direction of a priority cut
        self._thrust_at_max = False
        self._thrust_at_min = False

    def reset(self, nav: NavState, landed: bool = True) -> None:
        """Clear integrators and filters, take the heading/altitude targets from ``nav`` (arming, mode change)."""
        self._reset_integrators()
        self._heading_target = float(nav.heading_rad)
        self._z_target = float(nav.position_enu_m[2])
        self._landed = bool(landed)
        self._land_timer_s = 0.0
        self._limits = MixerLimits()

    def set_landed(self, landed: bool) -> None:
        """Force the landed state (e.g. the node knows the vehicle is on the ground at arming)."""
        if landed and not self._landed:
            self._reset_integrators()
        self._landed = bool(landed)
        self._land_timer_s = 0.0

    def set_mixer_limits(self, limits: MixerLimits) -> None:
        """Feed back the mixer's saturation flags of the last output (anti-windup)."""
        self._limits = limits

    # ------------------------------------------------------------------ modes
    def update_position(self, nav: NavState, gyro_flu_rad_s, target: PositionTarget, dt_s: float) -> ControlOutput:
        """Position hold / waypoint tracking (LOITER, GUIDED position, AUTO, RTL, LAND)."""
        c = self._cfg
        p = nav.position_enu_m
        ff = target.velocity_enu_m_s
        ex = float(target.position_enu_m[0]) - float(p[0])
        ey = float(target.position_enu_m[1]) - float(p[1])
        dist = math.hypot(ex, ey)
        vx, vy = float(ff[0]), float(ff[1])
        if dist > 1e-9:
            corr = sqrt_controller(dist, c.pos_xy_p_1_s, c.max_accel_xy_m_s2)
            corr = min(corr, c.max_speed_xy_m_s)
            vx += corr * ex / dist
            vy += corr * ey / dist
        if target.vertical_mode == VerticalMode.POSITION:
            ez = float(target.position_enu_m[2]) - float(p[2])
            vz = float(ff[2]) + sqrt_controller(ez, c.pos_z_p_1_s, c.max_accel_z_m_s2)
            self._z_target = float(target.position_enu_m[2])
        else:
            vz = float(ff[2])
            self._z_target = float(p[2])
        vz = min(max(vz, -c.max_descent_m_s), c.max_climb_m_s)
        if target.heading_rad is not None:
            self._slew_heading(float(target.heading_rad), dt_s)
        return self._velocity_stage(nav, gyro_flu_rad_s, (vx, vy, vz), target.accel_enu_m_s2, dt_s)

    def update_velocity(self, nav: NavState, gyro_flu_rad_s, velocity_enu_m_s, dt_s: float,
                        heading_rad: float | None = None, accel_enu_m_s2=(0.0, 0.0, 0.0)) -> ControlOutput:
        """Velocity command (GUIDED velocity); horizontal speed capped at max_speed_xy, vertical at the rates."""
        c = self._cfg
        vx, vy = float(velocity_enu_m_s[0]), float(velocity_enu_m_s[1])
        speed = math.hypot(vx, vy)
        if speed > c.max_speed_xy_m_s:
            vx *= c.max_speed_xy_m_s / speed
            vy *= c.max_speed_xy_m_s / speed
        vz = min(max(float(velocity_enu_m_s[2]), -c.max_descent_m_s), c.max_climb_m_s)
        self._z_target = float(nav.position_enu_m[2])
        if heading_rad is not None:
            self._slew_heading(float(heading_rad), dt_s)
        return self._velocity_stage(nav, gyro_flu_rad_s, (vx, vy, vz), accel_enu_m_s2, dt_s)

    def update_alt_hold(self, nav: NavState, gyro_flu_rad_s, roll_rad: float, pitch_rad: float,
                        yaw_rate_rad_s: float, climb_rate_m_s: float, dt_s: float) -> ControlOutput:
        """ALT_HOLD: pilot lean angles (aviation: roll right-wing-down +, pitch nose-up +), yaw rate (heading
        rate, clockwise / nose-right positive) and climb rate (m/s, up positive)."""
        c = self._cfg
        climb = min(max(float(climb_rate_m_s), -c.max_descent_m_s), c.max_climb_m_s)
        z = float(nav.position_enu_m[2])
        if self._landed:
            self._z_target = z
        self._z_target += climb * dt_s
        self._z_target = min(max(self._z_target, z - ALT_HOLD_LEASH_M), z + ALT_HOLD_LEASH_M)
        vz = climb + sqrt_controller(self._z_target - z, c.pos_z_p_1_s, c.max_accel_z_m_s2)
        vz = min(max(vz, -c.max_descent_m_s), c.max_climb_m_s)
        if self._check_takeoff(nav, vz):
            return self._idle_output(nav)
        az = self._vertical_velocity_loop(nav, vz, 0.0, dt_s)
        roll, pitch = self._limit_lean(float(roll_rad), float(pitch_rad))
        self._advance_heading(float(yaw_rate_rad_s), nav, dt_s)
        q_target = quat_from_aviation_euler(roll, pitch, self._heading_target)
        thrust = self._collective_thrust(nav, az)
        out = self._attitude_stage(nav, gyro_flu_rad_s, q_target, thrust, dt_s,
                                   yaw_rate_ff=-float(yaw_rate_rad_s), accel=(0.0, 0.0, az),
                                   velocity=(0.0, 0.0, vz), lean_limited=False)
        return self._land_detect(nav, out, vz, dt_s)

    def update_stabilize(self, nav: NavState, gyro_flu_rad_s, roll_rad: float, pitch_rad: float,
                         yaw_rate_rad_s: float, thrust_fraction: float, dt_s: float) -> ControlOutput:
        """STABILIZE: pilot lean angles (aviation convention), yaw rate (clockwise positive) and collective
        thrust as a fraction of the vehicle's maximum thrust (hover is mass * g / max_thrust)."""
        frac = min(max(float(thrust_fraction), 0.0), 1.0)
        thrust = frac * self._airframe.max_thrust_n
        if self._landed:
            if thrust > self._cfg.land_detect_thrust_fraction * self._hover_thrust:
                self._leave_landed()
            else:
                return self._idle_output(nav)
        roll, pitch = self._limit_lean(float(roll_rad), float(pitch_rad))
        self._advance_heading(float(yaw_rate_rad_s), nav, dt_s)
        q_target = quat_from_aviation_euler(roll, pitch, self._heading_target)
        out = self._attitude_stage(nav, gyro_flu_rad_s, q_target, min(thrust, self._thrust_max), dt_s,
                                   yaw_rate_ff=-float(yaw_rate_rad_s), accel=(0.0, 0.0, 0.0),
                                   velocity=(0.0, 0.0, 0.0), lean_limited=False)
        return self._land_detect(nav, out, 0.0, dt_s)

    def update_attitude(self, nav: NavState, gyro_flu_rad_s, q_target_wxyz, thrust_n: float, dt_s: float,
                        yaw_rate_ff_rad_s: float = 0.0) -> ControlOutput:
        """Attitude + collective thrust target (GUIDED attitude targets); tilt is limited to the lean angle.

        ``yaw_rate_ff_rad_s`` is a body-z (FLU, counter-clockwise positive) rate feed-forward."""
        q_t = quat_normalise(tuple(float(a) for a in q_target_wxyz))
        zt = quat_rotate(q_t, (0.0, 0.0, 1.0))
        tilt = math.acos(max(-1.0, min(1.0, zt[2])))
        max_lean = self._cfg.max_lean_angle_rad
        if tilt > max_lean:
            # Rotate back towards vertical about the horizontal axis z_world x z_target.
            ax, ay = -zt[1], zt[0]
            n = math.hypot(ax, ay)
            if n > 1e-9:
                k = (tilt - max_lean) / n
                q_t = quat_multiply(quat_from_rotation_vector(-ax * k, -ay * k, 0.0), q_t)
        thrust = min(max(float(thrust_n), 0.0), self._thrust_max)
        if self._landed:
            if thrust > self._cfg.land_detect_thrust_fraction * self._hover_thrust:
                self._leave_landed()
            else:
                return self._idle_output(nav)
        self._heading_target = heading_from_quat(q_t)
        out = self._attitude_stage(nav, gyro_flu_rad_s, q_t, thrust, dt_s, yaw_rate_ff=yaw_rate_ff_rad_s,
                                   accel=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0), lean_limited=tilt > max_lean)
        return self._land_detect(nav, out, 0.0, dt_s)

    # ------------------------------------------------------------------ stages
    def _velocity_stage(self, nav: NavState, gyro, vel_target, accel_ff, dt_s: float) -> ControlOutput:
        c = self._cfg
        vx_t, vy_t, vz_t = vel_target
        if self._check_takeoff(nav, vz_t):
            return self._idle_output(nav)
        v = nav.velocity_enu_m_s
        vx, vy = float(v[0]), float(v[1])
        # Horizontal PID: D on the (filtered) measured acceleration, I frozen while limited.
        ex, ey = vx_t - vx, vy_t - vy
        if self._prev_vel_xy is None:
            dvx = dvy = 0.0
        else:
            dvx = (vx - self._prev_vel_xy[0]) / dt_s
            dvy = (vy - self._prev_vel_xy[1]) / dt_s
        self._prev_vel_xy = (vx, vy)
        alpha = _lpf_alpha(c.vel_xy_d_filter_hz, dt_s)
        self._vel_xy_d[0] += alpha * (dvx - self._vel_xy_d[0])
        self._vel_xy_d[1] += alpha * (dvy - self._vel_xy_d[1])
        ix, iy = self._vel_xy_i
        dix, diy = c.vel_xy_i_1_s2 * ex * dt_s, c.vel_xy_i_1_s2 * ey * dt_s
        if self._lean_limited_xy and self._limited_track_u is not None:
            # cross-track priority cut (limit_accel_xy): only the along-track part was limited, so
            # only its growth is frozen; the crosswind part keeps integrating
            ux, uy = self._limited_track_u
            d_along = dix * ux + diy * uy
            if d_along * (ix * ux + iy * uy) > 0.0:
                dix -= d_along * ux
                diy -= d_along * uy
        elif self._lean_limited_xy and (ex * ix + ey * iy) > 0.0:
            dix = diy = 0.0
        if dix != 0.0 or diy != 0.0:
            ix += dix
            iy += diy
            mag = math.hypot(ix, iy)
            if mag > c.vel_xy_imax_m_s2:
                ix *= c.vel_xy_imax_m_s2 / mag
                iy *= c.vel_xy_imax_m_s2 / mag
            self._vel_xy_i = [ix, iy]
        # Feed-forward within the acceleration limits: a GUIDED acceleration target (up to 1000
        # m/s^2 passes the MAVLink sanity check) must not override the velocity loop.
        ffx, ffy = float(accel_ff[0]), float(accel_ff[1])
        ff_h = math.hypot(ffx, ffy)
        if ff_h > c.max_accel_xy_m_s2:
            ffx *= c.max_accel_xy_m_s2 / ff_h
            ffy *= c.max_accel_xy_m_s2 / ff_h
        ax = ffx + c.vel_xy_p_1_s * ex + ix - c.vel_xy_d_unitless * self._vel_xy_d[0]
        ay = ffy + c.vel_xy_p_1_s * ey + iy - c.vel_xy_d_unitless * self._vel_xy_d[1]
        az = self._vertical_velocity_loop(nav, vz_t, float(accel_ff[2]), dt_s)
        # Acceleration and lean limits.
        a_h = math.hypot(ax, ay)
        f_up = max(self._g + az, MIN_VERTICAL_SPECIFIC_FORCE_G * self._g)
        a_h_max = min(c.max_accel_xy_m_s2, f_up * self._tan_lean)
        lean_limited = a_h > a_h_max
        self._limited_track_u = None
        if lean_limited:
            ax, ay = limit_accel_xy(ax, ay, vx_t, vy_t, a_h_max)
            speed_t = math.hypot(vx_t, vy_t)
            if speed_t >= TRACK_PRIORITY_MIN_SPEED_M_S:
                ux, uy = vx_t / speed_t, vy_t / speed_t
                if abs(ax * uy - ay * ux) < a_h_max * (1.0 - 1e-9):   # the cross part fitted
                    self._limited_track_u = (ux, uy)
        self._lean_limited_xy = lean_limited
        # Thrust vector -> attitude target (Euler in the heading frame, so the heading is exact).
        yaw = 0.5 * math.pi - self._heading_target
        cy, sy = math.cos(yaw), math.sin(yaw)
        f_fwd = cy * ax + sy * ay
        f_left = -sy * ax + cy * ay
        f_norm = math.sqrt(f_fwd * f_fwd + f_left * f_left + f_up * f_up)
        roll_flu = math.asin(max(-1.0, min(1.0, -f_left / f_norm)))
        pitch_flu = math.atan2(f_fwd, f_up)
        q_target = quat_from_euler_zyx(yaw, pitch_flu, roll_flu)
        thrust = self._collective_thrust(nav, az)
        out = self._attitude_stage(nav, gyro, q_target, thrust, dt_s, yaw_rate_ff=0.0,
                                   accel=(ax, ay, az), velocity=(vx_t, vy_t, vz_t), lean_limited=lean_limited)
        return self._land_detect(nav, out, vz_t, dt_s)

    def _vertical_velocity_loop(self, nav: NavState, vz_target: float, az_ff: float, dt_s: float) -> float:
        c = self._cfg
        ez = vz_target - float(nav.velocity_enu_m_s[2])
        frozen = (ez > 0.0 and (self._thrust_at_max or self._limits.thrust_upper)) or \
                 (ez < 0.0 and (self._thrust_at_min or self._limits.thrust_lower))
        if not frozen:
            self._vel_z_i = min(max(self._vel_z_i + c.vel_z_i_1_s2 * ez * dt_s, -c.vel_z_imax_m_s2),
                                c.vel_z_imax_m_s2)
        az_ff = min(max(az_ff, -c.max_accel_z_m_s2), c.max_accel_z_m_s2)
        return az_ff + c.vel_z_p_1_s * ez + self._vel_z_i

    def _collective_thrust(self, nav: NavState, az: float) -> float:
        q = nav.q_wxyz
        x, y = float(q[1]), float(q[2])
        cos_tilt = 1.0 - 2.0 * (x * x + y * y)          # R[2, 2]: body z . world z
        cos_tilt = max(cos_tilt, self._min_cos_tilt)
        thrust = self._mass * max(self._g + az, 0.0) / cos_tilt
        self._thrust_at_max = thrust >= self._thrust_max
        self._thrust_at_min = thrust <= self._thrust_min
        return min(max(thrust, self._thrust_min), self._thrust_max)

    def _attitude_stage(self, nav: NavState, gyro, q_target, thrust: float, dt_s: float, *, yaw_rate_ff: float,
                        accel, velocity, lean_limited: bool) -> ControlOutput:
        c = self._cfg
        q = tuple(_floats(nav.q_wxyz))
        q_t = q_target
        z_cur = quat_rotate(q, (0.0, 0.0, 1.0))
        z_tgt = quat_rotate(q_t, (0.0, 0.0, 1.0))
        # Tilt error: world-frame rotation z_cur -> z_tgt.
        cx = z_cur[1] * z_tgt[2] - z_cur[2] * z_tgt[1]
        cy = z_cur[2] * z_tgt[0] - z_cur[0] * z_tgt[2]
        cz = z_cur[0] * z_tgt[1] - z_cur[1] * z_tgt[0]
        s = math.sqrt(cx * cx + cy * cy + cz * cz)
        dot = z_cur[0] * z_tgt[0] + z_cur[1] * z_tgt[1] + z_cur[2] * z_tgt[2]
        angle = math.atan2(s, dot)
        if s > 1e-9:
            k = angle / s
            rot_w = (cx * k, cy * k, cz * k)
        else:
            rot_w = (0.0, 0.0, 0.0)
        q_red = quat_multiply(quat_from_rotation_vector(*rot_w), q)
        # Remaining error about the (target) body z axis.
        q_yaw = quat_multiply(quat_conjugate(q_red), q_t)
        yaw_err = wrap_pi(2.0 * math.atan2(q_yaw[3], q_yaw[0]))
        q_inv = quat_conjugate(q)
        tilt_b = quat_rotate(q_inv, rot_w)
        zt_b = quat_rotate(q_inv, z_tgt)
        yaw_rate = c.ang_yaw_p_1_s * yaw_err + yaw_rate_ff
        yaw_rate = min(max(yaw_rate, -self._rate_yaw_max), self._rate_yaw_max)
        rmax = self._rate_rp_max
        rate_t = [min(max(c.ang_rp_p_1_s * tilt_b[0] + yaw_rate * zt_b[0], -rmax), rmax),
                  min(max(c.ang_rp_p_1_s * tilt_b[1] + yaw_rate * zt_b[1], -rmax), rmax),
                  yaw_rate * zt_b[2] + c.ang_rp_p_1_s * tilt_b[2]]
        rate_t[2] = min(max(rate_t[2], -self._rate_yaw_max), self._rate_yaw_max)
        torque = self._rate_loop(nav, gyro, rate_t, dt_s)
        return ControlOutput(thrust_n=float(thrust), torque_flu_n_m=np.array(torque),
                             q_target_wxyz=np.array(q_t), rate_target_flu_rad_s=np.array(rate_t),
                             accel_target_enu_m_s2=np.array(accel, dtype=float),
                             velocity_target_enu_m_s=np.array(velocity, dtype=float),
                             heading_target_rad=self._heading_target, lean_limited=lean_limited,
                             land_state=LandState.LANDED if self._landed else LandState.AIRBORNE,
                             touchdown=False)

    def _rate_loop(self, nav: NavState, gyro, rate_target, dt_s: float) -> tuple[float, float, float]:
        c = self._cfg
        g, bias = _floats(gyro), _floats(nav.gyro_bias)
        w = (g[0] - bias[0], g[1] - bias[1], g[2] - bias[2])
        alpha = _lpf_alpha(c.rate_d_filter_hz, dt_s)
        prev = self._prev_rate if self._prev_rate is not None else w
        self._prev_rate = w
        lim = self._limits
        ix_ok = not lim.roll_pitch
        alpha_cmd = [0.0, 0.0, 0.0]
        rate_d, rate_i = self._rate_d, self._rate_i
        for i, (kp, ki, kd, imax) in enumerate(self._rate_gains):
            err = rate_target[i] - w[i]
            rate_d[i] += alpha * ((w[i] - prev[i]) / dt_s - rate_d[i])
            frozen = (lim.yaw if i == 2 else not ix_ok) and err * rate_i[i] > 0.0
            if not frozen:
                rate_i[i] = min(max(rate_i[i] + ki * err * dt_s, -imax), imax)
            alpha_cmd[i] = kp * err + rate_i[i] - kd * rate_d[i]
        ixx, iyy, izz = self._inertia
        hx, hy, hz = ixx * w[0], iyy * w[1], izz * w[2]
        # tau = I alpha + w x (I w)
        return (ixx * alpha_cmd[0] + (w[1] * hz - w[2] * hy),
                iyy * alpha_cmd[1] + (w[2] * hx - w[0] * hz),
                izz * alpha_cmd[2] + (w[0] * hy - w[1] * hx))

    # ------------------------------------------------------------------ helpers
    def _slew_heading(self, heading_rad: float, dt_s: float) -> None:
        err = wrap_pi(heading_rad - self._heading_target)
        step = self._rate_yaw_max * dt_s
        err = min(max(err, -step), step)
        self._heading_target = (self._heading_target + err) % _TWO_PI

    def _advance_heading(self, yaw_rate_rad_s: float, nav: NavState, dt_s: float) -> None:
        """Pilot yaw rate (positive = nose right, clockwise like the heading) moves the heading target."""
        rate = min(max(yaw_rate_rad_s, -self._rate_yaw_max), self._rate_yaw_max)
        target = self._heading_target + rate * dt_s
        # Keep the target within 30 deg of the actual heading (no wind-up if the yaw is saturated).
        err = wrap_pi(target - float(nav.heading_rad))
        err = min(max(err, -PILOT_HEADING_LEASH_RAD), PILOT_HEADING_LEASH_RAD)
        self._heading_target = (float(nav.heading_rad) + err) % _TWO_PI

    def _limit_lean(self, roll: float, pitch: float) -> tuple[float, float]:
        max_lean = self._cfg.max_lean_angle_rad
        roll = min(max(roll, -max_lean), max_lean)
        pitch = min(max(pitch, -max_lean), max_lean)
        tilt = math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch))))
        if tilt > max_lean:
            roll *= max_lean / tilt
            pitch *= max_lean / tilt
        return roll, pitch

    def _check_takeoff(self, nav: NavState, climb_target: float) -> bool:
        """While landed: leave the landed state on a climb demand; otherwise report 'stay idle'."""
        if not self._landed:
            return False
        if climb_target > self._cfg.takeoff_min_climb_m_s:
            self._leave_landed()
            return False
        self._heading_target = float(nav.heading_rad)
        return True

    def _leave_landed(self) -> None:
        logger.info("FlightController: takeoff (leaving the landed state)")
        self._reset_integrators()
        self._landed = False
        self._land_timer_s = 0.0

    def _idle_output(self, nav: NavState) -> ControlOutput:
        self._reset_integrators()
        zero3 = np.zeros(3)
        return ControlOutput(thrust_n=0.0, torque_flu_n_m=zero3, q_target_wxyz=np.array(nav.q_wxyz, dtype=float),
                             rate_target_flu_rad_s=zero3.copy(), accel_target_enu_m_s2=zero3.copy(),
                             velocity_target_enu_m_s=zero3.copy(), heading_target_rad=self._heading_target,
                             lean_limited=False, land_state=LandState.LANDED, touchdown=False)

    def _land_detect(self, nav: NavState, out: ControlOutput, climb_target: float, dt_s: float) -> ControlOutput:
        c = self._cfg
        if self._landed:
            return out
        v = nav.velocity_enu_m_s
        low_thrust = out.thrust_n < c.land_detect_thrust_fraction * self._hover_thrust
        slow = abs(float(v[2])) < c.land_detect_max_speed_z_m_s and \
            math.hypot(float(v[0]), float(v[1])) < c.land_detect_max_speed_xy_m_s
        if low_thrust and slow and climb_target <= 0.0:
            self._land_timer_s += dt_s
        else:
            self._land_timer_s = 0.0
        if self._land_timer_s < c.land_detect_time_s:
            return out
        logger.info("FlightController: touchdown detected")
        self._landed = True
        self._land_timer_s = 0.0
        idle = self._idle_output(nav)
        return dataclasses.replace(idle, touchdown=True)

