"""Position resets onto vision fixes that were all rejected for ``position_reject_timeout_s``: a reset
re-opens the horizontal velocity (``NavFilter._reopen_horizontal_velocity``), so a filter whose
velocity ran away recovers on the next fixes instead of resetting onto them every timeout; and a reset
larger than ``vision_reset_max_m`` (SN_VIS_RST_MAX) is refused."""

from __future__ import annotations

import numpy as np

from autopilot_bridge.config import EkfConfig, PositionSource
from autopilot_bridge.ekf import NavFilter

G = 9.80665
DT = 0.01
SPEED = np.array([5.0, 0.0, 0.0])


def _fly(seconds: float, seed: int, reset_max_m: float = 0.0, velocity_kick_at_s: float | None = None,
         fix_offset=lambda t: np.zeros(2)) -> tuple[NavFilter, list[float], float]:
    """A filter that knows its constant velocity at the start, vision fixes at 10 Hz (true position
    plus ``fix_offset(t)``); optionally its velocity is kicked 6 m/s off. Returns the filter, the
    velocity error per tick and the final horizontal position error."""
    rng = np.random.default_rng(seed)
    nav = NavFilter(EkfConfig(position_source=PositionSource.EXTNAV, vision_reset_max_m=reset_max_m))
    nav.initialise((0.0, 0.0, G), 0.0, 100.0, position_enu_m=(0.0, 0.0, 100.0))
    nav._v = list(SPEED)
    p = np.array([0.0, 0.0, 100.0])
    errors = []
    for k in range(int(seconds / DT)):
        if velocity_kick_at_s is not None and k == int(velocity_kick_at_s / DT):
            nav._v[0] += 6.0    # the velocity runs away (what a wrong heading or bias does)
        p = p + SPEED * DT
        nav.predict(np.array([0.0, 0.0, G]) + rng.normal(0.0, 0.02, 3), rng.normal(0.0, 1e-4, 3), DT)
        if k % 5 == 0:
            nav.fuse_baro(float(p[2]))
            nav.fuse_compass(0.0)
        if k % 10 == 0:
            nav.fuse_vision_position(p[:2] + fix_offset(k * DT) + rng.normal(0.0, 0.5, 2), np.eye(2) * 0.25)
        errors.append(abs(nav.state().velocity_enu_m_s[0] - SPEED[0]))
    return nav, errors, float(np.hypot(*(nav.state().position_enu_m[:2] - p[:2])))


def test_a_runaway_velocity_is_recovered_after_one_position_reset():
    nav, errors, _ = _fly(40.0, seed=5, velocity_kick_at_s=10.0)
    assert nav.position_reset_count == 1
    assert max(errors[-int(10.0 / DT):]) < 0.5


def test_a_reset_onto_a_far_false_lock_is_refused_when_limited():
    """Consistent fixes 355 m off (a false lock on a repeated pattern) are rejected by the gate; with
    a 100 m limit the reset onto them is refused again and again and the estimate stays with the
    truth; without a limit it jumps onto them."""
    def false_lock(t: float) -> np.ndarray:
        return np.array([213.0, -285.0]) if 10.0 <= t < 25.0 else np.zeros(2)
    limited, _, err_limited = _fly(30.0, seed=7, reset_max_m=100.0, fix_offset=false_lock)
    assert limited.position_reset_count == 0 and limited.refused_reset_count == 2
    assert np.allclose(limited.last_refused_reset_m, (213.0, -285.0), atol=5.0)
    assert err_limited < 5.0
    free, _, _ = _fly(30.0, seed=7, fix_offset=false_lock)
    assert free.position_reset_count >= 1 and free.refused_reset_count == 0
