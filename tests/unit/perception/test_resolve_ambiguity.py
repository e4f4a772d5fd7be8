"""Resolving an ambiguous match with the autopilot's estimate
(``PerceptionConfig.resolve_ambiguity_min_posterior``, ``fix_covariance.local_mode_posterior``).

An ambiguous match's covariance is the mixture "here (the local peak's covariance), or anywhere in
the area searched"; against a Gaussian prior the local mode's posterior share decides whether it is
published with its local covariance."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_pipeline import ALT, CAM, MPP, H, W, err_m, render

from perception.config import PerceptionConfig
from perception.decision import FalseMatchMethod
from perception.fix_covariance import local_mode_posterior
from perception.ncc_search import SearchMode
from perception.pipeline import PerceptionPipeline
from scenenav.core.config import ConfigError

LOCAL = np.eye(2) * 1.0          # 1 m local 1-sigma
PRIOR = np.eye(2) * 4.0          # 2 m prior 1-sigma
AREA = 500.0 * 500.0             # a global search of a 500 m square


def test_the_local_mode_wins_near_the_prior_and_loses_far_from_it():
    near = local_mode_posterior((3.0, 0.0), LOCAL, 0.5, AREA, (0.0, 0.0), PRIOR)
    far = local_mode_posterior((30.0, 0.0), LOCAL, 0.5, AREA, (0.0, 0.0), PRIOR)
    assert near > 0.99 and far < 1e-6
    # monotonic in the distance and in the ambiguity weight
    shares = [local_mode_posterior((d, 0.0), LOCAL, 0.5, AREA, (0.0, 0.0), PRIOR) for d in range(0, 20)]
    assert all(a >= b for a, b in zip(shares, shares[1:], strict=False))
    weights = [local_mode_posterior((6.0, 0.0), LOCAL, w, AREA, (0.0, 0.0), PRIOR) for w in (0.1, 0.5, 0.9)]
    assert weights[0] > weights[1] > weights[2]


def test_a_wider_prior_keeps_the_local_mode_farther_out():
    tight = local_mode_posterior((10.0, 0.0), LOCAL, 0.5, AREA, (0.0, 0.0), np.eye(2) * 1.0)
    wide = local_mode_posterior((10.0, 0.0), LOCAL, 0.5, AREA, (0.0, 0.0), np.eye(2) * 25.0)
    assert wide > 0.99 > 0.5 > tight


@pytest.mark.parametrize(("w", "expected"), [(0.0, 1.0), (1.0, 0.0)])
def test_the_limits_of_the_ambiguity_weight(w, expected):
    assert local_mode_posterior((1.0, 1.0), LOCAL, w, AREA, (0.0, 0.0), PRIOR) == pytest.approx(expected)


@pytest.mark.parametrize("bad", [
    dict(fix=(math.nan, 0.0)), dict(area=0.0), dict(area=math.nan), dict(prior_cov=np.full((2, 2), math.nan)),
    dict(prior_cov=-np.eye(2) * 10.0)])
def test_unusable_inputs_give_no_share(bad):
    args = dict(fix=(1.0, 0.0), area=AREA, prior_cov=PRIOR)
    args.update(bad)
    assert local_mode_posterior(args["fix"], LOCAL, 0.5, args["area"], (0.0, 0.0), args["prior_cov"]) == 0.0


def _ambiguous_capture(day: np.ndarray, u: float, v: float) -> np.ndarray:
    """A capture at (u, v) so noisy that the global match is right but ambiguous (weight ~0.5)."""
    img = render(day, u, v, 0.4).astype(float) + np.random.default_rng(3).normal(0.0, 150.0, (CAM, CAM, 1))
    return np.clip(img, 0, 255).astype(np.uint8)


def _pipeline(ref, share: float) -> PerceptionPipeline:
    cfg = dataclasses.replace(PerceptionConfig(), resolve_ambiguity_min_posterior=share)
    return PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE, cfg)


@pytest.mark.parametrize(("share", "offset_m", "resolved"), [
    (0.9, 2.2, True),       # the estimate 2.2 m off (1.5 m sigma): the local mode holds the posterior
    (0.9, 30.0, False),     # 30 m off: "anywhere" explains it better; keep the wide covariance
    (0.0, 2.2, False),      # off
])
def test_an_accepted_ambiguous_match_near_the_estimate_gets_its_local_covariance(world, share, offset_m,
                                                                                 resolved):
    ref, day = world
    u, v = 300.0, 200.0
    x, y = (u - W / 2) * MPP, (H / 2 - v) * MPP
    pipe = _pipeline(ref, share)
    r = pipe.process(_ambiguous_capture(day, u, v), 0.4, ALT, 0.0,
                     estimate=(x + offset_m * 0.9, y - offset_m * 0.45, 1.5, 1.5))
    m = pipe.last_match
    assert r.accepted and r.search is SearchMode.GLOBAL and err_m(r, (u, v)) < 0.5
    # the area searched: every template position of the map (the map less the footprint)
    assert 0.2 < m.ambiguity_weight < 0.8 and 0.5 < m.search_area_m2 / (W * H * MPP * MPP) < 1.0
    assert np.trace(m.covariance_m2) > 100.0 * np.trace(m.local_covariance_m2)
    assert r.ambiguity_resolved is resolved and pipe.ambiguities_resolved == int(resolved)
    expected = m.local_covariance_m2 if resolved else m.covariance_m2
    assert np.allclose(r.covariance_m2, expected)


def test_a_confident_match_is_left_alone(world):
    ref, day = world
    u, v = 300.0, 200.0
    x, y = (u - W / 2) * MPP, (H / 2 - v) * MPP
    pipe = _pipeline(ref, 0.9)
    r = pipe.process(render(day, u, v, 0.4), 0.4, ALT, 0.0, estimate=(x, y, 1.5, 1.5))
    assert pipe.last_match.ambiguity_weight == 0.0 and not r.ambiguity_resolved
    assert np.allclose(r.covariance_m2, pipe.last_match.covariance_m2)


def test_a_rejected_match_is_never_resolved(world):
    ref, day = world
    from perception.assistant_map import AssistantMap
    amap = AssistantMap(W, H, MPP)
    amap.probability[:] = 0.1        # every area rated bad: every match rejected
    cfg = dataclasses.replace(PerceptionConfig(), resolve_ambiguity_min_posterior=0.9)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.ASSISTANT_MAP, cfg, assistant_map=amap)
    u, v = 300.0, 200.0
    x, y = (u - W / 2) * MPP, (H / 2 - v) * MPP
    r = pipe.process(_ambiguous_capture(day, u, v), 0.4, ALT, 0.0, estimate=(x, y, 1.5, 1.5))
    assert not r.accepted and not r.ambiguity_resolved


@pytest.mark.parametrize("value", [-0.1, 1.0, math.nan])
def test_the_setting_is_checked(value):
    with pytest.raises(ConfigError, match="resolve_ambiguity_min_posterior"):
        PerceptionConfig(resolve_ambiguity_min_posterior=value)


@pytest.mark.parametrize(("offset_m", "rejected"), [(2.2, False), (30.0, True)])
def test_an_ambiguous_match_the_estimate_all_but_rules_out_is_rejected(world, offset_m, rejected):
    """reject_ambiguity_below_posterior: the match's own peak holds less than that share against the
    estimate, so the fix says nothing (the posterior is the prior): rejected, reason ambiguous-far."""
    from perception.pipeline import Reason
    ref, day = world
    u, v = 300.0, 200.0
    x, y = (u - W / 2) * MPP, (H / 2 - v) * MPP
    cfg = dataclasses.replace(PerceptionConfig(), reject_ambiguity_below_posterior=0.01)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE, cfg)
    r = pipe.process(_ambiguous_capture(day, u, v), 0.4, ALT, 0.0,
                     estimate=(x + offset_m * 0.9, y - offset_m * 0.45, 1.5, 1.5))
    assert r.accepted is not rejected and pipe.ambiguities_rejected == int(rejected)
    assert (r.reason is Reason.AMBIGUOUS_FAR) is rejected
    assert not r.ambiguity_resolved          # resolution off: the mixture's covariance either way
    # without an estimate nothing is decided on it
    assert pipe.process(_ambiguous_capture(day, u, v), 0.4, ALT, 0.1).accepted
