"""DO_MOTOR_TEST's state machine (autopilot_bridge.motor_test), hand-checked against ArduCopter's
motor_test.cpp: throttle types, the PWM window, the timeout, motors in test order one after another."""

from __future__ import annotations

import numpy as np
import pytest

from autopilot_bridge.motor_test import QUAD_X_TEST_ORDER, MotorTest, command_from_pwm
from autopilot_bridge.vehicle_interface import MavSeverity, MotorTestRequest
from scenenav.core.contracts import QuadXRotor


def run(test: MotorTest, t: float, pilot_pwm: int = 0) -> np.ndarray:
    return test.output(t, pilot_pwm)


def test_quad_x_test_order_is_clockwise_from_front_right():
    assert QUAD_X_TEST_ORDER == (QuadXRotor.FRONT_RIGHT, QuadXRotor.BACK_RIGHT, QuadXRotor.BACK_LEFT,
                                 QuadXRotor.FRONT_LEFT)


def test_percent_throttle_spins_one_motor_until_the_timeout():
    test = MotorTest()
    test.start(MotorTestRequest(2, 0, 20, 3.0, 0), now_s=10.0)
    out = run(test, 10.5)
    assert out[QuadXRotor.BACK_RIGHT] == pytest.approx(0.2)      # 1000 + 1000 * 20 % = 1200 us
    assert np.count_nonzero(out) == 1
    assert test.running and run(test, 12.9)[QuadXRotor.BACK_RIGHT] > 0
    assert not run(test, 13.0).any() and not test.running
    assert test.texts == [(MavSeverity.INFO, "finished motor test")]


def test_pwm_outside_800_2200_and_percent_above_100_stop_the_test():
    for req in (MotorTestRequest(1, 1, 2300, 5.0, 1), MotorTestRequest(1, 1, 700, 5.0, 1),
                MotorTestRequest(1, 0, 101, 5.0, 1), MotorTestRequest(1, 7, 50, 5.0, 1)):
        test = MotorTest()
        test.start(req, 0.0)
        assert not run(test, 0.1).any() and not test.running, req


def test_pilot_throttle_passthrough_needs_rc_input():
    test = MotorTest()
    test.start(MotorTestRequest(1, 2, 0, 5.0, 1), 0.0)
    assert run(test, 0.1, pilot_pwm=1300)[QuadXRotor.FRONT_RIGHT] == pytest.approx(0.3)
    assert not run(test, 0.2, pilot_pwm=0).any() and not test.running   # no RC in: 0 us


def test_motor_count_runs_the_next_motors_after_half_a_timeout_at_minimum():
    test = MotorTest()
    test.start(MotorTestRequest(1, 1, 1100, 2.0, 3), 0.0)
    assert run(test, 1.0)[QuadXRotor.FRONT_RIGHT] == pytest.approx(0.1)
    assert not run(test, 2.5).any()                        # between motors: minimum output
    run(test, 3.0)                                         # 1.5 timeouts: motor 2 starts
    assert run(test, 3.5)[QuadXRotor.BACK_RIGHT] == pytest.approx(0.1)
    run(test, 6.0)
    assert run(test, 6.5)[QuadXRotor.BACK_LEFT] == pytest.approx(0.1)
    assert not run(test, 8.6).any() and not test.running   # the last motor ends the test


def test_timeout_is_capped_at_600_s_and_unknown_motor_spins_nothing():
    test = MotorTest()
    test.start(MotorTestRequest(9, 0, 10, 5000.0, 1), 0.0)
    assert not run(test, 599.0).any() and test.running
    run(test, 600.0)
    assert not test.running
    assert command_from_pwm(2200) == 1.0 and command_from_pwm(800) == 0.0
