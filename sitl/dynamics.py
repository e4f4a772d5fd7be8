"""Quadrotor rotor and airframe model (pure numpy; the pybullet shell is sitl.physics).

Frames (scenenav/core/frames.py): world ENU, body FLU, ``q_wxyz`` rotates body vectors into the world
(quaternion and heading helpers: ``scenenav.core.rotations``).
Rotor model after the ``gazebo_motor_model`` plugin that PX4's Iris model uses (constants in
``sitl.vehicle.VehicleParams``); for rotor i with speed w_i (rad/s, >= 0), spin direction d_i
(+1 = counter-clockwise seen from above) and position r_i in the body frame:

    thrust          T_i = k_T w_i^2                       along body +z, applied at r_i
    drag torque     Q_i = -d_i k_M T_i                    about body +z (reaction on the airframe)
    rotor drag      D_i = -c_D w_i v_perp                 applied at r_i
    rolling moment  M_i = -d_i c_R w_i v_perp

with v_perp the part of the body-frame airspeed (vehicle velocity minus wind) perpendicular to the
rotor axis (body z). Airframe drag is quadratic per body axis: F_j = -0.5 rho (Cd A)_j |v| v_j.
The motors are first-order lags with separate rise and fall time constants. Gravity is not part of
the wrench: the physics engine adds it.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from sitl.vehicle import VehicleParams

logger = logging.getLogger(__name__)


def rotation_rows(q_wxyz) -> tuple[tuple[float, float, float], ...]:
    """Rows of the body -> world rotation matrix of a quaternion (w, x, y, z), as plain floats.

    The quaternion is normalised; a zero or non-finite quaternion raises ValueError.
    """
    w, x, y, z = q_wxyz
    w, x, y, z = float(w), float(x), float(y), float(z)
    n = w * w + x * x + y * y + z * z
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError(f"quaternion {q_wxyz!r} has no direction")
    s = 2.0 / n
    wx, wy, wz = s * w * x, s * w * y, s * w * z
    xx, xy, xz = s * x * x, s * x * y, s * x * z
    yy, yz, zz = s * y * y, s * y * z, s * z * z
    return ((1.0 - (yy + zz), xy - wz, xz + wy),
            (xy + wz, 1.0 - (xx + zz), yz - wx),
            (xz - wy, yz + wx, 1.0 - (xx + yy)))


class QuadrotorDynamics:
    """Motor lag and the aerodynamic wrench of an X quadrotor (see the module docstring).

    Attributes:
        rotor_speeds_rad_s: (4,) current rotor speeds, rad/s (never negative).
    """

    def __init__(self, params: VehicleParams) -> None:
        n = len(params.rotor_positions_flu_m)
        if n != len(params.rotor_directions):
            raise ValueError("VehicleParams: rotor_positions_flu_m and rotor_directions differ in length")
        self.params = params
        self.rotor_count = n
        self._k_thrust = params.motor_constant_n_per_rad2_s2
        self._k_moment = params.moment_constant_m
        self._max_speed = params.max_rotor_speed_rad_s
        self._tau_up = params.motor_time_constant_up_s
        self._tau_down = params.motor_time_constant_down_s
        self._positions = np.array([(x, y, 0.0) for x, y in params.rotor_positions_flu_m])   # (n, 3)
        self._directions = np.array([float(d) for d in params.rotor_directions])             # (n,)
        self._drag_half_rho_cda_list = [0.5 * params.air_density_kg_m3 * cda
                                        for cda in params.body_drag_cd_area_m2]
        self._positions_list = [tuple(r) for r in self._positions.tolist()]
        self._directions_list = self._directions.tolist()
        self._rotor_drag = params.rotor_drag_coefficient
        self._rolling = params.rolling_moment_coefficient
        self._cache_dt_s = -1.0
        self._alpha_up = 0.0
        self._alpha_down = 0.0
        self._speeds = [0.0] * n

    @property
    def rotor_speeds_rad_s(self) -> np.ndarray:
        """(n,) current rotor speeds, rad/s (a fresh array)."""
        return np.array(self._speeds)

    @rotor_speeds_rad_s.setter
    def rotor_speeds_rad_s(self, speeds: np.ndarray) -> None:
        self._speeds = [float(w) for w in np.asarray(speeds, dtype=float).reshape(self.rotor_count)]

    @property
    def hover_command(self) -> float:
        """Normalised command whose steady rotor speed carries the weight."""
        return self.params.hover_rotor_speed_rad_s / self._max_speed

    def reset(self) -> None:
        """Stop the rotors."""
        self._speeds = [0.0] * self.rotor_count

    def set_rotor_speeds(self, rotor_speeds_rad_s: np.ndarray) -> None:
        """Set the rotor speeds directly (clipped to [0, max]); for scripted starts in the air."""
        speeds = np.nan_to_num(np.asarray(rotor_speeds_rad_s, dtype=float).reshape(self.rotor_count))
        self.rotor_speeds_rad_s = np.clip(speeds, 0.0, self._max_speed)

    def step_motors(self, command: np.ndarray, dt_s: float) -> np.ndarray:
        """Advance the motors by ``dt_s`` toward ``command`` and return the rotor speeds (rad/s).

        ``command`` is (n,) normalised: clipped to [0, 1], NaN read as 0; the commanded speed is
        command * max_rotor_speed. Each motor follows the exact discretisation of a first-order lag,
        with the rise time constant when speeding up and the fall one when slowing down.
        """
        cmd = command.tolist() if isinstance(command, np.ndarray) else list(command)
        self.advance_motors(cmd, dt_s)
        return np.array(self._speeds)

    def advance_motors(self, command: list[float], dt_s: float) -> None:
        """``step_motors`` without the arrays (the physics loop's hot path): ``command`` a list of
        n normalised commands; the new speeds are ``rotor_speeds_rad_s``."""
        if dt_s != self._cache_dt_s:
            if not dt_s >= 0.0:
                raise ValueError(f"dt_s = {dt_s}: expected a number >= 0")
            self._cache_dt_s = dt_s
            self._alpha_up = -math.expm1(-dt_s / self._tau_up)
            self._alpha_down = -math.expm1(-dt_s / self._tau_down)
        if len(command) != self.rotor_count:
            raise ValueError(f"command has {len(command)} values: expected {self.rotor_count}")
        speeds = self._speeds
        max_speed, up, down = self._max_speed, self._alpha_up, self._alpha_down
        for i, c in enumerate(command):
            c = float(c)
            if not c > 0.0:          # NaN and negative commands stop the motor
                c = 0.0
            elif c > 1.0:
                c = 1.0
            error = c * max_speed - speeds[i]
            speeds[i] += (up if error > 0.0 else down) * error

    def thrusts_n(self) -> np.ndarray:
        """(n,) rotor thrusts, N."""
        return self._k_thrust * self.rotor_speeds_rad_s * self.rotor_speeds_rad_s

    def _wrench_body_tuple(self, vx: float, vy: float, vz: float) -> tuple[float, ...]:
        """Body-frame wrench (fx, fy, fz, tx, ty, tz) for a body-frame airspeed, plain floats."""
        k_t = self._k_thrust
        k_m = self._k_moment
        fz = tx = ty = tz = 0.0
        w_sum = w_dir = lever_x = lever_y = 0.0
        for w, (rx, ry, _), d in zip(self._speeds, self._positions_list,
                                     self._directions_list, strict=True):
            thrust = k_t * w * w
            fz += thrust
            tx += ry * thrust               # r x (0, 0, T) = (r_y T, -r_x T, 0)
            ty -= rx * thrust
            tz -= d * k_m * thrust          # reaction of the rotor drag torque
            w_sum += w
            w_dir += d * w
            lever_x += w * rx
            lever_y += w * ry
        fx = fy = 0.0
        if vx != 0.0 or vy != 0.0 or vz != 0.0:
            # Rotor drag -c_D w_i v_perp at each rotor (v_perp = (vx, vy, 0)): force and moment
            # -c_D (sum_i w_i r_i) x v_perp, with r_i = (x_i, y_i, 0).
            c_d = self._rotor_drag
            fx -= c_d * w_sum * vx
            fy -= c_d * w_sum * vy
            tz -= c_d * (lever_x * vy - lever_y * vx)
            # Rolling moments -d_i c_R w_i v_perp.
            c_r = self._rolling * w_dir
            tx -= c_r * vx
            ty -= c_r * vy
            # Airframe drag -0.5 rho (Cd A)_j |v| v_j.
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            dx, dy, dz = self._drag_half_rho_cda_list
            fx -= dx * speed * vx
            fy -= dy * speed * vy
            fz -= dz * speed * vz
        return fx, fy, fz, tx, ty, tz

    def wrench_body(self, airspeed_flu_m_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force_flu_n, torque_flu_nm) about the centre of mass for a body-frame airspeed (m/s).

        The airspeed is the vehicle velocity relative to the air (velocity minus wind), in FLU.
        """
        vx, vy, vz = (float(c) for c in airspeed_flu_m_s)
        fx, fy, fz, tx, ty, tz = self._wrench_body_tuple(vx, vy, vz)
        return np.array([fx, fy, fz]), np.array([tx, ty, tz])

    def wrench(self, q_wxyz: np.ndarray, velocity_enu_m_s: np.ndarray,
               wind_enu_m_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force_enu_n, torque_enu_nm) acting at the centre of mass, in the WORLD frame. No gravity."""
        fx, fy, fz, tx, ty, tz = self.wrench_world(rotation_rows(q_wxyz), velocity_enu_m_s, wind_enu_m_s)
        return np.array([fx, fy, fz]), np.array([tx, ty, tz])

    def wrench_world(self, rows, velocity_enu_m_s, wind_enu_m_s) -> tuple[float, ...]:
        """``wrench`` as six plain floats (fx, fy, fz, tx, ty, tz), world frame, for the attitude
        given by its ``rotation_rows``: the physics loop's hot path (sequences of floats in, no
        arrays allocated)."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
        ax = float(velocity_enu_m_s[0]) - float(wind_enu_m_s[0])
        ay = float(velocity_enu_m_s[1]) - float(wind_enu_m_s[1])
        az = float(velocity_enu_m_s[2]) - float(wind_enu_m_s[2])
        # Airspeed in the body frame: R^T a.
        bx = r00 * ax + r10 * ay + r20 * az
        by = r01 * ax + r11 * ay + r21 * az
        bz = r02 * ax + r12 * ay + r22 * az
        fx, fy, fz, tx, ty, tz = self._wrench_body_tuple(bx, by, bz)
        return (r00 * fx + r01 * fy + r02 * fz,
                r10 * fx + r11 * fy + r12 * fz,
                r20 * fx + r21 * fy + r22 * fz,
                r00 * tx + r01 * ty + r02 * tz,
                r10 * tx + r11 * ty + r12 * tz,
                r20 * tx + r21 * ty + r22 * tz)
