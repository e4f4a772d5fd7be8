"""scenenav.core.numeric."""

from __future__ import annotations

import math

import numpy as np

from scenenav.core.numeric import largest_sd_2x2


def test_largest_sd_is_the_square_root_of_the_larger_eigenvalue():
    rng = np.random.default_rng(1)
    for _ in range(50):
        a = rng.normal(size=(2, 2))
        cov = a @ a.T
        assert math.isclose(largest_sd_2x2(cov), math.sqrt(np.linalg.eigvalsh(cov).max()), rel_tol=1e-9)
    assert largest_sd_2x2([[4.0, 0.0], [0.0, 9.0]]) == 3.0


def test_largest_sd_of_a_non_finite_covariance_is_nan():
    assert math.isnan(largest_sd_2x2([[float("nan"), 0.0], [0.0, 1.0]]))
    assert math.isnan(largest_sd_2x2([[1.0, float("inf")], [0.0, 1.0]]))
