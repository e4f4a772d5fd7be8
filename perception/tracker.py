"""Windowed NCC tracking: constant-velocity prediction and global re-acquisition.

See ``MatchTracker``; the search itself is ``perception.ncc_search.SceneMatcher``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from dataclasses import dataclass
from enum import Enum

import numpy as np

from perception.config import MatcherConfig
from perception.ncc_search import MatchResult, SceneMatcher, SearchMode

log = logging.getLogger(__name__)


class TrackState(str, Enum):
    """Tracker state."""

    ACQUIRING = "acquiring"   # no good fix yet: global search (or around an external prior)
    TRACKING = "tracking"     # windowed search around the constant-velocity prediction
    LOST = "lost"             # lost_after_n consecutive low-quality matches: global search


@dataclass(frozen=True)
class Prediction:
    """Where the next template centre is expected (continuous pixels) and how far to search."""

    uv: tuple[float, float]
    radius_px: float
    movement_px: float


class MatchTracker:
    """Windowed NCC tracking with constant-velocity prediction and global re-acquisition.

    Only quality-ok matches (see ``SceneMatcher``) update the track. The window radius is
    ``margin * (1 + misses) + movement_factor * |v| dt`` (``v`` from the last two good fixes); with a
    single good fix the velocity is unknown and ``max_speed_m_s * dt`` replaces the movement. A
    radius above ``max_search_radius_px``, or ``lost_after_n`` consecutive low-quality matches,
    switches to a global search; the first good global match restarts the track.
    """

    _HISTORY = 3

    def __init__(self, matcher: SceneMatcher, cfg: MatcherConfig | None = None) -> None:
        self.matcher = matcher
        self.cfg = cfg if cfg is not None else matcher.cfg
        self._fixes: deque[tuple[float, float, float]] = deque(maxlen=self._HISTORY)  # (t, u, v)
        self.state = TrackState.ACQUIRING
        self.misses = 0
        self.last_prediction: Prediction | None = None
        #: Good fixes since the track was last (re-)acquired (a long track is rarely a false one).
        self.track_fixes = 0

    def reset(self) -> None:
        """Forget the track (next match is global)."""
        self._fixes.clear()
        self.track_fixes = 0
        self.state = TrackState.ACQUIRING
        self.misses = 0
        self.last_prediction = None

    @property
    def velocity_px_s(self) -> tuple[float, float] | None:
        """Velocity from the last two good fixes (pixels/s), None when unknown."""
        if len(self._fixes) < 2:
            return None
        (t0, u0, v0), (t1, u1, v1) = self._fixes[-2], self._fixes[-1]
        dt = t1 - t0
        if dt <= 0.0:
            return None
        return (u1 - u0) / dt, (v1 - v0) / dt

    def last_movement_px(self) -> float:
        """Distance between the last two good fixes in pixels (0 when unknown)."""
        if len(self._fixes) < 2:
            return 0.0
        (_, u0, v0), (_, u1, v1) = self._fixes[-2], self._fixes[-1]
        return math.hypot(u1 - u0, v1 - v0)

    def predict(self, t_s: float) -> Prediction | None:
        """Constant-velocity prediction for time ``t_s``; None when a global search is due."""
        if not self._fixes or self.state is TrackState.LOST:
            return None
        cfg = self.cfg
        t_last, u_last, v_last = self._fixes[-1]
        dt = max(0.0, t_s - t_last)
        vel = self.velocity_px_s
        base = cfg.min_window_margin_px * (1 + self.misses)
        if vel is None:
            movement = cfg.max_speed_m_s / self.matcher.m_per_px * dt
            uv = (u_last, v_last)
            radius = base + movement
        else:
            uv = (u_last + vel[0] * dt, v_last + vel[1] * dt)
            movement = math.hypot(vel[0], vel[1]) * dt
            radius = base + cfg.movement_factor * movement
        if radius > cfg.max_search_radius_px:
            return None
        return Prediction(uv=uv, radius_px=radius, movement_px=movement)

    def match(self, template: np.ndarray, t_s: float, mask: np.ndarray | None = None,
              prior_uv: tuple[float, float] | None = None,
              prior_radius_px: float | None = None,
              offset_px: tuple[float, float] = (0.0, 0.0)) -> MatchResult:
        """Predict, match, update. ``prior_uv`` (e.g. from the autopilot) is used only when the
        tracker has no prediction of its own; its search radius defaults to max_search_radius_px.
        ``offset_px``: where the template centre lies relative to the drone (nadir) point, map px
        (``AlignedCapture.centre_offset_px``): the window is placed at the prediction plus it and the
        result is moved back by it, so positions and the track stay the drone's."""
        pred = self.predict(t_s)
        if pred is None and prior_uv is not None:
            radius = self.cfg.max_search_radius_px if prior_radius_px is None else prior_radius_px
            pred = Prediction(uv=prior_uv, radius_px=float(radius), movement_px=0.0)
        self.last_prediction = pred
        du, dv = offset_px
        if pred is None:
            result = self.matcher.match(template, None, None, mask)
        else:
            result = self.matcher.match(template, (pred.uv[0] + du, pred.uv[1] + dv), pred.radius_px, mask)
        if du != 0.0 or dv != 0.0:
            u, v = result.position_px[0] - du, result.position_px[1] - dv
            result = dataclasses.replace(result, position_px=(u, v),
                                         position_enu_m=self.matcher.pixel_to_world(u, v))
        self._update(result, t_s)
        return result

    def _update(self, result: MatchResult, t_s: float) -> None:
        if result.quality_ok:
            if result.search is not SearchMode.WINDOW or self.state is not TrackState.TRACKING:
                self._fixes.clear()          # (re-)acquired: old velocity no longer applies
                self.track_fixes = 0
            self.track_fixes += 1
            if self._fixes and t_s <= self._fixes[-1][0]:
                self._fixes.pop()            # same or older timestamp: keep the newest only
            self._fixes.append((t_s, result.position_px[0], result.position_px[1]))
            self.misses = 0
            self.state = TrackState.TRACKING
            return
        self.misses += 1
        if self.state is TrackState.TRACKING and self.misses >= self.cfg.lost_after_n:
            log.info("tracker lost after %d low-quality matches: global search", self.misses)
            self.state = TrackState.LOST
            self.misses = 0
        elif self.state is not TrackState.TRACKING:
            self.misses = 0      # global search already; do not grow a window we do not use


#: The prior's window covers this many standard deviations of the estimate's horizontal position.
PRIOR_SIGMAS = 3.0


def prior_search_radius_m(position_std_m, m_per_px: float, margin_px: float,
                          max_radius_px: float, min_radius_m: float = 0.0) -> float | None:
    """Search radius (m) around a position estimate of horizontal 1-sigma ``position_std_m`` (x, y,
    ...): ``margin_px`` map pixels plus ``PRIOR_SIGMAS`` sigmas of the horizontal error, at least
    ``min_radius_m``; None (search the whole map) when that exceeds ``max_radius_px`` or the std is
    not finite."""
    sx, sy = float(position_std_m[0]), float(position_std_m[1])
    if not (math.isfinite(sx) and math.isfinite(sy)):
        return None
    radius_m = max(margin_px * m_per_px + PRIOR_SIGMAS * math.hypot(sx, sy), min_radius_m)
    return radius_m if radius_m <= max_radius_px * m_per_px else None
