"""The autopilot's own airframe model: what the controller and the mixer believe about the vehicle.

A real ArduCopter knows its airframe only through its parameters; so does this autopilot. The
simulator's truth (``sitl.vehicle.VehicleParams``) is never imported here: a scenario can give the
autopilot a model that differs from the plant (``autopilot.params: {SN_MASS_KG: 1.8}``) and the flight
shows the mismatch.

Parameters (served with ArduCopter's over MAVLink, ``AIRFRAME_PARAM_SPECS``):

- ArduPilot names where ArduPilot has them (``libraries/AP_Motors/AP_MotorsMulticopter.cpp``
  ``@Param`` docs; https://ardupilot.org/copter/docs/motor-thrust-scaling.html):
  ``MOT_THST_EXPO`` (thrust curve: rotor thrust fraction = (1 - e) x + e x^2 of the linear command x;
  1 = thrust proportional to the rotor speed squared, which is what a rotor-speed command gives),
  ``MOT_SPIN_MIN`` / ``MOT_SPIN_MAX`` (the output range: command = spin_min + (spin_max - spin_min) x),
  ``MOT_THST_HOVER`` (hover thrust as a fraction of the maximum; 0 = from ``SN_MASS_KG`` and the rotor
  model; ArduPilot learns it, this autopilot does not).
- ``SN_`` parameters where ArduPilot has none (it works in throttle units, this controller in newtons):
  mass, inertia, rotor arm geometry, rotor thrust and drag-torque coefficients, maximum rotor speed.

Defaults are the 3DR Iris of PX4's Gazebo simulation (PX4-SITL_gazebo-classic,
``models/iris/iris.sdf.jinja``: base_link inertial, rotor_N joint poses, ``gazebo_motor_model``
parameters), the model the simulator flies, so by default the autopilot's model equals the plant
(``tests/unit/app/test_airframe_defaults.py``). ArduPilot's own defaults differ (MOT_THST_EXPO 0.65,
MOT_SPIN_MIN 0.15, MOT_SPIN_MAX 0.95): they describe an ESC's PWM range, not a rotor-speed command.

Rotor order: ``scenenav.core.contracts.QuadXRotor`` (ArduPilot's quad-X motors 1-4); body FLU.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from autopilot_bridge.params import ParameterStore, ParamSpec, ParamType
from scenenav.core.config import check
from scenenav.core.contracts import QuadXRotor, RotorSpin

STANDARD_GRAVITY_M_S2 = 9.80665  # standard gravity (CGPM 1901)


@dataclass(frozen=True)
class Airframe:
    """The autopilot's quad-X model (see the module docstring); defaults: the PX4 Iris."""

    # iris.sdf base_link <mass>.
    mass_kg: float = 1.5
    # iris.sdf base_link <inertia> ixx, iyy, izz (products of inertia are zero).
    inertia_kg_m2: tuple[float, float, float] = (0.029125, 0.029125, 0.055225)
    # iris.sdf rotor_0/rotor_2 joint poses: front rotors at x = +0.13 m, |y| = 0.22 m;
    # rotor_1/rotor_3: back rotors at x = -0.13 m, |y| = 0.20 m.
    front_arm_x_m: float = 0.13
    front_arm_y_m: float = 0.22
    back_arm_x_m: float = 0.13
    back_arm_y_m: float = 0.20
    # iris.sdf <motorConstant>: thrust = k * omega^2, N/(rad/s)^2.
    thrust_coefficient_n_per_rad2_s2: float = 5.84e-06
    # iris.sdf <momentConstant>: drag torque = c * thrust, N m per N.
    moment_constant_m: float = 0.06
    # iris.sdf <maxRotVelocity>, rad/s (the rotor speed of command 1).
    max_rotor_speed_rad_s: float = 1100.0
    # MOT_THST_EXPO: 1 = thrust proportional to the command squared (a rotor-speed command).
    thrust_expo: float = 1.0
    # MOT_SPIN_MIN / MOT_SPIN_MAX: the command range of zero to full thrust.
    spin_min: float = 0.0
    spin_max: float = 1.0
    # MOT_THST_HOVER: hover thrust / maximum thrust; 0 = mass_kg * g / max_thrust_n.
    thrust_hover: float = 0.0

    def __post_init__(self) -> None:
        for name in ("mass_kg", "front_arm_x_m", "front_arm_y_m", "back_arm_x_m", "back_arm_y_m",
                     "thrust_coefficient_n_per_rad2_s2", "max_rotor_speed_rad_s"):
            value = getattr(self, name)
            check(value > 0, name, value, "> 0")
        check(len(self.inertia_kg_m2) == 3 and min(self.inertia_kg_m2) > 0, "inertia_kg_m2",
              self.inertia_kg_m2, "three moments of inertia > 0")
        check(self.moment_constant_m >= 0, "moment_constant_m", self.moment_constant_m, ">= 0 m")
        check(-1.0 <= self.thrust_expo <= 1.0, "thrust_expo", self.thrust_expo, "in [-1, 1]")
        check(0.0 <= self.spin_min < self.spin_max <= 1.0, "spin_min", (self.spin_min, self.spin_max),
              "0 <= MOT_SPIN_MIN < MOT_SPIN_MAX <= 1")
        check(0.0 <= self.thrust_hover < 1.0, "thrust_hover", self.thrust_hover, "in [0, 1)")

    @property
    def gravity_m_s2(self) -> float:
        return STANDARD_GRAVITY_M_S2

    @property
    def rotor_positions_flu_m(self) -> tuple[tuple[float, float], ...]:
        """(x, y) of each rotor in ``QuadXRotor`` order."""
        where = {QuadXRotor.FRONT_RIGHT: (self.front_arm_x_m, -self.front_arm_y_m),
                 QuadXRotor.BACK_LEFT: (-self.back_arm_x_m, self.back_arm_y_m),
                 QuadXRotor.FRONT_LEFT: (self.front_arm_x_m, self.front_arm_y_m),
                 QuadXRotor.BACK_RIGHT: (-self.back_arm_x_m, -self.back_arm_y_m)}
        return tuple(where[r] for r in QuadXRotor)

    @property
    def rotor_spins(self) -> tuple[RotorSpin, ...]:
        return tuple(r.spin for r in QuadXRotor)

    @property
    def max_thrust_n(self) -> float:
        """Collective thrust of the four rotors at full command."""
        return 4.0 * self.thrust_coefficient_n_per_rad2_s2 * self.max_rotor_speed_rad_s ** 2

    @property
    def thrust_mass_kg(self) -> float:
        """The mass the controller scales thrust by: ``mass_kg``, or the one MOT_THST_HOVER implies."""
        if self.thrust_hover > 0.0:
            return self.thrust_hover * self.max_thrust_n / self.gravity_m_s2
        return self.mass_kg

    @property
    def hover_thrust_fraction(self) -> float:
        """Hover thrust / maximum thrust (MOT_THST_HOVER as this model predicts it)."""
        return self.thrust_mass_kg * self.gravity_m_s2 / self.max_thrust_n

    @classmethod
    def from_params(cls, params: ParameterStore) -> Airframe:
        p = params.get
        return cls(mass_kg=p("SN_MASS_KG"),
                   inertia_kg_m2=(p("SN_IXX"), p("SN_IYY"), p("SN_IZZ")),
                   front_arm_x_m=p("SN_ARM_FX"), front_arm_y_m=p("SN_ARM_FY"),
                   back_arm_x_m=p("SN_ARM_BX"), back_arm_y_m=p("SN_ARM_BY"),
                   thrust_coefficient_n_per_rad2_s2=p("SN_ROT_KT"),
                   moment_constant_m=p("SN_ROT_KM"), max_rotor_speed_rad_s=p("SN_ROT_WMAX"),
                   thrust_expo=p("MOT_THST_EXPO"), spin_min=p("MOT_SPIN_MIN"),
                   spin_max=p("MOT_SPIN_MAX"), thrust_hover=p("MOT_THST_HOVER"))


