"""Resolving an ambiguous match by its consistent predecessors (``perception.match_consistency``,
``PerceptionConfig.resolve_consistent_matches``): consecutive matches that agree on one place moving
at a constant velocity publish an ambiguous match with its own peak's covariance."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_pipeline import ALT, CAM, MPP, err_m, render

from perception.config import PerceptionConfig
from perception.decision import FalseMatchMethod
from perception.match_consistency import CONSISTENT_MATCH_MAX_GAP_S, MatchConsistency
from perception.pipeline import PerceptionPipeline
from scenenav.core.config import ConfigError


def _line(n: int, t0: float = 0.0, dt: float = 0.1, v=(10.0, -3.0)):
    return [(t0 + i * dt, (5.0 + v[0] * i * dt, 7.0 + v[1] * i * dt)) for i in range(n)]


def test_matches_on_a_constant_velocity_line_count_up_from_the_third():
    c = MatchConsistency(2.0)
    assert [c.observe(t, p) for t, p in _line(6)] == [0, 0, 1, 2, 3, 4]


def test_irregular_frame_times_are_extrapolated_not_assumed_equal():
    c = MatchConsistency(0.5)
    times = [0.0, 0.1, 0.25, 0.3, 0.42]
    runs = [c.observe(t, (10.0 * t, 2.0 * t)) for t in times]
    assert runs == [0, 0, 1, 2, 3]


def test_a_jump_beyond_the_tolerance_starts_the_count_again():
    c = MatchConsistency(2.0)
    pts = _line(5)
    for t, p in pts:
        c.observe(t, p)
    t, (x, y) = 0.5, (5.0 + 5.0, 7.0 - 1.5)        # where the line goes ...
    assert c.observe(t, (x + 2.5, y)) == 0        # ... but 2.5 m beside it
    # the jumped-to match and the last one on the line define the next line: no count for two frames
    assert c.observe(0.6, (x + 3.5, y - 0.3)) == 0


def test_within_the_tolerance_counts():
    c = MatchConsistency(2.0)
    for t, p in _line(3):
        c.observe(t, p)
    assert c.observe(0.3, (5.0 + 3.0 + 1.9, 7.0 - 0.9)) == 2


@pytest.mark.parametrize("gap", [CONSISTENT_MATCH_MAX_GAP_S + 0.05, 2.0])
def test_a_long_frame_gap_breaks_the_run(gap):
    c = MatchConsistency(2.0)
    for t, p in _line(4):
        c.observe(t, p)
    t = 0.3 + gap
    assert c.observe(t, (5.0 + 10.0 * t, 7.0 - 3.0 * t)) == 0


def test_a_standing_false_peak_is_consistent_but_an_implausible_speed_is_not():
    still = MatchConsistency(2.0)
    assert [still.observe(0.1 * i, (3.0, 3.0)) for i in range(4)] == [0, 0, 1, 2]
    fast = MatchConsistency(2.0)     # 40 m/s between frames: not a vehicle
    assert [fast.observe(0.1 * i, (4.0 * i, 0.0)) for i in range(4)] == [0, 0, 0, 0]


def test_nan_resets():
    c = MatchConsistency(2.0)
    for t, p in _line(4):
        c.observe(t, p)
    assert c.observe(0.4, (math.nan, 1.0)) == 0
    assert c.run == 0


@pytest.mark.parametrize("tol", [0.0, -1.0, math.nan])
def test_the_tolerance_is_checked(tol):
    with pytest.raises(ValueError, match="tol_m"):
        MatchConsistency(tol)


@pytest.mark.parametrize(("key", "value"), [("resolve_consistent_matches", -1),
                                            ("resolve_consistent_matches", 1.5),
                                            ("resolve_consistent_matches", True),
                                            ("consistent_match_tol_m", 0.0),
                                            ("consistent_match_tol_m", math.nan)])
def test_the_settings_are_checked(key, value):
    with pytest.raises(ConfigError, match=key):
        PerceptionConfig(**{key: value})


def _noisy(day: np.ndarray, u: float, v: float, seed: int) -> np.ndarray:
    """A capture at (u, v) so noisy that the global match is right but ambiguous."""
    img = render(day, u, v, 0.4).astype(float) + np.random.default_rng(seed).normal(0.0, 150.0, (CAM, CAM, 1))
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize(("n", "resolved_from"), [(2, 4), (0, None)])
def test_ambiguous_matches_on_a_consistent_run_get_their_local_covariance(world, n, resolved_from):
    """A flight east at 10 m/s over frames too noisy for a confident match: every match is
    one (global or in the window), right and ambiguous; from the (n + 2)-th on each continues n consistent ones."""
    ref, day = world
    cfg = dataclasses.replace(PerceptionConfig(), resolve_consistent_matches=n)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE, cfg)
    u0, v = 280.0, 200.0
    for i in range(6):
        u = u0 + 10.0 / MPP * 0.1 * i
        r = pipe.process(_noisy(day, u, v, i), 0.4, ALT, 0.1 * i)
        m = pipe.last_match
        assert r.accepted and err_m(r, (u, v)) < 0.6
        assert m.ambiguity_weight > 0.0
        resolved = resolved_from is not None and i >= resolved_from - 1
        assert r.ambiguity_resolved is resolved, i
        expected = m.local_covariance_m2 if resolved else m.covariance_m2
        assert np.allclose(r.covariance_m2, expected)
    assert pipe.ambiguities_resolved_by_consistency == (0 if resolved_from is None else 7 - resolved_from)


def test_an_inconsistent_ambiguous_match_keeps_its_wide_covariance(world):
    """The same run with the fourth frame taken 15 m north of the line: it breaks the run."""
    ref, day = world
    cfg = dataclasses.replace(PerceptionConfig(), resolve_consistent_matches=1)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE, cfg)
    out = []
    for i, dv in enumerate((0.0, 0.0, 0.0, -15.0 / MPP)):
        r = pipe.process(_noisy(day, 280.0 + 10.0 / MPP * 0.1 * i, 200.0 + dv, i), 0.4, ALT, 0.1 * i)
        out.append(r.ambiguity_resolved)
    assert out == [False, False, True, False]
