"""SN_VIS_MAX_SD on the in-process flight (``CoreFlight``: the flight core on the simulator's core,
GPS off, EK3_SRC1_POSXY 6, fixes from truth + 0.7 m noise every 0.1 s).

Cruising north on good fixes, the fixes turn into a consistent false lock 150 m east published with
a covariance as wide as a search area (1-sigma 79 m, what perception publishes for an ambiguous
match). Each fix passes the EKF's gate and moves the estimate a little; at ten a second they walk it
away while the filter's own 1-sigma stays small, and the vision failsafe never hears of it. With
SN_VIS_MAX_SD below their width one of them is fused every 5 s (the others only tell the vision
failsafe that perception is matching): the estimate dead-reckons, nearly unmoved by them. Truth is
used only in the assertions."""

from __future__ import annotations

import numpy as np
from support.sim_flight import CoreFlight, vision_cruise

from autopilot_bridge.failsafe import VisionFailsafeState

FALSE_LOCK_OFFSET_M = np.array([150.0, 0.0])
WIDE_COV_M2 = np.eye(2) * 79.0 ** 2


def _false_lock_after_cruise(max_sd_m: float) -> CoreFlight:
    f = vision_cruise(6, SN_VIS_DR_MAX=8, SN_VIS_MAX_SD=max_sd_m, SN_VIS_WIDE_SD=5)
    f.vision_offset_m = FALSE_LOCK_OFFSET_M
    f.vision_cov_m2 = WIDE_COV_M2
    f.run(15.0)
    return f


def _error_m(f: CoreFlight) -> float:
    return float(np.linalg.norm(np.asarray(f.core.estimate().position_enu_m[:2]) - f.p[:2]))


def test_wide_false_fixes_walk_the_estimate_away_when_every_fix_is_fused():
    f = _false_lock_after_cruise(0.0)
    assert _error_m(f) > 30.0, _error_m(f)
    assert f.core.failsafe.vision_state == VisionFailsafeState.NORMAL     # nobody noticed
    f.close()


def test_sn_vis_max_sd_fuses_one_wide_fix_in_five_seconds():
    f = _false_lock_after_cruise(30.0)    # with SN_VIS_WIDE_SD 5: the false lock is not narrowed
    assert _error_m(f) < 8.0, _error_m(f)
    assert f.core.failsafe.vision_state == VisionFailsafeState.NORMAL     # fixes keep coming
    assert f.core.stats["vision_wide_fused"] in (3, 4), f.core.stats     # 15 s at one per 5 s
    assert f.core.stats["vision_wide_skipped"] > 100
    assert f.core.stats["vision_wide_narrowed"] == 0
    f.close()



def test_sn_vis_wide_sd_fuses_wide_fixes_that_agree_with_the_estimate():
    """SN_VIS_WIDE_SD: 15 s of true fixes (truth + 0.7 m noise) published 79 m wide, as an ambiguous
    match that found the true peak is. Each lies where the estimate is, gets that 1-sigma and is
    fused at every frame: the estimate stays on them with a fix-rate uncertainty, not the
    dead-reckoning one (the false lock 150 m off stays wide: the test above)."""
    f = vision_cruise(6, SN_VIS_DR_MAX=8, SN_VIS_MAX_SD=30, SN_VIS_WIDE_SD=5)
    f.vision_cov_m2 = WIDE_COV_M2
    f.run(15.0)
    assert f.core.stats["vision_wide_narrowed"] > 140, f.core.stats
    assert f.core.stats["vision_wide_skipped"] == 0
    assert float(np.max(f.core.nav.position_std_m()[:2])) < 2.0
    assert _error_m(f) < 2.0, _error_m(f)
    f.close()
