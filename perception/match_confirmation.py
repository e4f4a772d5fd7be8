"""Confirming a match by the matches after it (pure: no zenoh, no pybullet, no pymavlink).

A true match is followed by true matches of the same ground track; a false one (a wrong peak of a
global search, a jump onto a look-alike block) is rarely followed, frame after frame, by matches
on one straight line through it. :class:`MatchConfirmation` holds each fix until ``successors``
more valid matches have arrived and accepts it only when it and they lie on one constant-velocity
track (a least-squares line x(t), y(t) through the ``successors + 1`` positions, every position
within ``tol_m`` of it) and the decision rule accepted it too: the confirmation only ever turns an
accepted fix into a rejected one (reason ``unconfirmed``), never the other way round. The price is
latency: a fix leaves ``successors`` frames after its capture (0.5 s at 10 Hz for 5); it keeps its
capture time, and the autopilot fuses it at that time (docs/interfaces.md, VisionFix). A fix whose
successors do not arrive within ``max_span_s`` of it (the track broke off: invalid frames, a gap)
is not confirmed. Fixes leave in the order they came. See docs/perception.md, "Confirming a match
by its successors".
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

T = TypeVar("T")


@dataclass(frozen=True)
class Pending(Generic[T]):
    """One fix waiting for its verdict: the caller's ``item`` and what the confirmation needs."""

    item: T
    t_s: float
    xy_m: tuple[float, float]
    valid: bool


def on_one_track(t_s: np.ndarray, xy_m: np.ndarray, tol_m: float) -> bool:
    """Whether the positions ``xy_m`` (N, 2) at times ``t_s`` (N,) lie within ``tol_m`` of one
    constant-velocity line (least squares in each axis)."""
    t = np.asarray(t_s, dtype=float) - float(t_s[0])
    A = np.column_stack([np.ones_like(t), t])
    coef, *_ = np.linalg.lstsq(A, np.asarray(xy_m, dtype=float), rcond=None)
    residual = np.linalg.norm(A @ coef - xy_m, axis=1)
    return bool(np.max(residual) <= tol_m)


class MatchConfirmation(Generic[T]):
    """Holds fixes until their successors confirm them (module docstring). ``successors`` 0: every
    fix leaves at once, confirmed (the confirmation is off)."""

    def __init__(self, successors: int, tol_m: float, max_span_s: float) -> None:
        if successors < 0 or not tol_m > 0.0 or not max_span_s > 0.0:
            raise ValueError(f"successors {successors}, tol_m {tol_m}, max_span_s {max_span_s}: expected "
                             f">= 0, > 0, > 0")
        self.successors = int(successors)
        self.tol_m = float(tol_m)
        self.max_span_s = float(max_span_s)
        self._pending: deque[Pending[T]] = deque()

    def push(self, item: T, t_s: float, xy_m: tuple[float, float], valid: bool) -> list[tuple[T, bool]]:
        """Add the newest fix; returns the fixes decided now, oldest first, each with whether it is
        confirmed (an invalid fix is never confirmed; nothing to confirm)."""
        self._pending.append(Pending(item, float(t_s), (float(xy_m[0]), float(xy_m[1])), bool(valid)))
        return self._decide(final=False)

    def flush(self) -> list[tuple[T, bool]]:
        """Decide every held fix (the run ends): those without their successors are unconfirmed."""
        return self._decide(final=True)

    def _decide(self, final: bool) -> list[tuple[T, bool]]:
        out: list[tuple[T, bool]] = []
        newest_t = self._pending[-1].t_s if self._pending else 0.0
        while self._pending:
            head = self._pending[0]
            if not head.valid or self.successors == 0:
                out.append((self._pending.popleft().item, head.valid))
                continue
            track = [p for p in self._pending if p.valid and p.t_s - head.t_s <= self.max_span_s]
            if len(track) > self.successors:
                track = track[:self.successors + 1]
                ok = on_one_track(np.array([p.t_s for p in track]), np.array([p.xy_m for p in track]),
                                  self.tol_m)
                out.append((self._pending.popleft().item, ok))
                continue
            if final or newest_t - head.t_s > self.max_span_s:
                out.append((self._pending.popleft().item, False))
                continue
            break
        return out

    def __len__(self) -> int:
        return len(self._pending)


__all__ = ["MatchConfirmation", "Pending", "on_one_track"]
