"""Battery and power module (pure numpy): what the vehicle's voltage/current sensor reads.

The pack is ``cells`` LiPo cells in series. Its open-circuit voltage follows the state of charge along
a measured single-cell LiPo discharge curve, and the terminal voltage sags by ``I R`` under load
(one lumped internal resistance, no relaxation dynamics). The charge drawn is the integral of the
current. The current is electrical, from the rotor state (not the command, which the motors follow
with a lag): ``idle + max * mean_i((w_i / w_max)^2)``, i.e. proportional to the mean rotor thrust
fraction, the model the autopilot used before the battery moved here (``BATTERY_IDLE_A`` /
``BATTERY_MAX_A``). About 21 A in an Iris hover (ArduPilot's SITL default 1.5 kg quad: 22.7 A).

Sources:
* discharge curve: ArduPilot ``libraries/SITL/SIM_Battery.cpp`` ``soc_table`` (resting voltage per
  cell vs state of charge of a LiPo cell), the rows from 100 % down to 2 %;
* pack: 3S, 3300 mAh (ArduPilot's default ``BATT_CAPACITY``); resistance 0.01 ohm (``SIM_Frame``
  default model ``refBatRes``).

The battery never feeds back into the physics: thrust does not depend on the voltage, so the power
model cannot change the truth.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from sitl.config import BatteryConfig

logger = logging.getLogger(__name__)

# (state of charge, resting cell voltage V), ascending state of charge. ArduPilot SIM_Battery.cpp.
LIPO_CELL_CURVE: tuple[tuple[float, float], ...] = (
    (0.0200, 2.977), (0.0385, 3.091), (0.0769, 3.165), (0.1154, 3.218), (0.1538, 3.296),
    (0.1923, 3.379), (0.2308, 3.462), (0.2692, 3.503), (0.3077, 3.543), (0.3462, 3.588),
    (0.3846, 3.636), (0.4231, 3.679), (0.4615, 3.715), (0.5000, 3.742), (0.5385, 3.783),
    (0.5769, 3.801), (0.6154, 3.833), (0.6538, 3.854), (0.6923, 3.887), (0.7308, 3.908),
    (0.7692, 3.943), (0.8077, 3.987), (0.8462, 4.039), (0.8846, 4.071), (0.9231, 4.085),
    (0.9615, 4.112), (1.0000, 4.173),
)
_SOC = np.array([s for s, _ in LIPO_CELL_CURVE])
_CELL_V = np.array([v for _, v in LIPO_CELL_CURVE])
_SECONDS_PER_HOUR = 3600.0


def cell_open_circuit_voltage_v(charge_fraction: float) -> float:
    """Resting voltage of one LiPo cell at a state of charge in [0, 1] (clamped to the curve)."""
    return float(np.interp(charge_fraction, _SOC, _CELL_V))


@dataclass(frozen=True)
class PowerReading:
    """Terminal voltage and current of the pack (truth, before the power module's noise)."""

    voltage_v: float
    current_a: float


class BatteryModel:
    """The pack's charge and its terminal voltage for the current the rotors draw."""

    def __init__(self, cfg: BatteryConfig, max_rotor_speed_rad_s: float) -> None:
        self.cfg = cfg
        self._inv_max_speed = 1.0 / float(max_rotor_speed_rad_s)
        self.consumed_mah = (1.0 - cfg.initial_charge_fraction) * cfg.capacity_mah

    @property
    def charge_fraction(self) -> float:
        """State of charge, 0..1."""
        return max(0.0, 1.0 - self.consumed_mah / self.cfg.capacity_mah)

    def current_a(self, rotor_speeds_rad_s) -> float:
        """Electrical current for the rotor speeds (rad/s)."""
        fractions = [float(w) * self._inv_max_speed for w in rotor_speeds_rad_s]
        mean_sq = sum(f * f for f in fractions) / len(fractions) if fractions else 0.0
        return self.cfg.idle_current_a + self.cfg.max_current_a * mean_sq

    def step(self, rotor_speeds_rad_s, dt_s: float) -> PowerReading:
        """Draw the rotors' current for ``dt_s`` and return the terminal voltage and current."""
        current = self.current_a(rotor_speeds_rad_s)
        self.consumed_mah += current * dt_s * 1000.0 / _SECONDS_PER_HOUR
        ocv = self.cfg.cells * cell_open_circuit_voltage_v(self.charge_fraction)
        return PowerReading(max(0.0, ocv - current * self.cfg.internal_resistance_ohm), current)


class PowerModuleModel:
    """Analog voltage/current sensor: truth + white noise (drawn only when a noise is set)."""

    def __init__(self, cfg: BatteryConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self._rng = rng

    def sample(self, reading: PowerReading) -> PowerReading:
        cfg = self.cfg
        voltage, current = reading.voltage_v, reading.current_a
        if cfg.voltage_noise_std_v > 0.0:
            voltage += cfg.voltage_noise_std_v * float(self._rng.standard_normal())
        if cfg.current_noise_std_a > 0.0:
            current += cfg.current_noise_std_a * float(self._rng.standard_normal())
        return PowerReading(voltage, current)
