"""Physical parameters of the IRIS-like quadrotor.

Source of every constant, unless stated otherwise: the 3DR Iris model of PX4's Gazebo simulation,
PX4-SITL_gazebo-classic, ``models/iris/iris.sdf.jinja`` (base_link inertial, rotor_N joints and the
``gazebo_motor_model`` plugin parameters). Frames: body FLU (x forward, y left, z up), as in that model.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class SpinDirection(IntEnum):
    """Rotor spin seen from above; +1 spins about body +z (counter-clockwise)."""

    CCW = 1
    CW = -1


@dataclass(frozen=True)
class VehicleParams:
    # iris.sdf base_link <mass>.
    mass_kg: float = 1.5
    # iris.sdf base_link <inertia> ixx, iyy, izz (products of inertia are zero).
    inertia_kg_m2: tuple[float, float, float] = (0.029125, 0.029125, 0.055225)
    # iris.sdf rotor_0..rotor_3 joint poses (x, y) in the body frame, metres.
    rotor_positions_flu_m: tuple[tuple[float, float], ...] = (
        (0.13, -0.22),   # rotor_0 front right
        (-0.13, 0.20),   # rotor_1 back left
        (0.13, 0.22),    # rotor_2 front left
        (-0.13, -0.20),  # rotor_3 back right
    )
    # iris.sdf motor plugins <turningDirection>: rotor_0 ccw, rotor_1 ccw, rotor_2 cw, rotor_3 cw.
    rotor_directions: tuple[SpinDirection, ...] = (
        SpinDirection.CCW, SpinDirection.CCW, SpinDirection.CW, SpinDirection.CW)
    # iris.sdf <motorConstant>: thrust = k * omega^2, N/(rad/s)^2.
    motor_constant_n_per_rad2_s2: float = 5.84e-06
    # iris.sdf <momentConstant>: drag torque = c * thrust, N m per N.
    moment_constant_m: float = 0.06
    # iris.sdf <maxRotVelocity>, rad/s.
    max_rotor_speed_rad_s: float = 1100.0
    # iris.sdf <timeConstantUp> / <timeConstantDown>: first-order motor lag, s.
    motor_time_constant_up_s: float = 0.0125
    motor_time_constant_down_s: float = 0.025
    # iris.sdf <rotorDragCoefficient>: in-plane rotor drag = -c * omega * v_perp, N/((rad/s)(m/s)).
    rotor_drag_coefficient: float = 8.06428e-05
    # iris.sdf <rollingMomentCoefficient>: rolling moment = -c * omega * v_perp, N m/((rad/s)(m/s)).
    rolling_moment_coefficient: float = 1e-06
    # Body drag (not in iris.sdf): quadratic, 0.5 * rho * Cd * A * |v| v per body axis, with Cd = 1.0
    # (bluff box) and the areas of the iris.sdf collision box 0.47 x 0.47 x 0.11 m; rho = 1.225 kg/m^3
    # (ISA sea level). Values are Cd * A, in m^2, for body x, y, z.
    body_drag_cd_area_m2: tuple[float, float, float] = (0.0517, 0.0517, 0.2209)
    air_density_kg_m3: float = 1.225
    # iris.sdf base_link collision box, metres.
    collision_box_m: tuple[float, float, float] = (0.47, 0.47, 0.11)
    gravity_m_s2: float = 9.80665  # standard gravity (CGPM 1901)

    @property
    def hover_rotor_speed_rad_s(self) -> float:
        """Rotor speed at which the four rotors carry the weight."""
        return (self.mass_kg * self.gravity_m_s2 / (4.0 * self.motor_constant_n_per_rad2_s2)) ** 0.5

    @property
    def max_thrust_n(self) -> float:
        return 4.0 * self.motor_constant_n_per_rad2_s2 * self.max_rotor_speed_rad_s ** 2
