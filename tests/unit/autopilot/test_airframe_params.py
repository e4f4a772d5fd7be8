"""The airframe model comes from the parameters, also when they change in flight (PARAM_SET)."""

from __future__ import annotations

import numpy as np
import pytest

from autopilot_bridge.airframe import Airframe
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.mixer import QuadXMixer
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from scenenav.core.config import ConfigError


def test_parameter_changes_rebuild_controller_and_mixer():
    store = ParameterStore(PARAM_SPECS)
    core = FlightCore(store)
    g = core.airframe.gravity_m_s2
    assert core.fc.hover_thrust_n == pytest.approx(1.5 * g)
    assert store.set("SN_MASS_KG", 2.0).ok
    assert core.airframe.mass_kg == 2.0 and core.fc.hover_thrust_n == pytest.approx(2.0 * g)
    assert core.mixer.hover_command > QuadXMixer().hover_command
    # MOT_THST_HOVER overrides the mass for the thrust scale (ArduPilot's hover throttle)
    assert store.set("MOT_THST_HOVER", 0.5).ok
    assert core.airframe.hover_thrust_fraction == pytest.approx(0.5)
    assert core.fc.hover_thrust_n == pytest.approx(0.5 * core.airframe.max_thrust_n)
    result = store.set("SN_MASS_KG", -1.0)                # unsafe: clamped to the model's limit
    assert result.ok and "clamped to 0.05" in result.reason
    assert core.airframe.mass_kg == pytest.approx(0.05)


def test_thrust_curve_and_output_range():
    a = Airframe(thrust_expo=0.65, spin_min=0.15, spin_max=0.95)
    m = QuadXMixer(a)
    t_max = m.rotor_thrust_limits_n[1]
    assert m.command_for_thrust(0.0) == pytest.approx(0.15)
    assert m.command_for_thrust(t_max) == pytest.approx(0.95)
    thrusts = np.linspace(0.0, t_max, 11)
    commands = [m.command_for_thrust(t) for t in thrusts]
    assert all(b > c for b, c in zip(commands[1:], commands, strict=False))
    # ArduPilot's curve: thrust fraction = (1 - e) x + e x^2 of the linear command x
    x = (m.command_for_thrust(0.3 * t_max) - 0.15) / 0.8
    assert (1 - 0.65) * x + 0.65 * x * x == pytest.approx(0.3)
    lin = QuadXMixer(Airframe(thrust_expo=0.0))
    assert lin.command_for_thrust(0.3 * t_max) == pytest.approx(0.3)
    with pytest.raises(ConfigError):
        Airframe(spin_min=0.5, spin_max=0.4)


def test_ek3_gbias_p_nse_sets_the_filters_gyro_bias_noise_at_start_and_in_flight():
    from autopilot_bridge.config import EkfConfig
    from autopilot_bridge.param_binding import gyro_bias_noise_density
    store = ParameterStore(PARAM_SPECS)
    core = FlightCore(store)
    default = EkfConfig().gyro_bias_noise_rad_s2_per_rt_hz
    assert core.nav._cfg.gyro_bias_noise_rad_s2_per_rt_hz == pytest.approx(default)
    assert store.set("EK3_GBIAS_P_NSE", 1.0e-4).ok
    assert core.nav._cfg.gyro_bias_noise_rad_s2_per_rt_hz == pytest.approx(0.1 * default)
    assert core.nav._q_density[9] == pytest.approx(gyro_bias_noise_density(1.0e-4) ** 2)
    store2 = ParameterStore(PARAM_SPECS)
    assert store2.set("EK3_GBIAS_P_NSE", 1.0e-5).ok
    assert FlightCore(store2).nav._cfg.gyro_bias_noise_rad_s2_per_rt_hz == pytest.approx(0.01 * default)


def test_ek3_acc_p_nse_sets_the_filters_velocity_process_noise_at_start_and_in_flight():
    from autopilot_bridge.config import EkfConfig
    store = ParameterStore(PARAM_SPECS)
    core = FlightCore(store)
    # the default reproduces the filter's own default exactly (published flights stay bit-identical)
    assert core.nav._cfg.accel_noise_m_s2_per_rt_hz == EkfConfig().accel_noise_m_s2_per_rt_hz
    assert store.set("EK3_ACC_P_NSE", 1.0).ok
    assert core.nav._q_density[3:6].tolist() == pytest.approx([0.1 ** 2] * 3)   # 1.0 x sqrt(0.01 s)
    store2 = ParameterStore(PARAM_SPECS)
    assert store2.set("EK3_ACC_P_NSE", 0.35).ok                                 # ArduPilot's default
    assert FlightCore(store2).nav._cfg.accel_noise_m_s2_per_rt_hz == pytest.approx(0.035)


def test_ek3_pos_i_gate_sets_the_filters_position_gate_at_start_and_in_flight():
    from autopilot_bridge.config import EkfConfig
    store = ParameterStore(PARAM_SPECS)
    core = FlightCore(store)
    assert core.nav._cfg.position_gate_sd == EkfConfig().position_gate_sd == 5.0   # 500 = 5 SD
    assert store.set("EK3_POS_I_GATE", 300).ok
    assert core.nav._cfg.position_gate_sd == pytest.approx(3.0)
    store2 = ParameterStore(PARAM_SPECS)
    assert store2.set("EK3_POS_I_GATE", 250).ok
    assert FlightCore(store2).nav._cfg.position_gate_sd == pytest.approx(2.5)
    low = store.set("EK3_POS_I_GATE", 50)                # below one SD: clamped to the safe minimum
    assert low.ok and "clamped to 100" in low.reason and core.nav._cfg.position_gate_sd == pytest.approx(1.0)


def test_viso_pos_m_nse_sets_the_filters_vision_noise_floor_at_start_and_in_flight():
    store = ParameterStore(PARAM_SPECS)
    core = FlightCore(store)
    assert core.nav._vision_floor_m == pytest.approx(0.2)          # ArduPilot's default, under the 0.3 m floor
    assert store.set("VISO_POS_M_NSE", 2.0).ok
    assert core.nav._vision_floor_m == pytest.approx(2.0)
    store2 = ParameterStore(PARAM_SPECS)
    assert store2.set("VISO_POS_M_NSE", 1.5).ok
    assert FlightCore(store2).nav._vision_floor_m == pytest.approx(1.5)
