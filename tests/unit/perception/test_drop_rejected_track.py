"""Dropping a track the decision rule keeps rejecting (``PerceptionConfig.drop_rejected_track_s``):
the tracker forgets it, the next search is around the re-acquisition prior (the autopilot's estimate
in the node), and the track evidence returns to its anchor at the last acceptance. And a lost track
searched for around that prior within ``reacquire_window_s`` of the last accepted fix."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_pipeline import ALT, MPP, H, W, err_m, fly, render

from perception.assistant_map import AssistantMap
from perception.config import PerceptionConfig, PerceptionNodeConfig
from perception.decision import Decision, FalseMatchMethod, TrackEvidence
from perception.ncc_search import SearchMode
from perception.pipeline import PerceptionPipeline, Reason
from perception.tracker import TrackState, prior_search_radius_m
from scenenav.core.config import ConfigError


def _pipeline(ref, p_true: float, drop_s: float) -> PerceptionPipeline:
    amap = AssistantMap(W, H, MPP)
    amap.probability[:] = p_true
    cfg = dataclasses.replace(PerceptionConfig(), drop_rejected_track_s=drop_s)
    return PerceptionPipeline(ref, MPP, FalseMatchMethod.ASSISTANT_MAP, cfg, assistant_map=amap)


def _world_xy(u: float, v: float) -> tuple[float, float]:
    return (u - W / 2) * MPP, (H / 2 - v) * MPP


def test_a_rejected_track_is_dropped_after_the_set_time(world):
    ref, day = world
    pipe = _pipeline(ref, 0.2, 0.5)        # the whole map rated bad: every sharp match is rejected
    results = fly(pipe, day, 6)             # t = 0 .. 0.5 s
    assert all(r.quality_ok and r.reason is Reason.MAP_BAD_AREA for r, _ in results)
    assert [r.search for r, _ in results[1:]] == [SearchMode.WINDOW] * 5
    assert pipe.dropped_tracks == 1 and pipe.reacquiring
    assert pipe.tracker.state is TrackState.ACQUIRING and pipe.tracker.predict(0.6) is None


def test_without_the_setting_the_tracker_keeps_a_rejected_track(world):
    ref, day = world
    pipe = _pipeline(ref, 0.2, 0.0)
    results = fly(pipe, day, 12)
    assert all(not r.accepted for r, _ in results)
    assert pipe.dropped_tracks == 0 and not pipe.reacquiring
    assert pipe.tracker.state is TrackState.TRACKING and results[-1][0].search is SearchMode.WINDOW


def test_after_a_drop_the_search_is_around_the_reacquisition_prior(world):
    ref, day = world
    pipe = _pipeline(ref, 0.2, 0.5)
    fly(pipe, day, 6)
    assert pipe.reacquiring
    u, v = 320.0, 205.0
    image = render(day, u, v, 0.4)
    # a prior 30 m off with a 10 m radius: the window cannot reach the truth, so the search was there
    x, y = _world_xy(u, v)
    far = pipe.process(image, 0.4, ALT, 0.6, reacquire_prior=(x + 30.0, y, 10.0))
    assert far.search is SearchMode.WINDOW and err_m(far, (u, v)) > 15.0
    pipe.tracker.reset()
    near = pipe.process(image, 0.4, ALT, 0.7, reacquire_prior=(x + 4.0, y, 10.0))
    assert near.search is SearchMode.WINDOW and err_m(near, (u, v)) < 0.5
    # a re-acquisition starts a new run of the track evidence (the window match is not a continuation)
    assert near.run == 0


def test_without_a_radius_the_reacquisition_searches_the_whole_map(world):
    ref, day = world
    pipe = _pipeline(ref, 0.2, 0.5)
    fly(pipe, day, 6)
    u, v = 320.0, 205.0
    x, y = _world_xy(u, v)
    r = pipe.process(render(day, u, v, 0.4), 0.4, ALT, 0.6, reacquire_prior=(x, y, None))
    assert r.search is not SearchMode.WINDOW and err_m(r, (u, v)) < 0.5


def test_the_reacquisition_prior_is_ignored_unless_a_track_was_dropped(world):
    ref, day = world
    pipe = _pipeline(ref, 0.9, 0.5)
    u, v = 320.0, 205.0
    x, y = _world_xy(u, v)
    first = pipe.process(render(day, u, v, 0.4), 0.4, ALT, 0.0, reacquire_prior=(x + 30.0, y, 10.0))
    assert first.search is not SearchMode.WINDOW and err_m(first, (u, v)) < 0.5 and first.accepted


def test_an_acceptance_ends_the_streak_and_the_reacquisition(world):
    ref, day = world
    pipe = _pipeline(ref, 0.2, 0.5)
    fly(pipe, day, 6)
    assert pipe.reacquiring
    pipe.assistant_map.probability[:] = 0.9           # the area now rated good
    u, v = 320.0, 205.0
    x, y = _world_xy(u, v)
    r = pipe.process(render(day, u, v, 0.4), 0.4, ALT, 0.6, reacquire_prior=(x, y, 10.0))
    assert r.accepted and r.decision is Decision.ACCEPT and not pipe.reacquiring
    # a rejection streak shorter than the limit, ended by an acceptance, drops nothing
    pipe.assistant_map.probability[:] = 0.2
    fly(pipe, day, 4, u0=322.0, v0=205.5, t0=0.7)
    pipe.assistant_map.probability[:] = 0.9
    fly(pipe, day, 1, u0=330.0, v0=207.5, t0=1.1)
    pipe.assistant_map.probability[:] = 0.2
    fly(pipe, day, 4, u0=332.0, v0=208.0, t0=1.2)
    assert pipe.dropped_tracks == 1 and pipe.tracker.state is TrackState.TRACKING


def _feed(ev: TrackEvidence, t0: float, u0: float, n: int, reacquired_first: bool = True) -> None:
    for k in range(n):
        ev.observe(t0 + 0.1 * k, (u0 + 2.0 * k, 100.0), True, reacquired_first and k == 0)


def test_track_evidence_drop_run_returns_to_the_anchor_at_the_last_acceptance():
    ev = TrackEvidence(min_run=5)
    _feed(ev, 0.0, 100.0, 6)                      # established: anchor at u = 110, 20 px/s
    ev.mark_accepted()
    accepted = ev.predict(1.0)
    _feed(ev, 1.0, 400.0, 6)                      # a false lock, established too: the anchor moved
    assert ev.predict(1.0)[0][0] > 300.0
    ev.drop_run()
    assert ev.count == 0
    assert ev.predict(1.0) == accepted            # back to the accepted run's anchor
    ev2 = TrackEvidence(min_run=5)
    _feed(ev2, 0.0, 100.0, 6)
    ev2.drop_run()                                # never accepted: no anchor at all
    assert ev2.predict(1.0) is None


def test_reacquisition_radius_has_a_floor():
    assert prior_search_radius_m((0.3, 0.4, 1.0), 0.5, 24, 400, min_radius_m=30.0) == pytest.approx(30.0)
    assert prior_search_radius_m((10.0, 0.0, 1.0), 0.5, 24, 400, min_radius_m=30.0) == pytest.approx(42.0)
    assert prior_search_radius_m((0.0, 0.0, 1.0), 0.5, 24, 400, min_radius_m=250.0) is None


@pytest.mark.parametrize("value", [-1.0, float("nan"), 601.0])
def test_bad_drop_times_are_refused(value):
    with pytest.raises(ConfigError, match="drop_rejected_track_s"):
        PerceptionConfig(drop_rejected_track_s=value)
    with pytest.raises(ConfigError, match="drop_rejected_track_s"):
        PerceptionNodeConfig(drop_rejected_track_s=value)


def test_bad_reacquisition_radius_is_refused():
    with pytest.raises(ConfigError, match="reacquire_min_radius_m"):
        PerceptionNodeConfig(reacquire_min_radius_m=-5.0)


def _lose_track(pipe: PerceptionPipeline, t0: float) -> None:
    """Low-quality matches (noise captures) until the tracker gives the track up."""
    noise = np.random.default_rng(3).integers(0, 256, (200, 200, 3), dtype=np.uint8)
    for k in range(pipe.cfg.matcher.lost_after_n):
        assert not pipe.process(noise, 0.4, ALT, t0 + 0.1 * k).quality_ok
    assert pipe.tracker.state is TrackState.LOST


@pytest.mark.parametrize(("window_s", "t_s", "around_prior"),
                         [(20.0, 5.0, True), (20.0, 30.0, False), (0.0, 5.0, False)])
def test_a_lost_track_is_searched_for_around_the_prior_within_the_window(world, window_s, t_s,
                                                                       around_prior):
    ref, day = world
    amap = AssistantMap(W, H, MPP)
    amap.probability[:] = 0.9
    cfg = dataclasses.replace(PerceptionConfig(), reacquire_window_s=window_s)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.ASSISTANT_MAP, cfg, assistant_map=amap)
    assert all(r.accepted for r, _ in fly(pipe, day, 3))     # last accepted at t = 0.2 s
    _lose_track(pipe, 0.3)
    u, v = 320.0, 205.0
    x, y = _world_xy(u, v)
    r = pipe.process(render(day, u, v, 0.4), 0.4, ALT, t_s, reacquire_prior=(x + 30.0, y, 10.0))
    if around_prior:      # the window around the prior cannot reach the truth 30 m away
        assert r.search is SearchMode.WINDOW and err_m(r, (u, v)) > 15.0 and r.run == 0
    else:                 # the whole map: the truth
        assert r.search is not SearchMode.WINDOW and err_m(r, (u, v)) < 0.5


def test_bad_reacquisition_window_is_refused():
    with pytest.raises(ConfigError, match="reacquire_window_s"):
        PerceptionConfig(reacquire_window_s=-1.0)
    with pytest.raises(ConfigError, match="reacquire_window_s"):
        PerceptionNodeConfig(reacquire_window_s=float("nan"))
