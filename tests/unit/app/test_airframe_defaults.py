"""The autopilot's default airframe model is the simulator's Iris, bit for bit (both cite PX4's
iris.sdf); the parameter store's defaults build that same model."""

from __future__ import annotations

from autopilot_bridge.airframe import Airframe
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from sitl.vehicle import VehicleParams


def test_autopilot_airframe_defaults_equal_the_simulated_vehicle():
    a, v = Airframe(), VehicleParams()
    assert a.mass_kg == v.mass_kg
    assert a.inertia_kg_m2 == v.inertia_kg_m2
    assert a.rotor_positions_flu_m == v.rotor_positions_flu_m
    assert [int(s) for s in a.rotor_spins] == [int(d) for d in v.rotor_directions]
    assert a.thrust_coefficient_n_per_rad2_s2 == v.motor_constant_n_per_rad2_s2
    assert a.moment_constant_m == v.moment_constant_m
    assert a.max_rotor_speed_rad_s == v.max_rotor_speed_rad_s
    assert a.gravity_m_s2 == v.gravity_m_s2
    assert a.max_thrust_n == v.max_thrust_n
    assert a.thrust_mass_kg == v.mass_kg
    assert a.hover_thrust_fraction == v.mass_kg * v.gravity_m_s2 / v.max_thrust_n
    # Rotor-speed commands: thrust ~ command^2 over the whole range.
    assert (a.thrust_expo, a.spin_min, a.spin_max) == (1.0, 0.0, 1.0)


def test_parameter_defaults_build_the_default_airframe():
    assert Airframe.from_params(ParameterStore(PARAM_SPECS)) == Airframe()
