"""Turn a grid path into flyable waypoints: shortcut, round corners, resample (world metres).

1. ``shortcut``: greedy line-of-sight simplification. From each anchor the farthest later vertex
   (galloping then bisection) whose straight segment keeps the clearance floor and, for the
   planned route, does not cost more than the sub-path it replaces (so the repulsive cost that
   keeps the route away from bad areas is not thrown away).
2. ``round_corners``: each interior vertex becomes a circular arc of the turn radius v^2 / a_lat,
   tangent to both legs, discretised into chords with sagitta <= ``arc_chord_tolerance_m``.
   Tangent lengths are limited to half of each leg; an arc whose chords break the clearance
   floor is retried with half the radius, down to a sharp corner (radius 0).
3. ``subdivide``: straight legs split into equal pieces no longer than the waypoint spacing.
   The flown polyline (straight lines between waypoints) is exactly the checked geometry.

The clearance floor of a replacement is min(required clearance, clearance of what it replaces),
so a route that starts or ends inside a clearance zone never gets worse there, and the rest of
the route keeps the required clearance.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from guidance.potential_field import PlanningGrid

log = logging.getLogger(__name__)

_EPS = 1e-9
_MIN_DEFLECTION_RAD = math.radians(1.0)


@dataclass(frozen=True)
class SegmentStats:
    """Conservative clearance, passability and integrated cost of a straight segment."""

    min_clearance_m: float
    passable: bool
    cost: float


@dataclass(frozen=True)
class FieldChecker:
    """Checks straight segments against per-cell fields of a planning grid.

    ``clearance_m`` is the per-cell lower bound of the footprint-edge-to-bad-pixel distance
    for any point of the cell; samples are ``spacing_m`` apart and the bound of a segment
    subtracts spacing_m / 2 so that points between samples are covered too.
    """

    grid: PlanningGrid
    clearance_m: np.ndarray
    passable: np.ndarray
    cost_per_m: np.ndarray

    @property
    def spacing_m(self) -> float:
        return self.grid.cell_m / 2.0

    def sample(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        length = float(np.hypot(*(b - a)))
        n = max(1, int(math.ceil(length / self.spacing_m)))
        t = np.linspace(0.0, 1.0, n + 1)[:, None]
        return a[None, :] * (1.0 - t) + b[None, :] * t

    def segment(self, a, b) -> SegmentStats:
        a = np.asarray(a, dtype=float)
        b = np.asarray(b, dtype=float)
        pts = self.sample(a, b)
        rows, cols = self.grid.cells_of_xy(pts)
        clear = float(self.clearance_m[rows, cols].min()) - self.spacing_m / 2.0
        passable = bool(self.passable[rows, cols].all())
        length = float(np.hypot(*(b - a)))
        costs = self.cost_per_m[rows, cols]
        cost = float(0.5 * (costs[1:] + costs[:-1]).sum() * length / max(1, len(pts) - 1))
        return SegmentStats(min_clearance_m=clear, passable=passable, cost=cost)

    def polyline(self, points: np.ndarray) -> SegmentStats:
        stats = [self.segment(points[i], points[i + 1]) for i in range(len(points) - 1)]
        if not stats:
            return SegmentStats(math.inf, True, 0.0)
        return SegmentStats(min(s.min_clearance_m for s in stats), all(s.passable for s in stats),
                            sum(s.cost for s in stats))


def polyline_length(points: np.ndarray) -> float:
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return 0.0
    return float(np.hypot(*np.diff(pts, axis=0).T).sum())


def dedupe(points: np.ndarray, tol_m: float = 1e-6) -> np.ndarray:
    """Drop consecutive duplicate points."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return pts
    keep = np.ones(len(pts), dtype=bool)
    keep[1:] = np.hypot(*np.diff(pts, axis=0).T) > tol_m
    keep[-1] = True
    out = pts[keep]
    if len(out) >= 2 and np.hypot(*(out[-1] - out[-2])) <= tol_m:
        out = np.delete(out, -2, axis=0)
    return out


def shortcut(points: np.ndarray, checker: FieldChecker, required_m: float, use_cost: bool,
             max_passes: int = 3) -> np.ndarray:
    """Greedy line-of-sight simplification keeping the clearance floor (and cost, if asked).

    Repeated (up to ``max_passes``) while it still removes vertices: the greedy galloping search
    is not monotonic, so a second pass over the fewer, farther vertices often shortens more.
    """
    pts = dedupe(points)
    for _ in range(max_passes):
        before = len(pts)
        pts = _shortcut_pass(pts, checker, required_m, use_cost)
        if len(pts) == before:
            break
    return pts


