"""MatchConfirmation (perception/match_confirmation.py): a fix leaves once its successors arrived,
confirmed only when they lie on one constant-velocity track with it; order is kept; a broken-off
track and the run's end leave fixes unconfirmed; 0 successors is a pass-through."""

from __future__ import annotations

import numpy as np
import pytest

from perception.match_confirmation import MatchConfirmation, on_one_track

DT = 0.1


def _track(n, v=(10.0, 2.0), noise_m=0.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    xy = np.column_stack([v[0] * t, v[1] * t]) + rng.normal(0.0, noise_m, (n, 2))
    return t, xy


def test_zero_successors_passes_every_fix_through_at_once():
    c = MatchConfirmation(0, 2.0, 0.8)
    assert c.push("a", 0.0, (0.0, 0.0), True) == [("a", True)]
    assert c.push("b", 0.1, (np.nan, np.nan), False) == [("b", False)]
    assert len(c) == 0


def test_a_straight_track_is_confirmed_each_fix_once_its_successors_arrived_in_order():
    t, xy = _track(12, noise_m=0.3)
    c = MatchConfirmation(5, 2.0, 0.8)
    out = []
    for k in range(12):
        decided = c.push(k, t[k], tuple(xy[k]), True)
        # fix j leaves with the arrival of fix j + 5
        assert [i for i, _ in decided] == ([k - 5] if k >= 5 else [])
        out += decided
    assert all(ok for _, ok in out)
    rest = c.flush()                       # the last five never got their successors
    assert [i for i, _ in rest] == list(range(7, 12)) and not any(ok for _, ok in rest)


def test_a_jump_off_the_track_is_not_confirmed_nor_are_the_fixes_whose_window_holds_it():
    t, xy = _track(20)
    xy[10] += (30.0, -20.0)                # a false match of a global search
    c = MatchConfirmation(5, 2.0, 0.8)
    verdict = {}
    for k in range(20):
        verdict.update(dict(c.push(k, t[k], tuple(xy[k]), True)))
    assert verdict[10] is False
    assert all(verdict[k] is False for k in range(5, 10))        # the jump is in their window
    assert all(verdict[k] is True for k in list(range(0, 5)) + [11, 12, 13, 14])


def test_on_one_track_takes_noise_within_the_tolerance_and_not_a_step():
    t, xy = _track(6)
    assert on_one_track(t, xy + [[0.0, 1.5], [0.0, -1.5]] * 3, 2.0)    # +-1.5 m: within 2 m
    stepped = xy.copy()
    stepped[3:] += (10.0, 0.0)            # a 10 m step (a jump to a look-alike block): no line holds it
    assert not on_one_track(t, stepped, 2.0)
    # the fitted line takes up part of a step as a velocity: a 3 m step stays within 2 m of it
    stepped[3:] -= (7.0, 0.0)
    assert on_one_track(t, stepped, 2.0)


def test_invalid_frames_keep_their_place_and_a_broken_off_track_leaves_unconfirmed():
    c = MatchConfirmation(3, 2.0, 0.5)
    assert c.push("v0", 0.0, (0.0, 0.0), True) == []
    assert c.push("i1", 0.1, (np.nan, np.nan), False) == []          # waits behind v0: order kept
    assert c.push("v2", 0.2, (2.0, 0.0), True) == []
    # no third successor within 0.5 s of v0: v0 leaves unconfirmed, then i1, and v2 waits on
    assert c.push("i3", 0.7, (np.nan, np.nan), False) == [("v0", False), ("i1", False)]
    assert [i for i, _ in c.flush()] == ["v2", "i3"]


@pytest.mark.parametrize("args", [(-1, 2.0, 0.8), (3, 0.0, 0.8), (3, 2.0, 0.0)])
def test_bad_settings_raise(args):
    with pytest.raises(ValueError):
        MatchConfirmation(*args)
