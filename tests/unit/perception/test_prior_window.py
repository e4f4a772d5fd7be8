"""The search window around the autopilot's estimate (``perception.prior_from_estimate``): its radius
from the estimate's standard deviation, and the pipeline searching only there."""

from __future__ import annotations

import math

import pytest
from test_pipeline import ALT, MPP, H, W, err_m, render

from perception.decision import FalseMatchMethod
from perception.ncc_search import SearchMode
from perception.pipeline import PerceptionPipeline
from perception.tracker import PRIOR_SIGMAS, prior_search_radius_m


def test_prior_radius_hand_checked():
    # 24 px at 0.5 m/px = 12 m, plus 3 sigma of hypot(3, 4) = 5 m
    assert prior_search_radius_m((3.0, 4.0, 9.0), 0.5, 24, 400) == pytest.approx(12.0 + PRIOR_SIGMAS * 5.0)
    assert prior_search_radius_m((0.0, 0.0, 0.0), 0.5, 24, 400) == pytest.approx(12.0)
    # wider than max_search_radius_px (400 px = 200 m): no window, a global search
    assert prior_search_radius_m((60.0, 60.0, 1.0), 0.5, 24, 400) is None
    assert prior_search_radius_m((math.nan, 1.0, 1.0), 0.5, 24, 400) is None


def test_a_small_prior_window_keeps_the_match_inside_it(world):
    ref, day = world
    u, v = 310.0, 210.0
    x, y = (u - W / 2) * MPP, (H / 2 - v) * MPP
    image = render(day, u, v, 1.0)
    # the estimate 4 m off, a 10 m window: the true position is inside, found in a window search
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    r = pipe.process(image, 1.0, ALT, 0.0, (x + 4.0, y), prior_radius_m=10.0)
    assert r.search is SearchMode.WINDOW and err_m(r, (u, v)) < 0.3
    # the estimate 30 m off with a 10 m window: the match cannot reach the truth (stays near the prior)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    r = pipe.process(image, 1.0, ALT, 0.0, (x + 30.0, y), prior_radius_m=10.0)
    assert r.search is SearchMode.WINDOW and err_m(r, (u, v)) > 15.0
