"""MAV_CMD_DO_MOTOR_TEST as ArduCopter runs it (``ArduCopter/motor_test.cpp``,
``AP_MotorsMatrix::output_test_seq``), and the flight core's part of it (``MotorTestMixin``).

Facts taken from ArduCopter 4.5:

* param1 motor in *test order* (1..4; quad X: 1 front right, 2 back right, 3 back left, 4 front left,
  clockwise from the front right), param2 throttle type, param3 throttle, param4 timeout s (at most
  600 s), param5 motor count (0 = 1: that many motors one after the other, each for the timeout,
  with half a timeout at minimum output between them).
* Throttle types: 0 percent (0..100 of MOT_PWM_MIN..MOT_PWM_MAX; above 100 stops the test),
  1 PWM, 2 the pilot's throttle channel (RC3 in), 3 compass calibration (a percentage: differs, no
  per-motor compass calibration here); any other stops the test. A PWM outside 800..2200 stops it.
  Those checks run while the test runs, so the command itself is ACCEPTED (as ArduCopter).
* Start: "starting motor test" (INFO); refused (FAILED) when the vehicle is not landed:
  CRITICAL "Motor Test: vehicle not landed". A command while a test runs restarts its timer with the
  new values. The end: "finished motor test" (INFO), the motors stop.
* A test-order number beyond the motors spins nothing (``output_test_seq`` ignores it).

Differs: ArduCopter checks only that the vehicle is landed (and the board, RC calibration and the
safety switch, which do not exist here); here a test also needs the vehicle disarmed ("Motor Test:
vehicle armed"), and arming is refused while one runs ("Arm: Motor test running").

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from autopilot_bridge.vehicle_interface import MavSeverity, MotorTestRequest, Outcome
from scenenav.core.contracts import QuadXRotor

MOTOR_TEST_PWM_MIN = 800         # ArduCopter motor_test.cpp: the PWM a test may output
MOTOR_TEST_PWM_MAX = 2200
MOTOR_TEST_TIMEOUT_MAX_S = 600.0
MOT_PWM_MIN_US = 1000            # MOT_PWM_MIN / MOT_PWM_MAX defaults (core_telemetry's PWM scale)
MOT_PWM_MAX_US = 2000
# AP_MotorsMatrix quad X: test order 1..4 -> motor (QuadXRotor index = ArduPilot motor number - 1)
QUAD_X_TEST_ORDER = (QuadXRotor.FRONT_RIGHT, QuadXRotor.BACK_RIGHT, QuadXRotor.BACK_LEFT,
                     QuadXRotor.FRONT_LEFT)


class MotorTestThrottle(IntEnum):
    """MOTOR_TEST_THROTTLE_TYPE (DO_MOTOR_TEST param2)."""

    PERCENT = 0
    PWM = 1
    PILOT = 2
    COMPASS_CAL = 3


def command_from_pwm(pwm: int) -> float:
    """Motor command 0..1 on the MOT_PWM_MIN..MOT_PWM_MAX scale."""
    return min(max((pwm - MOT_PWM_MIN_US) / (MOT_PWM_MAX_US - MOT_PWM_MIN_US), 0.0), 1.0)


class MotorTest:
    """The test's state machine on the caller's clock (simulated seconds)."""

    def __init__(self) -> None:
        self.running = False
        self._req = MotorTestRequest(0, 0, 0, 0.0, 1)
        self._seq = 0
        self._count = 0
        self._start_s = 0.0
        self._timeout_s = 0.0
        self.texts: list[tuple[MavSeverity, str]] = []

    def start(self, req: MotorTestRequest, now_s: float) -> None:
        """(Re)start with ``req``; the caller has done the start checks."""
        self.running = True
        self._req = req
        self._seq = req.motor_seq
        self._count = max(req.motor_count, 1)
        self._start_s = now_s
        self._timeout_s = min(req.timeout_s, MOTOR_TEST_TIMEOUT_MAX_S)

    def stop(self) -> None:
        if self.running:
            self.running = False
            self.texts.append((MavSeverity.INFO, "finished motor test"))

    def output(self, now_s: float, pilot_throttle_pwm: int) -> np.ndarray:
        """The four motor commands for this tick (zeros between motors and once stopped)."""
        commands = np.zeros(len(QuadXRotor))
        if not self.running:
            return commands
        elapsed = now_s - self._start_s
        if elapsed >= self._timeout_s:
            if self._count > 1:
                if elapsed >= 1.5 * self._timeout_s:       # next motor after half a timeout at minimum
                    self._seq += 1
                    self._count -= 1
                    self._start_s = now_s
                return commands
            self.stop()
            return commands
        pwm = self._pwm(pilot_throttle_pwm)
        if pwm is None or not MOTOR_TEST_PWM_MIN <= pwm <= MOTOR_TEST_PWM_MAX:
            self.stop()
            return commands
        if 1 <= self._seq <= len(QUAD_X_TEST_ORDER):
            commands[QUAD_X_TEST_ORDER[self._seq - 1]] = command_from_pwm(pwm)
        return commands

    def _pwm(self, pilot_throttle_pwm: int) -> int | None:
        kind, value = self._req.throttle_type, self._req.throttle_value
        if kind in (MotorTestThrottle.PERCENT, MotorTestThrottle.COMPASS_CAL):
            if value > 100:
                return 0
            return int(MOT_PWM_MIN_US + (MOT_PWM_MAX_US - MOT_PWM_MIN_US) * value / 100.0)
        if kind == MotorTestThrottle.PWM:
            return value
        if kind == MotorTestThrottle.PILOT:
            return pilot_throttle_pwm
        return None


class MotorTestMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_motor_test(self) -> None:
        self.motor_test_state = MotorTest()

    def motor_test(self, req: MotorTestRequest) -> Outcome:
        """DO_MOTOR_TEST (Vehicle protocol)."""
        test = self.motor_test_state
        if not test.running:
            self._announce(MavSeverity.INFO, "starting motor test")
            if self._armed:
                return self._motor_test_refused("Motor Test: vehicle armed")
            if not self.fc.landed:
                return self._motor_test_refused("Motor Test: vehicle not landed")
        test.start(req, self._now_s)
        self._tel = None
        return Outcome(True)

    def _motor_test_refused(self, text: str) -> Outcome:
        self._announce(MavSeverity.CRITICAL, text)
        return Outcome(False)       # no reason: the text above is the answer (ArduCopter's CRITICAL)

    def _motor_test_output(self) -> np.ndarray:
        test = self.motor_test_state
        out = test.output(self._now_s, self._pilot_throttle_pwm())
        for severity, text in test.texts:
            self._announce(severity, text)
        test.texts.clear()
        return out

    def _pilot_throttle_pwm(self) -> int:
        """RC input on RCMAP_THROTTLE (0 without one), as ``channel_throttle->get_radio_in()``."""
        channels = self.rc_channels()
        index = self.params.get_int("RCMAP_THROTTLE") - 1
        return int(channels[index]) if 0 <= index < len(channels) else 0
