"""EKF and battery failsafes of the flight core, as ArduCopter 4.5 runs them (pure: no zenoh, no
pymavlink). The flight core calls both once per control tick with simulated time, next to
``failsafe.FailsafeMonitor``, and applies the returned :class:`~autopilot_bridge.failsafe.FailsafeEvent` s
the same way (mode change, STATUSTEXT).

EKF failsafe (``ArduCopter/ekf_check.cpp``, ``events.cpp`` ``failsafe_ekf_event``):

* off when ``FS_EKF_THRESH`` <= 0 (the flight core passes 0 with external navigation as the
  position source: the vision failsafe owns that case); evaluated while armed (ArduCopter: also on the ground; no
  action is taken there, as here);
* the variances are the EKF_STATUS_REPORT ones (test ratios, 1 = at the innovation gate): the
  estimate is bad when two of compass, velocity and position are at or above the threshold,
  or velocity is at or above twice the threshold (``ekf_over_threshold``);
* bad for ``EKF_CHECK_ITERATIONS_MAX`` = 10 checks at 10 Hz (1 s) -> failsafe; the counter counts
  down one per good check and the failsafe clears at zero;
* action by ``FS_EKF_ACTION``: 0 report only, 1 LAND when the mode needs a position estimate,
  2 ALT_HOLD when the mode needs one, 3 LAND from every mode; the texts are ArduCopter's
  "EKF variance" (CRITICAL) and "EKF Failsafe Cleared".

Battery failsafe (``AP_BattMonitor::check_failsafes``, ``ArduCopter/events.cpp``
``handle_battery_failsafe``):

* low when the voltage stays below ``BATT_LOW_VOLT`` for ``BATT_LOW_TIMER`` seconds, or when the
  remaining capacity (``BATT_CAPACITY`` - consumed) falls below ``BATT_LOW_MAH``; critical
  likewise with ``BATT_CRT_VOLT`` / ``BATT_CRT_MAH`` (a threshold of 0 is off);
* a failsafe never clears and only escalates (low -> critical), as ArduPilot's;
* action by ``BATT_FS_LOW_ACT`` / ``BATT_FS_CRT_ACT``: 0 warn only, 1 LAND, 2 RTL, 3 SmartRTL or
  RTL (RTL here), 4 SmartRTL or LAND (LAND here), 6 the mission's landing sequence (AUTO_RTL,
  ``FlightCore.jump_to_landing_sequence``) or, without one, "Trying RTL Mode" and RTL,
  7 BRAKE or LAND (LAND here); 5 (terminate) is refused by the parameter store;
* on the ground nothing is done (ArduCopter disarms a landed vehicle); the text is ArduPilot's
  "Battery 1 is low 10.40V used 2500 mAh" (CRITICAL).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Callable

from autopilot_bridge.failsafe import FailsafeAction, FailsafeEvent, FailsafeKind
from autopilot_bridge.vehicle_interface import MavSeverity

EKF_CHECK_RATE_HZ = 10.0          # ekf_check runs at 10 Hz (ArduCopter scheduler table)
EKF_CHECK_ITERATIONS_MAX = 10     # ekf_check.cpp: 1 s of bad variances is a failure


class EkfFailsafeAction(IntEnum):
    """FS_EKF_ACTION (ArduCopter 4.5)."""

    REPORT_ONLY = 0
    LAND = 1
    ALT_HOLD = 2
    LAND_EVEN_STABILIZE = 3


class BatteryFailsafeAction(IntEnum):
    """BATT_FS_LOW_ACT / BATT_FS_CRT_ACT (ArduCopter 4.5)."""

    NONE = 0
    LAND = 1
    RTL = 2
    SMARTRTL_OR_RTL = 3
    SMARTRTL_OR_LAND = 4
    TERMINATE = 5                 # refused by the parameter store: no flight termination here
    AUTO_DO_LAND_START_OR_RTL = 6
    BRAKE_OR_LAND = 7


class BatteryLevel(IntEnum):
    OK = 0
    LOW = 1
    CRITICAL = 2


_BATTERY_ACTIONS: dict[BatteryFailsafeAction, FailsafeAction] = {
    BatteryFailsafeAction.LAND: FailsafeAction.LAND,
    BatteryFailsafeAction.RTL: FailsafeAction.RTL,
    BatteryFailsafeAction.SMARTRTL_OR_RTL: FailsafeAction.RTL,
    BatteryFailsafeAction.SMARTRTL_OR_LAND: FailsafeAction.LAND,
    BatteryFailsafeAction.AUTO_DO_LAND_START_OR_RTL: FailsafeAction.LAND_START_OR_RTL,
    BatteryFailsafeAction.BRAKE_OR_LAND: FailsafeAction.LAND,
}


@dataclass(frozen=True)
class EkfVariances:
    """EKF_STATUS_REPORT test ratios (NaN = unknown, counted as fine)."""

    velocity: float
    position_horiz: float
    compass: float


def ekf_over_threshold(v: EkfVariances, thresh: float) -> bool:
    """ArduCopter's ``ekf_over_threshold``: two of compass, velocity, position over, or velocity
    over twice the threshold."""
    def over(x: float, limit: float) -> bool:
        return math.isfinite(x) and x >= limit
    count = 0
    if over(v.compass, thresh):
        count += 1
    if over(v.velocity, 2.0 * thresh):
        count += 2
    elif over(v.velocity, thresh):
        count += 1
    if over(v.position_horiz, thresh):
        count += 1
    return count >= 2


class EkfCheck:
    """The EKF failsafe state machine (see the module docstring)."""

    def __init__(self) -> None:
        self._fail_count = 0
        self._active = False
        self._next_check_s: float | None = None

    @property
    def active(self) -> bool:
        return self._active

    def reset(self) -> None:
        self._fail_count = 0
        self._active = False
        self._next_check_s = None

    def update(self, now_s: float, armed: bool, position_mode: bool,
               variances: Callable[[], EkfVariances], thresh: float,
               action: int) -> list[FailsafeEvent]:
        """One control tick; ``variances`` is called only when a 10 Hz check is due."""
        if not armed or thresh <= 0.0:
            self.reset()
            return []
        if self._next_check_s is not None and now_s < self._next_check_s:
            return []
        self._next_check_s = now_s + 1.0 / EKF_CHECK_RATE_HZ
        if ekf_over_threshold(variances(), thresh):
            self._fail_count = min(self._fail_count + 1, EKF_CHECK_ITERATIONS_MAX)
        else:
            self._fail_count = max(self._fail_count - 1, 0)
        if not self._active and self._fail_count >= EKF_CHECK_ITERATIONS_MAX:
            self._active = True
            return [FailsafeEvent(FailsafeKind.EKF, self._action(action, position_mode),
                                  MavSeverity.CRITICAL, "EKF variance")]
        if self._active and self._fail_count == 0:
            self._active = False
            return [FailsafeEvent(FailsafeKind.EKF, FailsafeAction.CLEARED, MavSeverity.INFO,
                                  "EKF Failsafe Cleared")]
        return []

    @staticmethod
    def _action(value: int, position_mode: bool) -> FailsafeAction:
        try:
            setting = EkfFailsafeAction(int(value))
        except ValueError:
            setting = EkfFailsafeAction.LAND
        if setting == EkfFailsafeAction.LAND_EVEN_STABILIZE:
            return FailsafeAction.LAND
        if setting == EkfFailsafeAction.REPORT_ONLY or not position_mode:
            return FailsafeAction.REPORT
        return FailsafeAction.ALT_HOLD if setting == EkfFailsafeAction.ALT_HOLD else FailsafeAction.LAND


@dataclass(frozen=True)
class BatterySettings:
    """The BATT_* parameters of the battery failsafe (0 = that threshold is off)."""

    low_volt_v: float = 10.5          # BATT_LOW_VOLT
    low_timer_s: float = 10.0         # BATT_LOW_TIMER
    low_mah: float = 0.0              # BATT_LOW_MAH
    crt_volt_v: float = 0.0           # BATT_CRT_VOLT
    crt_mah: float = 0.0              # BATT_CRT_MAH
    capacity_mah: float = 3300.0      # BATT_CAPACITY
    low_action: int = 0               # BATT_FS_LOW_ACT
    crt_action: int = 0               # BATT_FS_CRT_ACT


class BatteryFailsafe:
    """Low / critical battery detection and action (see the module docstring)."""

    def __init__(self) -> None:
        self._level = BatteryLevel.OK
        self._low_since_s: float | None = None
        self._crt_since_s: float | None = None

    @property
    def level(self) -> BatteryLevel:
        return self._level

    def update(self, now_s: float, flying: bool, voltage_v: float, consumed_mah: float,
               s: BatterySettings) -> list[FailsafeEvent]:
        if not math.isfinite(voltage_v):
            return []
        remaining = s.capacity_mah - consumed_mah if math.isfinite(consumed_mah) else math.inf
        self._crt_since_s = self._since(self._crt_since_s, now_s, 0.0 < voltage_v < s.crt_volt_v)
        self._low_since_s = self._since(self._low_since_s, now_s, 0.0 < voltage_v < s.low_volt_v)
        critical = ((self._crt_since_s is not None and now_s - self._crt_since_s >= s.low_timer_s)
                    or (s.crt_mah > 0.0 and remaining < s.crt_mah))
        low = ((self._low_since_s is not None and now_s - self._low_since_s >= s.low_timer_s)
               or (s.low_mah > 0.0 and remaining < s.low_mah))
        level = BatteryLevel.CRITICAL if critical else BatteryLevel.LOW if low else BatteryLevel.OK
        if level <= self._level:
            return []
        self._level = level
        value = s.crt_action if level == BatteryLevel.CRITICAL else s.low_action
        try:
            setting = BatteryFailsafeAction(int(value))
        except ValueError:
            setting = BatteryFailsafeAction.NONE
        action = _BATTERY_ACTIONS.get(setting, FailsafeAction.REPORT) if flying else FailsafeAction.REPORT
        word = "critical" if level == BatteryLevel.CRITICAL else "low"
        used = consumed_mah if math.isfinite(consumed_mah) else 0.0
        return [FailsafeEvent(FailsafeKind.BATTERY, action, MavSeverity.CRITICAL,
                              f"Battery 1 is {word} {voltage_v:.2f}V used {used:.0f} mAh")]

    @staticmethod
    def _since(since_s: float | None, now_s: float, below: bool) -> float | None:
        if not below:
            return None
        return now_s if since_s is None else since_s
