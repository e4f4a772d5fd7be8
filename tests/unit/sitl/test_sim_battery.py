"""Battery model: LiPo open-circuit voltage curve, charge drawn, sag under load, current from rotors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from scenenav.core.config import ConfigError
from sitl.battery import (
    BatteryModel,
    PowerModuleModel,
    PowerReading,
    cell_open_circuit_voltage_v,
)
from sitl.config import BatteryConfig
from sitl.vehicle import VehicleParams

MAX_SPEED = VehicleParams().max_rotor_speed_rad_s


def test_open_circuit_voltage_follows_the_lipo_curve():
    assert cell_open_circuit_voltage_v(1.0) == pytest.approx(4.173)
    assert cell_open_circuit_voltage_v(0.5) == pytest.approx(3.742)
    assert cell_open_circuit_voltage_v(0.0) == pytest.approx(2.977)        # clamped below the table
    socs = np.linspace(0.0, 1.0, 101)
    volts = [cell_open_circuit_voltage_v(s) for s in socs]
    assert all(b >= a for a, b in itertools.pairwise(volts))


def test_current_from_rotor_speeds_and_charge_drawn():
    battery = BatteryModel(BatteryConfig(), MAX_SPEED)
    assert battery.current_a(np.zeros(4)) == pytest.approx(0.5)
    assert battery.current_a(np.full(4, MAX_SPEED)) == pytest.approx(40.5)
    hover = VehicleParams().hover_rotor_speed_rad_s
    reading = battery.step(np.full(4, hover), 3600.0 / 10.0)        # a tenth of an hour
    assert reading.current_a == pytest.approx(0.5 + 40.0 * (hover / MAX_SPEED) ** 2)
    assert battery.consumed_mah == pytest.approx(reading.current_a * 100.0)
    ocv = 3 * cell_open_circuit_voltage_v(battery.charge_fraction)
    assert reading.voltage_v == pytest.approx(ocv - 0.01 * reading.current_a)


def test_power_module_noise_only_when_asked():
    truth = PowerReading(12.0, 10.0)
    rng = np.random.default_rng(0)
    assert PowerModuleModel(BatteryConfig(), rng).sample(truth) == truth
    assert rng.bit_generator.state == np.random.default_rng(0).bit_generator.state   # nothing drawn
    noisy = PowerModuleModel(BatteryConfig(voltage_noise_std_v=0.1, current_noise_std_a=0.5), rng)
    assert noisy.sample(truth) != truth


def test_config_range_checks():
    with pytest.raises(ConfigError, match="cells"):
        BatteryConfig(cells=0)
    with pytest.raises(ConfigError, match="initial_charge_fraction"):
        BatteryConfig(initial_charge_fraction=1.5)
