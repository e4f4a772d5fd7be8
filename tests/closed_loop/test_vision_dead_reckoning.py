"""The vision failsafe with SN_VIS_DR_MAX on the in-process flight (``CoreFlight``: the flight core on
the simulator's core, GPS off, EK3_SRC1_POSXY 6, vision fixes from truth + 0.7 m noise every 0.1 s).

The vehicle cruises north in GUIDED towards a point 600 m away; the fixes stop (ground that cannot be
matched). With SN_VIS_DR_MAX 0 it holds at SN_VIS_TIMEOUT and lands; with SN_VIS_DR_MAX 8 m it flies
on towards the point on dead reckoning (announced) until the EKF's horizontal 1-sigma passes 8 m, and
the fixes' return during it ends the dead reckoning without any stop. Truth is used only in the
assertions."""

from __future__ import annotations

import math

import numpy as np
from support.sim_flight import CoreFlight, vision_cruise

from autopilot_bridge.failsafe import VisionFailsafeState


def _cruise(dr_max_m: float, seed: int = 6) -> CoreFlight:
    """Take off to 20 m on fixes and cruise north at WPNAV_SPEED 10 m/s for 15 s; fixes still on."""
    return vision_cruise(seed, SN_VIS_DR_MAX=dr_max_m)


def _speed(f: CoreFlight) -> float:
    return math.hypot(float(f.v[0]), float(f.v[1]))


def test_without_sn_vis_dr_max_the_vehicle_holds_at_the_timeout_then_lands():
    f = _cruise(0.0)
    c = f.core
    f.vision = False
    f.run(6.0)                      # 3 s timeout + the stop
    assert c.failsafe.vision_state == VisionFailsafeState.HOLD and _speed(f) < 2.0
    f.run(6.0)
    assert c.failsafe.vision_state == VisionFailsafeState.LAND
    f.close()


def test_with_sn_vis_dr_max_the_vehicle_flies_on_until_the_estimate_is_too_uncertain():
    f = _cruise(8.0)
    c = f.core
    f.vision = False
    start = np.array(f.p[:2])
    f.run(6.0)
    assert c.failsafe.vision_state == VisionFailsafeState.DEAD_RECKONING, c.failsafe.vision_state
    assert _speed(f) > 7.0 and not c.failsafe.any_active
    # flies on while the 1-sigma is within 8 m, then holds
    assert f.run(120.0, until=lambda: c.failsafe.vision_state == VisionFailsafeState.HOLD)
    sigma = float(max(c.estimate().position_std_m[:2]))
    assert 8.0 < sigma < 9.0, sigma
    flown = float(np.linalg.norm(np.array(f.p[:2]) - start))
    assert flown > 60.0, flown       # at 10 m/s, at least the 6 s above
    err = float(np.linalg.norm(np.asarray(c.estimate().position_enu_m[:2]) - f.p[:2]))
    assert err < 4.0 * sigma, (err, sigma)      # the uncertainty it reports is not wildly optimistic
    f.close()


def test_fixes_back_during_dead_reckoning_end_it_without_a_stop():
    f = _cruise(8.0)
    c = f.core
    f.vision = False
    f.run(5.0)
    assert c.failsafe.vision_state == VisionFailsafeState.DEAD_RECKONING
    f.vision = True
    f.run(1.0)
    assert c.failsafe.vision_state == VisionFailsafeState.NORMAL
    assert _speed(f) > 7.0 and c.stats["failsafe_vision_hold"] == 0
    f.close()
