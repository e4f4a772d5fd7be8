"""Quad-X mixer on the autopilot's airframe model (``autopilot_bridge.airframe``): (collective thrust, body
torques) -> 4 motor commands in ``scenenav.core.contracts.QuadXRotor`` order.

Physics (body FLU, rotor i at (x_i, y_i), thrust T_i along body +z, spin direction d_i = +1 CCW / -1 CW):

    collective  T   = sum T_i
    roll        t_x = sum  y_i * T_i          (r x F with F = (0, 0, T_i): x-component  y_i * T_i)
    pitch       t_y = sum -x_i * T_i          (y-component -x_i * T_i)
    yaw         t_z = sum -d_i * c * T_i      (rotor reaction torque, c = moment_constant_m)

So a positive roll torque (about body +x, forward) needs more thrust on the left rotors (y > 0): the left
side rises and the right wing goes down. A positive pitch torque (about body +y, left) needs more thrust
on the back rotors: the nose goes down. A positive yaw torque (counter-clockwise seen from above) needs
more thrust on the clockwise rotors (rotor_2, rotor_3), whose reaction torque is counter-clockwise.

The 4x4 allocation matrix is inverted exactly (the Iris arms are slightly asymmetric: front rotors at
|y| = 0.22 m, back rotors at |y| = 0.20 m); with zero torques the four thrusts are equal.

Commands are normalised rotor speeds (``MotorCommand``). The model's thrust curve (MOT_THST_EXPO e, the
ArduPilot thrust curve of ``AP_MotorsMulticopter::thrust_to_actuator``) maps a rotor's thrust fraction
f = T_i / (k w_max^2) to the linear command x = ((e - 1) + sqrt((1 - e)^2 + 4 e f)) / (2 e), and
command_i = MOT_SPIN_MIN + (MOT_SPIN_MAX - MOT_SPIN_MIN) x. For e = 1 (the default, a rotor-speed
command: thrust = k omega^2) that is command_i = sqrt(T_i / k) / w_max, computed in that form.

Saturation priority (rotor thrust limits [0, k w_max^2]):
1. roll/pitch: if the roll/pitch thrust differences alone span more than the available range, they are
   scaled down together (keeping the torque direction); flag ``roll_pitch``.
2. thrust: the common collective offset is moved (down, or up) just enough for roll/pitch to fit;
   flags ``thrust_upper`` / ``thrust_lower``.
3. yaw: the yaw thrust differences are scaled by the largest factor in [0, 1] that still fits; flag ``yaw``.
The limit flags are fed back to the controllers for anti-windup.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from autopilot_bridge.airframe import Airframe

logger = logging.getLogger(__name__)

NUM_ROTORS = 4


@dataclass(frozen=True)
class MixerLimits:
    """Which demands the mixer could not meet on the last call (for controller anti-windup)."""

    roll_pitch: bool = False
    thrust_upper: bool = False
    thrust_lower: bool = False
    yaw: bool = False

    @property
    def any(self) -> bool:
        return self.roll_pitch or self.thrust_upper or self.thrust_lower or self.yaw


@dataclass(frozen=True)
class MixerOutput:
    """Motor commands (rotor-speed fractions, ``QuadXRotor`` order) and what they achieve."""

    commands: np.ndarray            # (4,) in [MOT_SPIN_MIN, MOT_SPIN_MAX]
    rotor_thrusts_n: np.ndarray     # (4,) steady-state thrust of each rotor at its command
    thrust_n: float                 # collective thrust achieved
    torque_flu_n_m: np.ndarray      # (3,) body torque achieved
    limits: MixerLimits


class QuadXMixer:
    """Allocates collective thrust and body torques to the four rotors of the airframe model."""

    def __init__(self, airframe: Airframe | None = None) -> None:
        self._airframe = a = airframe if airframe is not None else Airframe()
        positions = a.rotor_positions_flu_m
        xs = np.array([p[0] for p in positions], dtype=float)
        ys = np.array([p[1] for p in positions], dtype=float)
        dirs = np.array([int(d) for d in a.rotor_spins], dtype=float)
        # Rows: collective thrust, roll torque, pitch torque, yaw torque; columns: rotor thrusts.
        self._allocation = np.vstack([np.ones(NUM_ROTORS), ys, -xs, -dirs * a.moment_constant_m])
        self._inverse = np.linalg.inv(self._allocation)
        self._alloc_rows = tuple(tuple(float(v) for v in row) for row in self._allocation)
        self._inv_cols = tuple(tuple(float(v) for v in self._inverse[:, j]) for j in range(NUM_ROTORS))
        self._k = a.thrust_coefficient_n_per_rad2_s2
        self._w_max = a.max_rotor_speed_rad_s
        self._t_min = 0.0
        self._t_max = self._k * self._w_max ** 2

    @property
    def allocation_matrix(self) -> np.ndarray:
        """4x4 matrix mapping rotor thrusts (N) to [thrust N, roll, pitch, yaw torque N m]."""
        return self._allocation.copy()

    @property
    def rotor_thrust_limits_n(self) -> tuple[float, float]:
        return self._t_min, self._t_max

    @property
    def hover_command(self) -> float:
        """Command of each rotor when the four together carry the vehicle's weight (the model's)."""
        a = self._airframe
        return self.command_for_thrust(a.thrust_mass_kg * a.gravity_m_s2 / NUM_ROTORS)

    def command_for_thrust(self, rotor_thrust_n: float) -> float:
        """Normalised command that makes one rotor produce ``rotor_thrust_n`` in steady state."""
        return float(self._commands(np.array([max(rotor_thrust_n, 0.0)]))[0])

    def _commands(self, thrusts: np.ndarray) -> np.ndarray:
        """Rotor thrusts (N, within the limits) -> commands through the thrust curve."""
        a = self._airframe
        e = a.thrust_expo
        if e == 1.0:
            x = np.sqrt(thrusts / self._k) / self._w_max
        else:
            f = thrusts / self._t_max
            x = f if e == 0.0 else ((e - 1.0) + np.sqrt((1.0 - e) ** 2 + 4.0 * e * f)) / (2.0 * e)
        return a.spin_min + (a.spin_max - a.spin_min) * x

    def mix(self, thrust_n: float, torque_flu_n_m) -> MixerOutput:
        """Collective thrust (N, along body +z) and body torques (N m, FLU) -> motor commands."""
        # Scalar arithmetic on the four rotors (numpy calls on 4-vectors cost more than the
        # arithmetic); the same operations in the same order as the vectorised form, so the same bits.
        tx, ty, tz = (float(torque_flu_n_m[0]), float(torque_flu_n_m[1]), float(torque_flu_n_m[2]))
        c0, c1, c2, c3 = self._inv_cols
        t_min, t_max = self._t_min, self._t_max
        span = t_max - t_min
        thrust = float(thrust_n)
        base = [c * thrust for c in c0]             # equal thrusts for a pure collective demand
        base_level = (base[0] + (base[1] + base[2] + base[3])) / NUM_ROTORS   # numpy's reduction order
        rp = [a * tx + b * ty for a, b in zip(c1, c2, strict=True)]
        yaw = [c * tz for c in c3]

        roll_pitch_limited = False
        rp_max, rp_min = max(rp), min(rp)
        rp_range = rp_max - rp_min
        if rp_range > span:
            f = span / rp_range
            rp = [r * f for r in rp]
            rp_max, rp_min = max(rp), min(rp)
            roll_pitch_limited = True

        # Collective level that lets roll/pitch fit.
        lo = t_min - rp_min
        hi = t_max - rp_max
        thrust_upper = thrust_lower = False
        level = base_level
        if level > hi:
            level = hi
            thrust_upper = True
        if level < lo:
            level = lo
            thrust_lower = True
        partial = [level + r for r in rp]

        # Largest yaw scale in [0, 1] that keeps every rotor within its limits.
        scale = 1.0
        for i in range(NUM_ROTORS):
            y = yaw[i]
            if y > 1e-12:
                scale = min(scale, (t_max - partial[i]) / y)
            elif y < -1e-12:
                scale = min(scale, (t_min - partial[i]) / y)
        scale = max(scale, 0.0)
        yaw_limited = scale < 1.0 - 1e-9
        thrust_list = [min(max(pa + scale * y, t_min), t_max) for pa, y in zip(partial, yaw, strict=True)]
        commands = np.array(self._commands_list(thrust_list))
        # what the thrusts achieve (allocation x thrusts, summed in rotor order; the flight uses only
        # the commands and the limits)
        t0, t1, t2, t3 = thrust_list
        achieved = [r0 * t0 + r1 * t1 + r2 * t2 + r3 * t3 for r0, r1, r2, r3 in self._alloc_rows]
        limits = MixerLimits(roll_pitch=roll_pitch_limited, thrust_upper=thrust_upper,
                             thrust_lower=thrust_lower, yaw=yaw_limited)
        return MixerOutput(commands=commands, rotor_thrusts_n=np.array(thrust_list), thrust_n=achieved[0],
                           torque_flu_n_m=np.array(achieved[1:]), limits=limits)

    def _commands_list(self, thrusts: list[float]) -> list[float]:
        """``_commands`` on a list of floats (the same arithmetic, element by element)."""
        a = self._airframe
        e = a.thrust_expo
        lo, gain = a.spin_min, a.spin_max - a.spin_min
        if e == 1.0:
            k, w_max = self._k, self._w_max
            return [lo + gain * (math.sqrt(t / k) / w_max) for t in thrusts]
        t_max = self._t_max
        if e == 0.0:
            return [lo + gain * (t / t_max) for t in thrusts]
        return [lo + gain * (((e - 1.0) + math.sqrt((1.0 - e) ** 2 + 4.0 * e * (t / t_max))) / (2.0 * e))
                for t in thrusts]
