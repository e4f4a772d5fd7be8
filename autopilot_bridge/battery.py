"""Battery monitor: what the power module measured (``PowerSample`` on the bus, published by the
simulator), as ArduPilot's ``AP_BattMonitor_Analog`` reports it.

Voltage and current are the newest measurement; consumed charge is the measured current integrated
over the time between samples (``consumed_mah += current_a * dt_ms / 3600``, not across gaps of 2 s
or more, as ``AP_BattMonitor_Analog::read`` does); remaining % = 100 (BATT_CAPACITY - consumed) /
BATT_CAPACITY, clamped to [0, 100] and truncated. Before the first measurement everything is
unknown: NaN voltage and current (BATTERY_STATUS / SYS_STATUS then carry UINT16_MAX and -1) and
remaining -1, as ArduPilot reports a monitor without data.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scenenav.core.numeric import all_finite

MAX_INTEGRATION_GAP_S = 2.0     # AP_BattMonitor_Analog: no integration across longer gaps
MAH_PER_AMP_SECOND = 1000.0 / 3600.0


@dataclass(frozen=True)
class BatteryState:
    """The battery as the autopilot reports it (NaN / -1 = unknown)."""

    voltage_v: float = math.nan
    current_a: float = math.nan
    consumed_mah: float = math.nan
    remaining_pct: int = -1


class BatteryMonitor:
    """Integrates the power module's samples; see the module docstring."""

    def __init__(self) -> None:
        self._voltage_v = math.nan
        self._current_a = math.nan
        self._consumed_mah = 0.0
        self._last_t_s: float | None = None
        self.rejected = 0

    @property
    def has_data(self) -> bool:
        return self._last_t_s is not None

    def on_sample(self, t_s: float, voltage_v: float, current_a: float) -> None:
        """One measurement at simulated time ``t_s``; non-finite or out-of-order ones are counted
        and dropped."""
        if not all_finite(t_s, voltage_v, current_a) or (
                self._last_t_s is not None and t_s <= self._last_t_s):
            self.rejected += 1
            return
        if self._last_t_s is not None and t_s - self._last_t_s < MAX_INTEGRATION_GAP_S:
            self._consumed_mah += float(current_a) * (t_s - self._last_t_s) * MAH_PER_AMP_SECOND
        self._last_t_s = float(t_s)
        self._voltage_v = float(voltage_v)
        self._current_a = float(current_a)

    def state(self, capacity_mah: float) -> BatteryState:
        if self._last_t_s is None:
            return BatteryState()
        remaining = -1
        if capacity_mah > 0:
            # AP_BattMonitor_Backend::capacity_remaining_pct (truncated, as its uint8_t)
            pct = 100.0 * (capacity_mah - self._consumed_mah) / capacity_mah
            remaining = int(max(0.0, min(100.0, pct)))
        return BatteryState(self._voltage_v, self._current_a, self._consumed_mah, remaining)
