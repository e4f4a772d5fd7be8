"""DO_MOTOR_TEST and PREFLIGHT_REBOOT_SHUTDOWN on the in-process flight (``CoreFlight``): the motor
test spins the tested motor of the vehicle on the ground and stops at the timeout, is refused armed
(disarmed, ArduCopter's land detector says landed: its 'not landed' refusal cannot happen); a reboot starts the flight core again (EKF aligned anew, home set, STABILIZE,
disarmed) with the parameters as stored."""

from __future__ import annotations

from support.sim_flight import CoreFlight

from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import MotorTestRequest, StatusTextEvent
from scenenav.core.contracts import QuadXRotor


def _texts(core) -> list[str]:
    return [e.text for e in core.drain_events() if isinstance(e, StatusTextEvent)]


def test_motor_test_spins_the_motor_on_the_ground_then_stops_and_reboot_starts_again():
    f = CoreFlight(7, gps=True, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=3, EK3_SRC1_VELXY=3)
    c = f.core
    f.run(3.0, until=lambda: c.aligned)
    assert c.aligned
    _texts(c)
    assert c.motor_test(MotorTestRequest(1, 0, 12, 1.0, 1)).ok
    f.run(0.5)
    assert f.cmd[QuadXRotor.FRONT_RIGHT] > 0.1 and f.cmd[[1, 2, 3]].max() == 0.0
    assert c.telemetry().servo_pwm[QuadXRotor.FRONT_RIGHT] == 1120
    assert not c.arm(False).ok                                   # no arming during a test
    f.run(0.7)
    assert not f.cmd.any() and not c.motor_test_state.running
    texts = _texts(c)
    assert "starting motor test" in texts and "finished motor test" in texts

    assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok
    assert not c.motor_test(MotorTestRequest(1, 0, 12, 1.0, 1)).ok
    assert "Motor Test: vehicle armed" in _texts(c)
    assert c.disarm(False).ok
    c.params.set("RTL_ALT", 2500)
    c.reboot()
    assert not c.aligned and not c.armed and c.mode == CopterMode.STABILIZE
    assert c.params.get("RTL_ALT") == 2500
    f.run(20.0, until=lambda: c.aligned)
    assert c.aligned and c.telemetry().home_set
    f.close()
