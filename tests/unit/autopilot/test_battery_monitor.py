"""Battery reporting from the power module's measurements (``PowerSample``), as AP_BattMonitor:
unknown before the first sample, consumed charge integrated from the measured current."""

from __future__ import annotations

import math

import pytest

from autopilot_bridge import telemetry
from autopilot_bridge.battery import BatteryMonitor
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore

UINT16_MAX = 65535


def _encoded(core: FlightCore):
    ctx = telemetry.EncodeContext(mission_item_count=0, battery_monitor=4)
    tel = core.telemetry()
    return telemetry.encode_sys_status(tel, ctx), telemetry.encode_battery_status(tel, ctx)


def test_without_power_samples_the_battery_is_unknown_as_in_ardupilot():
    core = FlightCore(ParameterStore(PARAM_SPECS))
    sys_status, battery = _encoded(core)
    assert sys_status.voltage_battery == UINT16_MAX
    assert sys_status.current_battery == -1 and sys_status.battery_remaining == -1
    assert battery.voltages[0] == UINT16_MAX
    assert battery.current_battery == -1 and battery.battery_remaining == -1


def test_measured_voltage_current_and_consumed_charge_are_reported():
    core = FlightCore(ParameterStore(PARAM_SPECS, defaults={"BATT_CAPACITY": 1000}))
    for k in range(360):                       # 35.9 s at 10 Hz, 10 A
        core.on_power(k * 0.1, 12.3, 10.0)
    state = core.battery.state(1000.0)
    assert state.consumed_mah == pytest.approx(10.0 * 35.9 / 3.6)      # 99.7 mAh
    assert state.remaining_pct == 90
    sys_status, battery = _encoded(core)
    assert sys_status.voltage_battery == 12300 and sys_status.current_battery == 1000
    assert sys_status.battery_remaining == 90
    assert battery.voltages[0] == 12300 and battery.battery_remaining == 90


def test_gaps_and_bad_samples_are_not_integrated():
    m = BatteryMonitor()
    m.on_sample(0.0, 12.0, 5.0)
    m.on_sample(10.0, 12.0, 5.0)               # 10 s gap: no charge counted (as AP_BattMonitor)
    m.on_sample(10.5, math.nan, 5.0)           # dropped
    m.on_sample(10.0, 12.0, 5.0)               # not newer: dropped
    assert m.state(3300.0).consumed_mah == 0.0 and m.rejected == 2
    m.on_sample(11.0, 11.9, 36.0)
    assert m.state(3300.0).consumed_mah == pytest.approx(36.0 * 1.0 / 3.6)
    assert m.state(3300.0).voltage_v == 11.9
    assert m.state(0.0).remaining_pct == -1    # no capacity: remaining unknown
