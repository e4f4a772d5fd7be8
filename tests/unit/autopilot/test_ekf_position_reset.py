"""A position reset after persistently rejected fixes re-opens the horizontal velocity
(``NavFilter._reopen_horizontal_velocity``): a filter whose velocity ran away recovers on the next
fixes instead of resetting onto them every ``position_reset_timeout_s``."""

from __future__ import annotations

import numpy as np

from autopilot_bridge.config import EkfConfig, PositionSource
from autopilot_bridge.ekf import NavFilter

G = 9.80665
DT = 0.01
SPEED = np.array([5.0, 0.0, 0.0])


def test_a_runaway_velocity_is_recovered_after_one_position_reset():
    rng = np.random.default_rng(5)
    nav = NavFilter(EkfConfig(position_source=PositionSource.EXTNAV))
    nav.initialise((0.0, 0.0, G), 0.0, 100.0, position_enu_m=(0.0, 0.0, 100.0))
    p = np.array([0.0, 0.0, 100.0])
    nav._v = list(SPEED)        # the filter starts knowing the (constant) velocity
    errors = []
    for k in range(int(40.0 / DT)):
        if k == int(10.0 / DT):
            nav._v[0] += 6.0    # then its velocity runs away (what a wrong heading or bias does)
        p = p + SPEED * DT
        nav.predict(np.array([0.0, 0.0, G]) + rng.normal(0.0, 0.02, 3), rng.normal(0.0, 1e-4, 3), DT)
        if k % 5 == 0:
            nav.fuse_baro(float(p[2]))
            nav.fuse_compass(0.0)
        if k % 10 == 0:
            nav.fuse_vision_position(p[:2] + rng.normal(0.0, 0.5, 2), np.eye(2) * 0.25)
        errors.append(abs(nav.state().velocity_enu_m_s[0] - SPEED[0]))
    assert nav.position_reset_count == 1
    assert max(errors[-int(10.0 / DT):]) < 0.5


def test_a_reset_onto_a_far_false_lock_is_refused_when_limited():
    """Consistent fixes 300 m off (a false lock on a repeated pattern) are rejected by the gate; with
    ``vision_reset_max_m`` 100 m the reset onto them is refused again and again, and the estimate
    stays with the truth; without a limit it jumps onto them."""
    def fly(limit_m: float) -> tuple[NavFilter, float]:
        rng = np.random.default_rng(7)
        nav = NavFilter(EkfConfig(position_source=PositionSource.EXTNAV, vision_reset_max_m=limit_m))
        nav.initialise((0.0, 0.0, G), 0.0, 100.0, position_enu_m=(0.0, 0.0, 100.0))
        nav._v = list(SPEED)
        p = np.array([0.0, 0.0, 100.0])
        for k in range(int(30.0 / DT)):
            p = p + SPEED * DT
            nav.predict(np.array([0.0, 0.0, G]) + rng.normal(0.0, 0.02, 3), rng.normal(0.0, 1e-4, 3), DT)
            if k % 5 == 0:
                nav.fuse_baro(float(p[2]))
                nav.fuse_compass(0.0)
            if k % 10 == 0:
                offset = np.array([213.0, -285.0]) if 10.0 <= k * DT < 25.0 else np.zeros(2)
                nav.fuse_vision_position(p[:2] + offset + rng.normal(0.0, 0.5, 2), np.eye(2) * 0.25)
        return nav, float(np.hypot(*(nav.state().position_enu_m[:2] - p[:2])))
    limited, err_limited = fly(100.0)
    assert limited.position_reset_count == 0 and limited.refused_reset_count == 2
    assert np.allclose(limited.last_refused_reset_m, (213.0, -285.0), atol=5.0)
    assert err_limited < 5.0
    free, _ = fly(0.0)
    assert free.position_reset_count >= 1 and free.refused_reset_count == 0
