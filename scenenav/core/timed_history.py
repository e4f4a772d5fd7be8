"""Timestamped samples received from the bus: the one in force at a time, and whether it has surely
arrived.

A node that acts at simulated time ``t`` on another node's stream (perception aligning a frame with
the autopilot's attitude, guidance checking the drift at a tick) must use the sample of ``t``, not
whichever one happened to have arrived: two Zenoh links (the simulator's and the publisher's) race,
and taking the newest one makes lockstep runs differ. ``sample_settled`` says when the sample at or
before ``t`` is known for sure; ``sample_at`` picks it. Histories are sequences of
``(timestamp_us, value)`` in arrival order, which is publication order on one link. Pure; the caller
holds whatever lock guards the history.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import TypeVar

T = TypeVar("T")

#: A stream whose newest sample is this many of its own periods older than the asked time has
#: stopped (its publisher left): waiting for it would cost every later request the full wait.
STALLED_PERIODS = 20


def sample_at(history: Sequence[tuple[int, T]], t_us: int) -> T | None:
    """The newest sample stamped at or before ``t_us`` (the oldest one if all are later; None if empty)."""
    if not history:
        return None
    times = [t for t, _ in history]
    i = bisect.bisect_right(times, t_us) - 1
    return history[max(i, 0)][1]


def sample_settled(history: Sequence[tuple[int, object]], t_us: int,
                   stalled_periods: int = STALLED_PERIODS) -> bool:
    """Whether the sample at or before ``t_us`` is known for sure: one stamped within a period (the
    spacing of the last two samples) before ``t_us``, or later, has arrived. Also true when fewer
    than two samples have arrived (nothing to measure a period by) or the stream has stalled
    (``stalled_periods`` periods behind ``t_us``)."""
    if len(history) < 2:
        return True
    newest = history[-1][0]
    period = newest - history[-2][0]
    if period <= 0:
        return True
    if newest < t_us - stalled_periods * period:
        return True
    return newest > t_us - period
