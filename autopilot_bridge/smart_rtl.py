"""SMART_RTL: the breadcrumb path recorded in flight and the law that flies it back home (pure).

As ArduPilot's ``AP_SmartRTL`` and ArduCopter's ``mode_smart_rtl.cpp`` (read for behaviour):

* recording starts at arming, the first point being where the vehicle armed (home); a point is
  added when the vehicle is more than SRTL_ACCURACY (m) from the last one; SRTL_POINTS (0
  disables) bounds the buffer;
* when the buffer is full the path is simplified (Ramer-Douglas-Peucker with SRTL_ACCURACY / 2, as
  ArduPilot's ``SMARTRTL_SIMPLIFY_EPSILON``); if it is still full, recording stops and the path is
  unusable: "SmartRTL deactivated: buffer full". Differs: ArduPilot also prunes loops (where the
  path crosses itself within SRTL_ACCURACY), which shortens the way back; that is not done here;
* the mode brakes to a stop and then follows the points back, newest first, at WPNAV_SPEED; the
  last point, home, is flown to 2 m above it (ArduCopter adds 2 m for the final leg), and the
  flight core then lands (LAND, or RTL when RTL_ALT_FINAL > 0, as ArduCopter);
* an unusable path refuses the mode ("SmartRTL: path unavailable"); the failsafes that ask for
  SmartRTL fall back to RTL: "SmartRTL Unavailable, Trying RTL Mode".

Positions are world ENU metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from autopilot_bridge.config import GuidanceConfig
from autopilot_bridge.flight_laws import LawKind, Tracker
from autopilot_bridge.guidance_law import Waypoint

# ArduCopter mode_smart_rtl.cpp: the final point (home) is approached 2 m above it.
FINAL_POINT_CLIMB_M = 2.0
# AP_SmartRTL.h: SMARTRTL_SIMPLIFY_EPSILON = accuracy * 0.5
SIMPLIFY_EPSILON_FRACTION = 0.5


def simplify(points: Sequence[np.ndarray], epsilon_m: float) -> list[np.ndarray]:
    """Ramer-Douglas-Peucker: drop the points within ``epsilon_m`` of the line that replaces them
    (3-D distance to the segment); the first and last points always stay."""
    pts = [np.asarray(p, dtype=float) for p in points]
    if len(pts) < 3:
        return pts
    keep = [False] * len(pts)
    keep[0] = keep[-1] = True
    stack = [(0, len(pts) - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        seg = pts[b] - pts[a]
        length2 = float(seg @ seg)
        best, best_d = -1, -1.0
        for i in range(a + 1, b):
            rel = pts[i] - pts[a]
            t = 0.0 if length2 == 0.0 else min(max(float(rel @ seg) / length2, 0.0), 1.0)
            d = float(np.linalg.norm(rel - t * seg))
            if d > best_d:
                best, best_d = i, d
        if best_d > epsilon_m:
            keep[best] = True
            stack.append((a, best))
            stack.append((best, b))
    return [p for p, k in zip(pts, keep, strict=True) if k]


class BreadcrumbPath:
    """The recorded path; ``usable`` once armed with at least the start point and not overflowed."""

    def __init__(self) -> None:
        self._points: list[np.ndarray] = []
        self._accuracy_m = 2.0
        self._max_points = 300
        self.active = False
        self.deactivated_reason = ""

    @property
    def points(self) -> list[np.ndarray]:
        return [p.copy() for p in self._points]

    @property
    def usable(self) -> bool:
        return self.active and len(self._points) >= 1

    def start(self, position_enu_m, accuracy_m: float, max_points: int) -> None:
        """Arming: begin a new path at ``position_enu_m`` (SRTL_POINTS 0 leaves it inactive)."""
        self._accuracy_m = max(float(accuracy_m), 0.0)
        self._max_points = int(max_points)
        self._points = [np.asarray(position_enu_m, dtype=float)[:3].copy()]
        self.active = self._max_points > 0
        self.deactivated_reason = "" if self.active else "SRTL_POINTS is 0"

    def stop(self) -> None:
        self.active = False
        self._points = []

    def handle_position_reset(self, delta_xy_m) -> None:
        d = np.array([float(delta_xy_m[0]), float(delta_xy_m[1]), 0.0])
        self._points = [p + d for p in self._points]

    def add(self, position_enu_m) -> str | None:
        """Record ``position_enu_m`` if it is far enough from the last point; returns the
        deactivation message when the buffer overflowed (once)."""
        if not self.active:
            return None
        p = np.asarray(position_enu_m, dtype=float)[:3]
        last = self._points[-1]
        dx, dy, dz = (float(p[0] - last[0]), float(p[1] - last[1]), float(p[2] - last[2]))
        if math.sqrt(dx * dx + dy * dy + dz * dz) <= self._accuracy_m:
            return None
        if len(self._points) >= self._max_points:
            self._points = simplify(self._points, self._accuracy_m * SIMPLIFY_EPSILON_FRACTION)
            if len(self._points) >= self._max_points:
                self.active = False
                self.deactivated_reason = "buffer full"
                return "SmartRTL deactivated: buffer full"
        self._points.append(p.copy())
        return None

    def route_home(self, start_enu_m) -> list[np.ndarray]:
        """The way back: the recorded points newest first (those within SRTL_ACCURACY of
        ``start_enu_m`` dropped), home last and raised by 2 m."""
        pts = simplify(self._points, self._accuracy_m * SIMPLIFY_EPSILON_FRACTION)
        back = list(reversed(pts))
        start = np.asarray(start_enu_m, dtype=float)[:3]
        while len(back) > 1 and float(np.linalg.norm(back[0] - start)) <= self._accuracy_m:
            back.pop(0)
        back[-1] = back[-1] + np.array([0.0, 0.0, FINAL_POINT_CLIMB_M])
        return back


def smart_rtl_law(cfg: GuidanceConfig, path: BreadcrumbPath, start_enu_m) -> Tracker:
    """The tracker that flies ``path`` back home from ``start_enu_m`` (the stopping point)."""
    wps = [Waypoint(tuple(float(a) for a in p)) for p in path.route_home(start_enu_m)]
    law = Tracker(cfg, wps, start_enu_m)
    law.kind = LawKind.SMART_RTL
    return law
