"""Whether consecutive matches agree on one place moving at a constant velocity.

``MatchConsistency.observe`` takes each valid match's position and time and returns how many matches
in a row (this one included) have each lain within a tolerance of the straight line through the two
before them, extrapolated to their time. Independent searches of consecutive frames that keep
agreeing on one moving place are evidence that the place is the vehicle's, whatever the correlation
surface's second peaks say: the pipeline uses it to publish such an ambiguous match with its own
peak's covariance (``PerceptionConfig.resolve_consistent_matches``; docs/perception.md). A frame gap
longer than ``CONSISTENT_MATCH_MAX_GAP_S`` or a speed above ``MAX_SPEED_M_S`` between two matches
starts the count again.
"""

from __future__ import annotations

import math
from collections import deque

#: Two matches further apart in time than this do not continue each other (a 10 Hz camera with one
#: frame lost leaves 0.2 s).
CONSISTENT_MATCH_MAX_GAP_S = 0.35
#: Faster than this between two matches is not a vehicle's motion: well above the Iris's 10 m/s
#: survey speed plus wind, with room for a jittered capture time.
MAX_SPEED_M_S = 35.0


class MatchConsistency:
    """The run length of constant-velocity-consistent matches (module docstring)."""

    def __init__(self, tol_m: float) -> None:
        if not (math.isfinite(tol_m) and tol_m > 0.0):
            raise ValueError(f"tol_m must be a distance > 0 m, got {tol_m!r}")
        self.tol_m = float(tol_m)
        self._recent: deque[tuple[float, float, float]] = deque(maxlen=2)
        self.run = 0

    def reset(self) -> None:
        """Forget the matches seen so far."""
        self._recent.clear()
        self.run = 0

    def observe(self, t_s: float, position_enu_m: tuple[float, float]) -> int:
        """Add a valid match at ``t_s``; the number of consistent matches in a row, this one included
        (0: this one does not continue the two before it, or there were not two)."""
        x, y = float(position_enu_m[0]), float(position_enu_m[1])
        if not (math.isfinite(t_s) and math.isfinite(x) and math.isfinite(y)):
            self.reset()
            return 0
        if self._recent and not self._continues(self._recent[-1], (t_s, x, y)):
            self._recent.clear()
        consistent = False
        if len(self._recent) == 2:
            (t0, x0, y0), (t1, x1, y1) = self._recent
            k = (t_s - t1) / (t1 - t0)
            consistent = math.hypot(x - (x1 + k * (x1 - x0)), y - (y1 + k * (y1 - y0))) <= self.tol_m
        self.run = self.run + 1 if consistent else 0
        self._recent.append((t_s, x, y))
        return self.run

    @staticmethod
    def _continues(prev: tuple[float, float, float], cur: tuple[float, float, float]) -> bool:
        dt = cur[0] - prev[0]
        return (0.0 < dt <= CONSISTENT_MATCH_MAX_GAP_S
                and math.hypot(cur[1] - prev[1], cur[2] - prev[2]) <= MAX_SPEED_M_S * dt)
