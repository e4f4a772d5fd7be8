"""The sample in force at a time, and whether it has surely arrived (scenenav.core.timed_history)."""

from __future__ import annotations

from scenenav.core.timed_history import STALLED_PERIODS, sample_at, sample_settled


def test_sample_at_takes_the_newest_at_or_before_the_time():
    h = [(0, "a"), (50, "b"), (100, "c")]
    assert sample_at(h, 49) == "a" and sample_at(h, 50) == "b" and sample_at(h, 1000) == "c"
    assert sample_at(h, -5) == "a"                 # all later: the oldest
    assert sample_at([], 10) is None


def test_settled_once_a_sample_within_a_period_before_the_time_arrived():
    h = [(0, 0), (50, 0)]                          # period 50
    assert sample_settled(h, 60)                   # 50 > 60 - 50: the sample at or before 60 is in
    assert not sample_settled(h, 100)              # the one of 100 may still be on its way
    assert sample_settled(h + [(100, 0)], 100)
    assert sample_settled(h + [(150, 0)], 100)     # a later one arrived: so did 100's (one link)


def test_settled_when_nothing_to_wait_for():
    assert sample_settled([], 10) and sample_settled([(0, 0)], 10_000)
    h = [(0, 0), (50, 0)]
    assert not sample_settled(h, 50 + STALLED_PERIODS * 50)
    assert sample_settled(h, 51 + STALLED_PERIODS * 50)   # the stream stopped: do not wait for it
