"""EKF and battery failsafes (autopilot_bridge.failsafe_checks), ArduCopter's rules."""

from __future__ import annotations

import math

from autopilot_bridge.failsafe import FailsafeAction, FailsafeKind
from autopilot_bridge.failsafe_checks import (
    BatteryFailsafe,
    BatteryLevel,
    BatterySettings,
    EkfCheck,
    EkfVariances,
    ekf_over_threshold,
)
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore

GOOD = EkfVariances(0.1, 0.1, 0.1)
BAD = EkfVariances(0.9, 0.9, 0.1)   # velocity and position over 0.8
TICK_S = 0.0025                    # 400 Hz control ticks


def test_over_threshold_needs_two_or_double_velocity():
    assert not ekf_over_threshold(EkfVariances(0.9, 0.1, 0.1), 0.8)
    assert ekf_over_threshold(EkfVariances(1.6, 0.1, 0.1), 0.8)
    assert ekf_over_threshold(EkfVariances(0.1, 0.9, 0.9), 0.8)
    assert not ekf_over_threshold(EkfVariances(math.nan, math.nan, 5.0), 0.8)


def run_ekf(check, variances, seconds, start_s=0.0, *, position_mode=True, action=1, thresh=0.8):
    events, t = [], start_s
    while t < start_s + seconds:
        events += check.update(t, True, position_mode, lambda: variances, thresh, action)
        t += TICK_S
    return events, t


def test_ekf_failsafe_after_one_second_of_bad_variances_then_clears():
    check = EkfCheck()
    events, t = run_ekf(check, BAD, 0.85)
    assert events == [] and not check.active
    events, t = run_ekf(check, BAD, 0.3, t)
    assert [(e.kind, e.action, e.text) for e in events] == [
        (FailsafeKind.EKF, FailsafeAction.LAND, "EKF variance")]
    events, t = run_ekf(check, GOOD, 0.85, t)
    assert events == [] and check.active
    events, _ = run_ekf(check, GOOD, 0.3, t)
    assert [e.action for e in events] == [FailsafeAction.CLEARED] and not check.active


def test_ekf_failsafe_actions():
    for action, position_mode, expected in [
            (0, True, FailsafeAction.REPORT), (1, True, FailsafeAction.LAND),
            (1, False, FailsafeAction.REPORT), (2, True, FailsafeAction.ALT_HOLD),
            (2, False, FailsafeAction.REPORT), (3, False, FailsafeAction.LAND)]:
        events, _ = run_ekf(EkfCheck(), BAD, 1.5, position_mode=position_mode, action=action)
        assert [e.action for e in events] == [expected], (action, position_mode)


def test_ekf_failsafe_off_when_thresh_zero_or_disarmed():
    assert run_ekf(EkfCheck(), BAD, 3.0, thresh=0.0)[0] == []
    check = EkfCheck()
    assert all(check.update(t * 0.1, False, True, lambda: BAD, 0.8, 1) == [] for t in range(40))


def test_battery_low_voltage_after_timer_then_critical_by_capacity():
    fs = BatteryFailsafe()
    s = BatterySettings(low_volt_v=10.5, low_timer_s=10.0, crt_mah=500.0, capacity_mah=3300.0,
                        low_action=2, crt_action=1)
    assert fs.update(0.0, True, 10.4, 100.0, s) == []
    assert fs.update(9.9, True, 10.4, 100.0, s) == []
    events = fs.update(10.0, True, 10.4, 100.0, s)
    assert [(e.kind, e.action, e.text) for e in events] == [
        (FailsafeKind.BATTERY, FailsafeAction.RTL, "Battery 1 is low 10.40V used 100 mAh")]
    assert fs.update(11.0, True, 10.4, 200.0, s) == []          # no repeat
    events = fs.update(12.0, True, 10.3, 2900.0, s)             # 400 mAh left < 500
    assert [e.action for e in events] == [FailsafeAction.LAND]
    assert events[0].text.startswith("Battery 1 is critical")
    assert fs.level == BatteryLevel.CRITICAL
    assert fs.update(13.0, True, 12.0, 2900.0, s) == []         # never clears


def test_battery_voltage_recovering_resets_the_timer_and_ground_only_reports():
    s = BatterySettings(low_volt_v=10.5, low_timer_s=10.0, low_action=1)
    fs = BatteryFailsafe()
    fs.update(0.0, True, 10.4, 0.0, s)
    fs.update(5.0, True, 11.0, 0.0, s)
    assert fs.update(12.0, True, 10.4, 0.0, s) == []
    events = BatteryFailsafe()
    grounded = events.update(0.0, False, 10.0, 0.0, BatterySettings(low_timer_s=0.0, low_action=1))
    assert [e.action for e in grounded] == [FailsafeAction.REPORT]
    assert BatteryFailsafe().update(0.0, True, math.nan, 0.0, s) == []


def test_battery_failsafe_actions_stored_except_terminate():
    params = ParameterStore(PARAM_SPECS)
    for value in (0, 1, 2, 3, 4, 6, 7):
        assert params.set("BATT_FS_LOW_ACT", value).ok and params.get("BATT_FS_LOW_ACT") == value
    refused = params.set("BATT_FS_CRT_ACT", 5)
    assert not refused.ok and params.get_int("BATT_FS_CRT_ACT") == 0 and refused.reason
