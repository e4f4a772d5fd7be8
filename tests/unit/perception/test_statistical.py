"""Statistical false-match detector (paper 6.3 baseline): detrended position variance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.statistical import StatisticalDetector, detrended_variance_m2


def test_hand_checked_variance():
    # x exactly linear (no residual); y = 0, 0, 3 about its fitted line: residuals 0.5, -1, 0.5.
    samples = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 3.0]])
    assert detrended_variance_m2(samples) == pytest.approx((0.25 + 1.0 + 0.25) / (3 - 2))


def test_equal_times_fall_back_to_the_mean():
    samples = np.array([[5.0, 0.0, 0.0], [5.0, 2.0, 0.0], [5.0, 1.0, 3.0]])
    # x: 0, 2, 1 about 1 -> 2; y: 0, 0, 3 about 1 -> 6; (2 + 6) / (n - 1).
    assert detrended_variance_m2(samples) == pytest.approx(4.0)


def test_steady_line_is_never_flagged():
    det = StatisticalDetector(window=30, threshold=1.4)
    for k in range(100):
        t = 0.04 * k
        flag, var = det.update(10.0 * t + 3.0, -4.0 * t, t)      # 10.8 m/s straight leg
        assert not flag
        if k >= 2:
            assert var == pytest.approx(0.0, abs=1e-9)


def test_noisy_steady_line_stays_below_threshold():
    rng = np.random.default_rng(0)
    det = StatisticalDetector()
    flags = []
    for k in range(200):
        t = 0.1 * k
        flag, _ = det.update(10.0 * t + rng.normal(0, 0.3), rng.normal(0, 0.3), t)
        flags.append(flag)
    assert not any(flags)
    assert det.variance_m2 == pytest.approx(2 * 0.3 ** 2, rel=0.6)


def test_jump_is_flagged_then_clears_after_the_window():
    det = StatisticalDetector(window=30, threshold=1.4)
    flags, variances = [], []
    for k in range(100):
        t = 0.1 * k
        x = 10.0 * t + (25.0 if k == 50 else 0.0)              # one false match, 25 m off
        flag, var = det.update(x, 0.0, t)
        flags.append(flag)
        variances.append(var)
    assert not any(flags[:50])
    assert flags[50] and variances[50] > 1.4
    # The paper's latency: flagged while the jump stays in the window of 30 ...
    assert all(flags[50:80])
    # ... and clear again once it has left.
    assert not any(flags[80:])


def test_too_few_samples():
    det = StatisticalDetector()
    assert det.update(0.0, 0.0, 0.0) == (False, pytest.approx(float("nan"), nan_ok=True))
    flag, var = det.update(100.0, 0.0, 0.1)
    assert not flag and math.isnan(var)


def test_bad_values():
    det = StatisticalDetector()
    with pytest.raises(ValueError):
        det.update(float("nan"), 0.0, 0.0)
    with pytest.raises(ValueError):
        StatisticalDetector(window=2)
    with pytest.raises(ValueError):
        StatisticalDetector(threshold=0.0)