def _shortcut_pass(pts: np.ndarray, checker: FieldChecker, required_m: float, use_cost: bool) -> np.ndarray:
    n = len(pts)
    if n <= 2:
        return pts
    segs = [checker.segment(pts[k], pts[k + 1]) for k in range(n - 1)]
    seg_clear = np.array([s.min_clearance_m for s in segs])
    prefix_cost = np.concatenate([[0.0], np.cumsum([s.cost for s in segs])])

    def ok(i: int, j: int) -> bool:
        if j == i + 1:
            return True
        floor = min(required_m, float(seg_clear[i:j].min()))
        stats = checker.segment(pts[i], pts[j])
        if not stats.passable or stats.min_clearance_m < floor - _EPS:
            return False
        return not use_cost or stats.cost <= prefix_cost[j] - prefix_cost[i] + 1e-6

    out = [0]
    i = 0
    while i < n - 1:
        good = i + 1
        step = 1
        bad = None
        while good < n - 1:
            j = min(i + 2 * step, n - 1)
            if ok(i, j):
                good = j
                step *= 2
            else:
                bad = j
                break
        if bad is not None:
            lo, hi = good, bad
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if ok(i, mid):
                    lo = mid
                else:
                    hi = mid
            good = lo
        out.append(good)
        i = good
    return pts[out]


def _rotate(v: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _arc(prev_pt, vertex, next_pt, radius_m: float, chord_tol_m: float, max_chord_m: float):
    """Chord points of the arc tangent to both legs at a vertex, and the radius actually used."""
    d1 = vertex - prev_pt
    d2 = next_pt - vertex
    l1, l2 = float(np.hypot(*d1)), float(np.hypot(*d2))
    d1, d2 = d1 / l1, d2 / l2
    theta = math.atan2(d1[0] * d2[1] - d1[1] * d2[0], float(np.dot(d1, d2)))
    half = abs(theta) / 2.0
    if abs(theta) < _MIN_DEFLECTION_RAD or half >= math.pi / 2.0 - 1e-6:
        return None, 0.0
    tangent = radius_m * math.tan(half)
    t_max = 0.5 * min(l1, l2)
    if tangent > t_max:
        tangent = t_max
        radius_m = tangent / math.tan(half)
    t1 = vertex - d1 * tangent
    normal = np.array([-d1[1], d1[0]]) * (1.0 if theta > 0 else -1.0)
    centre = t1 + normal * radius_m
    step = math.pi / 2.0
    if chord_tol_m < radius_m:
        step = min(step, 2.0 * math.acos(1.0 - chord_tol_m / radius_m))
    if max_chord_m < 2.0 * radius_m:
        step = min(step, 2.0 * math.asin(max_chord_m / (2.0 * radius_m)))
    n = max(1, int(math.ceil(abs(theta) / step)))
    rel = t1 - centre
    pts = np.array([centre + _rotate(rel, theta * k / n) for k in range(n + 1)])
    return pts, radius_m


def round_corners(points: np.ndarray, checker: FieldChecker, required_m: float, radius_m: float,
                  chord_tol_m: float, max_chord_m: float) -> tuple[np.ndarray, list[float]]:
    """Replace interior vertices by chord-discretised arcs; returns points and per-corner radii."""
    pts = dedupe(points)
    if len(pts) <= 2 or radius_m <= 0:
        return pts, []
    min_radius = checker.grid.cell_m / 2.0
    out = [pts[0]]
    radii: list[float] = []
    for k in range(1, len(pts) - 1):
        prev_pt, vertex, next_pt = pts[k - 1], pts[k], pts[k + 1]
        legs = checker.polyline(np.array([prev_pt, vertex, next_pt]))
        floor = min(required_m, legs.min_clearance_m)
        r = radius_m
        arc = None
        used = 0.0
        while r >= min_radius:
            cand, used = _arc(prev_pt, vertex, next_pt, r, chord_tol_m, max_chord_m)
            if cand is None:
                break
            stats = checker.polyline(cand)
            if stats.passable and stats.min_clearance_m >= floor - _EPS:
                arc = cand
                break
            r = used / 2.0
        if arc is None:
            out.append(vertex)
            deflection = _deflection(prev_pt, vertex, next_pt)
            if deflection >= _MIN_DEFLECTION_RAD:
                radii.append(0.0)
        else:
            out.extend(arc)
            radii.append(used)
    out.append(pts[-1])
    return dedupe(np.asarray(out)), radii


def _deflection(a, b, c) -> float:
    d1 = b - a
    d2 = c - b
    return abs(math.atan2(d1[0] * d2[1] - d1[1] * d2[0], float(np.dot(d1, d2))))


def subdivide(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """Split every leg into equal pieces no longer than ``spacing_m`` (keeps every vertex)."""
    pts = dedupe(points)
    out = [pts[0]]
    for a, b in zip(pts[:-1], pts[1:], strict=False):
        n = max(1, int(math.ceil(float(np.hypot(*(b - a))) / spacing_m - 1e-9)))
        for k in range(1, n + 1):
            out.append(a + (b - a) * (k / n))
    return np.asarray(out)


def densify(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """Samples along a polyline at most ``spacing_m`` apart (including every vertex)."""
    return subdivide(points, spacing_m)
