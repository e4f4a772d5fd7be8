"""ArduPilot EKF3's final in-flight yaw alignment (``FlightCoreConfig.inflight_yaw_reset_height_m``,
EKF3_MAG_FINAL_RESET_ALT 2.5 m): on the ground the compass reads a local magnetic anomaly (here 15
degrees at the ground from steel under the take-off pad, decaying as ``(1 / (1 + h))^3`` with height:
the simulator's ``sim.compass.anomaly_*`` law with a 1 m source depth); the filter aligns with it at
rest. Climbing out of it, the compass
soon reads true, but the filter, sure of its heading, rejects it until its rejection timeout (5 s
of flight on a wrong heading). The in-flight alignment resets the heading to the compass at 2.5 m,
once per flight. Truth is used only in the assertions."""

from __future__ import annotations

import math

from support.sim_flight import CoreFlight

from scenenav.core.rotations import heading_from_quat

ANOMALY_RAD = math.radians(15.0)


def _fly_to_8_m(reset_height_m: float) -> tuple[list[float], CoreFlight]:
    """Heading errors (deg, estimate - truth) sampled every 0.1 s from 3 m to 8 m of the climb."""
    f = CoreFlight(4, gps=False, core={"inflight_yaw_reset_height_m": reset_height_m},
                   EK3_SRC1_POSXY=6, SN_VIS_TIMEOUT=0, SN_VIS_MIN_ALT=0)
    f.compass_error = lambda h: ANOMALY_RAD * (1.0 / (1.0 + max(h, 0.0))) ** 3
    f.vision = True
    c = f.core
    c.set_vision_available(True)
    f.arm_in_guided()
    assert c.takeoff(20.0).ok
    errors = []
    while f.p[2] < 8.0:
        f.run(0.1)
        assert f.t < 60.0, "the climb did not reach 8 m"
        if f.p[2] > 3.0:
            est = heading_from_quat(tuple(c.estimate().q_wxyz))
            true = heading_from_quat(tuple(f.plant.q))
            errors.append(math.degrees(math.remainder(est - true, math.tau)))
    f.close()
    return errors, f


def test_the_heading_is_realigned_to_the_compass_at_2_5_m():
    errors, f = _fly_to_8_m(2.5)
    assert f.core.stats["inflight_yaw_alignments"] == 1
    assert max(abs(e) for e in errors) < 3.0, errors          # 15 deg x (1 / 3.5)^3 = 0.35 deg at the reset


def test_without_it_the_ground_heading_is_kept_into_the_climb():
    errors, f = _fly_to_8_m(0.0)
    assert f.core.stats["inflight_yaw_alignments"] == 0
    assert abs(errors[0]) > 10.0, errors