_IRIS = Airframe()
_F = ParamType.REAL32

AIRFRAME_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("MOT_SPIN_MAX", _F, _IRIS.spin_max, 0.9, 1.0, "",
              "Command at which the thrust saturates (fraction of the command range)"),
    ParamSpec("MOT_SPIN_MIN", _F, _IRIS.spin_min, 0.0, 0.3, "",
              "Command at which the thrust starts (fraction of the command range)"),
    ParamSpec("MOT_THST_EXPO", _F, _IRIS.thrust_expo, -1.0, 1.0, "",
              "Thrust curve: 0 linear, 1 thrust proportional to the command squared"),
    ParamSpec("MOT_THST_HOVER", _F, _IRIS.thrust_hover, 0.0, 0.6875, "",
              "Hover thrust as a fraction of the maximum; 0 = from SN_MASS_KG and the rotor model"),
    ParamSpec("SN_ARM_BX", _F, _IRIS.back_arm_x_m, 0.01, 5.0, "m",
              "Airframe model: back rotors behind the centre of mass"),
    ParamSpec("SN_ARM_BY", _F, _IRIS.back_arm_y_m, 0.01, 5.0, "m",
              "Airframe model: back rotors beside the centre of mass"),
    ParamSpec("SN_ARM_FX", _F, _IRIS.front_arm_x_m, 0.01, 5.0, "m",
              "Airframe model: front rotors ahead of the centre of mass"),
    ParamSpec("SN_ARM_FY", _F, _IRIS.front_arm_y_m, 0.01, 5.0, "m",
              "Airframe model: front rotors beside the centre of mass"),
    ParamSpec("SN_IXX", _F, _IRIS.inertia_kg_m2[0], 1e-5, 100.0, "kg m^2",
              "Airframe model: moment of inertia about body x (roll)"),
    ParamSpec("SN_IYY", _F, _IRIS.inertia_kg_m2[1], 1e-5, 100.0, "kg m^2",
              "Airframe model: moment of inertia about body y (pitch)"),
    ParamSpec("SN_IZZ", _F, _IRIS.inertia_kg_m2[2], 1e-5, 100.0, "kg m^2",
              "Airframe model: moment of inertia about body z (yaw)"),
    ParamSpec("SN_MASS_KG", _F, _IRIS.mass_kg, 0.05, 100.0, "kg", "Airframe model: take-off mass"),
    ParamSpec("SN_ROT_KM", _F, _IRIS.moment_constant_m, 0.0, 1.0, "m",
              "Airframe model: rotor drag torque per newton of thrust"),
    ParamSpec("SN_ROT_KT", _F, _IRIS.thrust_coefficient_n_per_rad2_s2, 1e-8, 1e-2,
              "N/(rad/s)^2", "Airframe model: rotor thrust = SN_ROT_KT * rotor speed^2"),
    ParamSpec("SN_ROT_WMAX", _F, _IRIS.max_rotor_speed_rad_s, 10.0, 10000.0, "rad/s",
              "Airframe model: rotor speed at full command"),
)

# The model's physics needs every value within its range (a zero mass or arm length breaks the
# mixer): each is clamped there when set (params module docstring: safe limits).
AIRFRAME_PARAM_SPECS = tuple(dataclasses.replace(spec, safe_min=spec.min_value,
                                                 safe_max=spec.max_value)
                             for spec in AIRFRAME_PARAM_SPECS)
AIRFRAME_PARAM_NAMES = frozenset(spec.name for spec in AIRFRAME_PARAM_SPECS)
