"""Route planning over an assistant map: potential field first, navigation function as fallback.

``plan_route(probability, m_per_px, start_xy_m, goal_xy_m, cfg)`` is the one entry point (used
by ``scenenav plan`` and, later, the guidance node). Pure numpy/scipy.

Clearance (what the route keeps): the camera footprint is modelled as a disc of diameter
``footprint_m`` centred under the drone. The clearance of a route point is the distance from the
footprint edge to the nearest bad pixel centre (probability < 0.5, and unvisited pixels when
``unvisited_weight`` is 1): distance(point, nearest bad pixel centre) - footprint_m / 2. Every
point of the returned polyline (the straight lines between waypoints, not just the waypoints)
keeps clearance >= ``clearance_m`` -- except, when the start or the goal itself lies closer than
that, the shortest possible stretch needed to leave or reach it (``escape_length_m``).
``min_clearance_m`` is measured at full map resolution on the final polyline (sampled every
half pixel); the planner's own checks use conservative coarse-grid bounds.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from guidance import navigation_function as navfn
from guidance.config import FallbackReason, PlannerConfig, PlannerMethod
from guidance.potential_field import (
    DescentStatus,
    PlanningGrid,
    PotentialField,
    bad_pixel_mask,
    build_grid,
    choose_factor,
    descend,
)
from guidance.smoothing import FieldChecker, densify, polyline_length, round_corners, shortcut, subdivide
from scenenav.core.errors import UserError
from scenenav.core.formats.route_file import round_or_none
from scenenav.core.frames import pixel_to_world, world_to_pixel

log = logging.getLogger(__name__)

_STATUS_TO_REASON = {
    DescentStatus.LOCAL_MINIMUM: FallbackReason.LOCAL_MINIMUM,
    DescentStatus.OSCILLATION: FallbackReason.OSCILLATION,
    DescentStatus.CLEARANCE: FallbackReason.CLEARANCE,
    DescentStatus.MAX_STEPS: FallbackReason.MAX_STEPS,
}
# The potential-field route is replaced when the navigation function's costs < 99 % of it.
_COST_TOLERANCE = 0.99


class NoPathError(UserError):
    """Start and goal lie in different free components: no route keeps the required clearance."""


@dataclass(frozen=True)
class PlannedRoute:
    """A planned route in world ENU metres plus its quality figures (see docs/guidance.md)."""

    waypoints_xy_m: np.ndarray          # (N, 2) east, north; first = start, last = goal
    length_m: float
    min_clearance_m: float              # inf when the map has no bad pixel
    shortest_free_length_m: float
    length_ratio: float
    straight_line_bad_fraction: float
    route_bad_fraction: float
    route_unvisited_fraction: float
    escape_length_m: float
    min_turn_radius_m: float            # inf when the route has no corner
    method: PlannerMethod
    fallback_used: bool
    fallback_reason: FallbackReason
    grid_cell_m: float
    plan_time_s: float
    cfg: PlannerConfig
    raw_path_xy_m: np.ndarray = field(repr=False)       # before smoothing
    shortest_path_xy_m: np.ndarray = field(repr=False)  # shortest obstacle-free path (shortcut)

    def planner_params(self) -> dict:
        """Resolved planner parameters for the route file."""
        c = self.cfg
        return {
            "method": self.method.value,
            "fallback_reason": self.fallback_reason.value,
            "footprint_m": round(c.footprint_width_m, 3),
            "clearance_m": c.clearance_m,
            "required_distance_m": round(c.required_distance_m, 3),
            "bad_probability_threshold": c.bad_probability_threshold,
            "unvisited_weight": c.unvisited_weight,
            "keep_footprint_on_map": c.keep_footprint_on_map,
            "altitude_m": c.altitude_m,
            "cruise_speed_m_s": c.cruise_speed_m_s,
            "max_lateral_accel_m_s2": c.max_lateral_accel_m_s2,
            "turn_radius_m": round(c.turn_radius_m, 3),
            "min_turn_radius_m": round_or_none(self.min_turn_radius_m, 3),
            "waypoint_spacing_m": c.waypoint_spacing_m,
            "influence_distance_m": c.influence_distance_m,
            "attractive_gain": c.attractive_gain,
            "repulsive_gain_m": c.repulsive_gain_m,
            "step_m": c.step_m,
            "nav_repulsive_weight": c.nav_repulsive_weight,
            "grid_cell_m": round(self.grid_cell_m, 4),
            "escape_length_m": round(self.escape_length_m, 3),
            "route_unvisited_fraction": round(self.route_unvisited_fraction, 5),
            "plan_time_s": round(self.plan_time_s, 3),
        }


def _fmt_xy(xy) -> str:
    return f"({xy[0]:.1f}, {xy[1]:.1f}) m"


def validate_probability(probability) -> np.ndarray:
    """The assistant map as a 2-D float array, or a one-line UserError."""
    arr = np.asarray(probability)
    if arr.ndim != 2 or min(arr.shape) < 2:
        raise UserError(f"assistant map: probability has shape {arr.shape}; expected a 2-D H x W array")
    if not np.issubdtype(arr.dtype, np.floating):
        raise UserError(f"assistant map: probability has dtype {arr.dtype}; expected float32 with NaN = unvisited")
    if np.isnan(arr).all():
        raise UserError("assistant map: every cell is NaN (unvisited); expected a map with visited cells")
    return arr


def snap_slack_m(height_px: int, width_px: int, m_per_px: float, cfg: PlannerConfig) -> float:
    """How much further in than the clearance (and the map edge) ``snap_to_good_area`` moves a point:
    the planning grid judges a point by conservative bounds (``PlanningGrid.margin_m``, and a quarter
    cell for the checker's samples), and a moved point this much further in is free there, so the
    route reaches it without an escape through the clearance zone (which can run along the edge)."""
    return choose_factor(height_px, width_px, m_per_px, cfg) * m_per_px * (math.sqrt(2.0) + 0.25) + m_per_px


def snap_to_good_area(probability: np.ndarray, m_per_px: float, xy_m, cfg: PlannerConfig,
                      max_m: float) -> tuple[float, float] | None:
    """``xy_m`` (world metres) itself when it lies on a good matching area (not ``bad_pixel_mask``);
    otherwise the nearest point within ``max_m`` with the route's clearance around it (camera
    footprint half-width + ``clearance_m`` to the nearest bad pixel, plus the planning grid's
    conservative margin, so that the planner counts it free) whose camera footprint lies
    inside the map (``camera_footprint_radius_m`` from every edge: beyond it there is nothing to
    match, and a goal there is hovered over while the vehicle turns); None when there is none. For
    goals given by place rather than by map (a mission reused on another world)."""
    prob = validate_probability(probability)
    h, w = prob.shape
    bad = bad_pixel_mask(prob, cfg)
    u, v = world_to_pixel(float(xy_m[0]), float(xy_m[1]), w, h, m_per_px)
    if 0 <= u < w and 0 <= v < h and not bad[min(int(v), h - 1), min(int(u), w - 1)]:
        return float(xy_m[0]), float(xy_m[1])
    depth_px = ndimage.distance_transform_edt(~bad)
    slack_m = snap_slack_m(h, w, m_per_px, cfg)
    need_px = (cfg.required_distance_m + slack_m) / m_per_px
    r = max_m / m_per_px
    r0, r1 = max(0, int(v - r)), min(h, int(v + r) + 1)
    c0, c1 = max(0, int(u - r)), min(w, int(u + r) + 1)
    edge_px = int(math.ceil((cfg.camera_footprint_radius_m + slack_m) / m_per_px))
    # only candidates whose footprint lies on the map: clip the search window to the inner rectangle
    r0, r1 = max(r0, edge_px), min(r1, h - edge_px)
    c0, c1 = max(c0, edge_px), min(c1, w - edge_px)
    if r0 >= r1 or c0 >= c1:
        return None
    rows, cols = np.nonzero(depth_px[r0:r1, c0:c1] >= need_px)
    if rows.size == 0:
        return None
    d2 = (rows + r0 + 0.5 - v) ** 2 + (cols + c0 + 0.5 - u) ** 2
    k = int(np.argmin(d2))
    if d2[k] > r * r:
        return None
    x, y = pixel_to_world(cols[k] + c0 + 0.5, rows[k] + r0 + 0.5, w, h, m_per_px)
    return float(x), float(y)


def _check_point(prob: np.ndarray, m_per_px: float, xy: np.ndarray, name: str, cfg: PlannerConfig) -> None:
    h, w = prob.shape
    half_w, half_h = w * m_per_px / 2.0, h * m_per_px / 2.0
    if not np.all(np.isfinite(xy)):
        raise UserError(f"{name} {tuple(xy)}: expected finite x,y metres")
    if not (-half_w <= xy[0] < half_w and -half_h < xy[1] <= half_h):
        raise UserError(f"{name} {_fmt_xy(xy)} is outside the map; expected x in [{-half_w:.1f}, {half_w:.1f}) "
                        f"and y in ({-half_h:.1f}, {half_h:.1f}] m (east, north of the map centre)")
    u, v = world_to_pixel(xy[0], xy[1], w, h, m_per_px)
    col, row = min(int(u), w - 1), min(int(v), h - 1)
    p = prob[row, col]
    if np.isnan(p):
        if cfg.unvisited_weight >= 1.0:
            raise UserError(f"{name} {_fmt_xy(xy)} lies on an unvisited cell, an obstacle with "
                            "unvisited_weight = 1; expected a point on a good matching area")
    elif p < cfg.bad_probability_threshold:
        raise UserError(f"{name} {_fmt_xy(xy)} lies in a bad matching area (probability {p:.2f} < "
                        f"{cfg.bad_probability_threshold}); expected a point on a good matching area")


def _escape_cells(grid: PlanningGrid, cfree: np.ndarray, ends: list[tuple[int, int]]) -> np.ndarray:
    """Non-free, non-bad cells connected to a start/goal cell that is itself not free."""
    escape = np.zeros_like(cfree)
    near = grid.inside & ~grid.bad & ~cfree
    todo = [rc for rc in ends if not cfree[rc]]
    if not todo:
        return escape
    for rc in todo:
        near[rc] = True
    labels, _ = ndimage.label(near, structure=np.ones((3, 3), dtype=bool))
    for rc in todo:
        escape |= labels == labels[rc]
    return escape


def _cells_to_points(grid: PlanningGrid, cells: np.ndarray, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    centres = grid.cell_centre_xy(cells[:, 0], cells[:, 1])
    return np.vstack([start[None, :], centres, goal[None, :]])


def _check_escape_interior(cells: np.ndarray, cfree: np.ndarray, start, goal, cfg: PlannerConfig) -> None:
    free = cfree[cells[:, 0], cells[:, 1]]
    if not free.any():
        return
    first = int(np.argmax(free))
    last = len(free) - 1 - int(np.argmax(free[::-1]))
    if not free[first:last + 1].all():
        raise NoPathError(
            f"no route from start {_fmt_xy(start)} to goal {_fmt_xy(goal)} keeps the footprint "
            f"({cfg.footprint_width_m:.1f} m) {cfg.clearance_m:g} m clear of bad matching areas: the only "
            "connections are too narrow; expected a goal reachable through wider good areas "
            "(or a smaller --clearance-m / --footprint-m)")


def _no_path(start, goal, cfg: PlannerConfig) -> NoPathError:
    return NoPathError(
        f"no route from start {_fmt_xy(start)} to goal {_fmt_xy(goal)}: they lie in different free "
        f"components when the footprint ({cfg.footprint_width_m:.1f} m) keeps {cfg.clearance_m:g} m from bad "
        "matching areas; expected a goal reachable through good areas (or a smaller --clearance-m / --footprint-m)")


def exact_min_distance_m(bad_px: np.ndarray, grid: PlanningGrid, samples_xy_m: np.ndarray) -> float:
    """Minimum over samples of the distance (m) to the nearest bad pixel centre, at full resolution.

    Coarse distances bound the true one within +-margin_m; only samples whose lower bound can beat
    the best upper bound are evaluated exactly, a chunk at a time, against the boundary pixels of
    the bad set inside a window around the chunk.
    """
    rows, cols = grid.cells_of_xy(samples_xy_m)
    coarse = grid.dist_bad_m[rows, cols]
    if not np.isfinite(coarse).any():
        return math.inf
    lower = coarse - grid.margin_m
    best = float((coarse + grid.margin_m).min())
    h, w = bad_px.shape
    u, v = world_to_pixel(samples_xy_m[:, 0], samples_xy_m[:, 1], w, h, grid.m_per_px)
    order = np.flatnonzero(lower <= best)
    chunk = 256
    for k in range(0, len(order), chunk):
        idx = order[k:k + chunk]
        idx = idx[lower[idx] <= best]
        if idx.size == 0:
            continue
        reach_px = best / grid.m_per_px + 2.0
        r0 = max(0, int(math.floor(v[idx].min() - reach_px)))
        r1 = min(h, int(math.ceil(v[idx].max() + reach_px)) + 1)
        c0 = max(0, int(math.floor(u[idx].min() - reach_px)))
        c1 = min(w, int(math.ceil(u[idx].max() + reach_px)) + 1)
        sub = bad_px[r0:r1, c0:c1]
        if not sub.any():
            continue
        edge = sub & ~ndimage.binary_erosion(sub, border_value=1)
        rr, cc = np.nonzero(edge)
        tree = cKDTree(np.column_stack([cc + c0 + 0.5, rr + r0 + 0.5]))
        d, _ = tree.query(np.column_stack([u[idx], v[idx]]))
        best = min(best, float(d.min()) * grid.m_per_px)
    return best


def _fraction(prob: np.ndarray, m_per_px: float, samples_xy_m: np.ndarray, threshold: float) -> tuple[float, float]:
    """Shares of samples whose nadir pixel is bad (p < threshold) and unvisited (NaN)."""
    h, w = prob.shape
    u, v = world_to_pixel(samples_xy_m[:, 0], samples_xy_m[:, 1], w, h, m_per_px)
    cols = np.clip(np.floor(u).astype(np.int64), 0, w - 1)
    rows = np.clip(np.floor(v).astype(np.int64), 0, h - 1)
    p = prob[rows, cols]
    with np.errstate(invalid="ignore"):
        bad = float(np.mean(p < threshold))
    return bad, float(np.mean(np.isnan(p)))


def _touches_unvisited(grid: PlanningGrid, path: np.ndarray) -> bool:
    rows, cols = grid.cells_of_xy(densify(path, grid.cell_m / 2.0))
    return bool((grid.unvisited_share[rows, cols] > 0.0).any())


def _navigation_route(grid: PlanningGrid, edges: navfn.GridEdges, nav_cost: np.ndarray, cfree: np.ndarray,
                      checker: FieldChecker, s_rc, g_rc, start, goal, cfg: PlannerConfig) -> np.ndarray:
    """Descend the navigation function and shortcut the result."""
    cells, _ = navfn.plan_on_grid(edges, nav_cost, s_rc, g_rc)
    if cells is None:  # cannot happen after the shortest path: same graph connectivity
        raise _no_path(start, goal, cfg)
    _check_escape_interior(cells, cfree, start, goal, cfg)
    return shortcut(_cells_to_points(grid, cells, start, goal), checker, cfg.clearance_m, use_cost=True)


def plan_route(probability: np.ndarray, m_per_px: float, start_xy_m, goal_xy_m,
               cfg: PlannerConfig | None = None, names: tuple[str, str] = ("start", "goal")) -> PlannedRoute:
    """Plan a route from ``start_xy_m`` to ``goal_xy_m`` (world ENU metres) over an assistant map.

    Raises ``UserError`` for bad input (start/goal outside the map or in a bad area, malformed
    map) and ``NoPathError`` when no route keeps the clearance.
    """
    t0 = time.perf_counter()
    cfg = cfg or PlannerConfig()
    prob = validate_probability(probability)
    if not (isinstance(m_per_px, (int, float)) and math.isfinite(m_per_px) and m_per_px > 0):
        raise UserError(f"m_per_px = {m_per_px!r}: expected a positive number of metres per pixel")
    m_per_px = float(m_per_px)
    start = np.asarray(start_xy_m, dtype=float).reshape(2)
    goal = np.asarray(goal_xy_m, dtype=float).reshape(2)
    _check_point(prob, m_per_px, start, names[0], cfg)
    _check_point(prob, m_per_px, goal, names[1], cfg)

    grid = build_grid(prob, m_per_px, cfg)
    radius = cfg.footprint_width_m / 2.0
    half_sample = grid.cell_m / 4.0  # FieldChecker samples every cell_m / 2
    clearance = grid.clearance_lb_m(radius)
    if cfg.keep_footprint_on_map:    # the map's edge as one more obstacle, kept the camera footprint away
        clearance = np.minimum(clearance, grid.edge_distance_lb_m() - cfg.camera_footprint_radius_m
                               + cfg.clearance_m)
    cfree = grid.inside & ~grid.bad & (clearance - half_sample >= cfg.clearance_m)
    s_rc = tuple(int(a) for a in grid.cells_of_xy(start))
    g_rc = tuple(int(a) for a in grid.cells_of_xy(goal))
    escape = _escape_cells(grid, cfree, [s_rc, g_rc])
    trav = cfree | escape
    nav_cost = navfn.cost_per_m(grid, cfg)
    nav_cost[escape] *= navfn.ESCAPE_COST_FACTOR
    length_cost = np.ones_like(nav_cost)
    length_cost[escape] *= navfn.ESCAPE_COST_FACTOR
    nav_checker = FieldChecker(grid=grid, clearance_m=clearance, passable=trav, cost_per_m=nav_cost)
    len_checker = FieldChecker(grid=grid, clearance_m=clearance, passable=trav, cost_per_m=length_cost)

    # Shortest obstacle-free path (reference, and the connectivity test).
    edges = navfn.grid_edges(trav, grid.cell_m)
    cells, _ = navfn.plan_on_grid(edges, length_cost, s_rc, g_rc)
    if cells is None:
        raise _no_path(start, goal, cfg)
    _check_escape_interior(cells, cfree, start, goal, cfg)
    shortest_pts = shortcut(_cells_to_points(grid, cells, start, goal), len_checker, cfg.clearance_m,
                            use_cost=False)
    shortest_len = polyline_length(shortest_pts)

    # Classic potential field first.
    reason = FallbackReason.NONE
    path = None
    if cfree[s_rc] and cfree[g_rc]:
        pf = PotentialField.build(grid, goal, cfg)
        result = descend(pf, start, cfree)
        if result.status is DescentStatus.REACHED:
            raw = result.path_xy_m.copy()
            raw[0], raw[-1] = start, goal
            if nav_checker.polyline(raw).min_clearance_m < cfg.clearance_m - 1e-9:
                reason = FallbackReason.CLEARANCE
            else:
                path = shortcut(raw, nav_checker, cfg.clearance_m, use_cost=True)
                if polyline_length(path) > cfg.pf_max_length_ratio * max(shortest_len, 1e-9):
                    reason = FallbackReason.TOO_LONG
                    path = None
        else:
            reason = _STATUS_TO_REASON[result.status]
    else:
        reason = FallbackReason.START_OR_GOAL_IN_CLEARANCE_ZONE

    nav_path = None
    if path is not None and cfg.unvisited_weight > 0.0 and _touches_unvisited(grid, path):
        # Soft obstacles deflect the descent but cannot stop it: keep the potential-field route
        # only if it does not cost more than the navigation function's.
        nav_path = _navigation_route(grid, edges, nav_cost, cfree, nav_checker, s_rc, g_rc, start, goal, cfg)
        if nav_checker.polyline(nav_path).cost < _COST_TOLERANCE * nav_checker.polyline(path).cost:
            reason = FallbackReason.HIGHER_COST
            path = None
    if path is None:
        log.info("potential field abandoned (%s); descending the navigation function", reason.value)
        if nav_path is None:
            nav_path = _navigation_route(grid, edges, nav_cost, cfree, nav_checker, s_rc, g_rc, start, goal, cfg)
        path = nav_path
        method = PlannerMethod.NAVIGATION_FUNCTION
    else:
        method = PlannerMethod.POTENTIAL_FIELD

    rounded, radii = round_corners(path, nav_checker, cfg.clearance_m, cfg.turn_radius_m,
                                   cfg.arc_chord_tolerance_m, cfg.waypoint_spacing_m)
    waypoints = subdivide(rounded, cfg.waypoint_spacing_m)
    waypoints[0], waypoints[-1] = start, goal

    # Quality figures at full resolution.
    bad_px = bad_pixel_mask(prob, cfg)
    samples = densify(waypoints, m_per_px / 2.0)
    min_dist = exact_min_distance_m(bad_px, grid, samples)
    min_clear = min_dist - radius
    route_bad, route_unv = _fraction(prob, m_per_px, samples, cfg.bad_probability_threshold)
    line = densify(np.array([start, goal]), m_per_px / 2.0)
    line_bad, _ = _fraction(prob, m_per_px, line, cfg.bad_probability_threshold)
    escape_len = 0.0
    if escape.any() and len(samples) > 1:
        r_rows, r_cols = grid.cells_of_xy(samples)
        in_zone = escape[r_rows, r_cols]
        step_len = np.hypot(*np.diff(samples, axis=0).T)
        escape_len = float((step_len * (in_zone[1:] | in_zone[:-1])).sum())
        log.warning("start or goal lies closer to bad area than the clearance: %.1f m of the route "
                    "are inside the clearance zone", escape_len)
    length = polyline_length(waypoints)
    ratio = length / shortest_len if shortest_len > 0 else 1.0
    elapsed = time.perf_counter() - t0
    log.info("route %.0f m (%.2fx shortest free %.0f m), min clearance %.1f m, %s in %.2f s",
             length, ratio, shortest_len, min_clear, method.value, elapsed)
    return PlannedRoute(
        waypoints_xy_m=waypoints, length_m=length, min_clearance_m=min_clear,
        shortest_free_length_m=shortest_len, length_ratio=ratio, straight_line_bad_fraction=line_bad,
        route_bad_fraction=route_bad, route_unvisited_fraction=route_unv, escape_length_m=escape_len,
        min_turn_radius_m=min(radii) if radii else math.inf, method=method,
        fallback_used=method is PlannerMethod.NAVIGATION_FUNCTION, fallback_reason=reason,
        grid_cell_m=grid.cell_m, plan_time_s=elapsed, cfg=cfg, raw_path_xy_m=path,
        shortest_path_xy_m=shortest_pts)


def plan_escaping(probability: np.ndarray, m_per_px: float, points_xy_m, cfg: PlannerConfig,
                  escape_m: float) -> tuple[list[PlannedRoute], np.ndarray, tuple[float, float] | None]:
    """:func:`plan_through`, except that a start lying *on* a bad matching area (where the vehicle
    is, not where it is asked to go: a take-off point, a position after drifting) is left by the
    shortest way: the legs start at the nearest point with the route's clearance within ``escape_m``
    (:func:`snap_to_good_area`) and the route begins with the straight hop there. Returns (legs,
    route waypoints, the point the route escapes to or None). ``escape_m`` 0, or no such point
    within it, plans from the start itself (and says why there is no route)."""
    pts = [tuple(float(c) for c in p) for p in np.asarray(points_xy_m, dtype=float).reshape(-1, 2)]
    escaped = None
    if escape_m > 0.0 and len(pts) >= 2:
        moved = snap_to_good_area(probability, m_per_px, pts[0], cfg, escape_m)
        if moved is not None and moved != pts[0]:
            escaped = moved
    legs = plan_through(probability, m_per_px, [escaped or pts[0], *pts[1:]], cfg)
    route = join_legs(legs)
    if escaped is not None:
        route = np.vstack([np.asarray(pts[0], dtype=float)[None, :], route])
    return legs, route, escaped


def plan_keeping_on_map(probability: np.ndarray, m_per_px: float, points_xy_m, cfg: PlannerConfig,
                        escape_m: float) -> tuple[list[PlannedRoute], np.ndarray, tuple[float, float] | None, bool]:
    """:func:`plan_escaping`; when ``cfg.keep_footprint_on_map`` leaves no route (a goal reachable only
    along the map's edge), plan again without it: a route whose captures may leave the map for a
    while is better than none. Returns (legs, route, escape point or None, whether the footprint was
    kept on the map). ``NoPathError`` only when there is no route either way."""
    try:
        legs, route, escaped = plan_escaping(probability, m_per_px, points_xy_m, cfg, escape_m)
        return legs, route, escaped, cfg.keep_footprint_on_map
    except NoPathError:
        if not cfg.keep_footprint_on_map:
            raise
    relaxed = dataclasses.replace(cfg, keep_footprint_on_map=False)
    legs, route, escaped = plan_escaping(probability, m_per_px, points_xy_m, relaxed, escape_m)
    return legs, route, escaped, False


def plan_through(probability: np.ndarray, m_per_px: float, points_xy_m,
                 cfg: PlannerConfig | None = None) -> list[PlannedRoute]:
    """Plan one route per leg through ``points_xy_m`` (start, via-points..., goal), in order.

    Each leg is :func:`plan_route` between consecutive points (so each keeps the clearance and says
    clearly when no route exists); :func:`join_legs` turns the legs into one waypoint list.
    """
    pts = np.asarray(points_xy_m, dtype=float).reshape(-1, 2)
    if len(pts) < 2:
        raise UserError(f"{len(pts)} point(s): expected a start and at least one goal")
    names = ["start"] + [f"goal {i + 1}" for i in range(len(pts) - 1)]
    return [plan_route(probability, m_per_px, pts[i], pts[i + 1], cfg, names=(names[i], names[i + 1]))
            for i in range(len(pts) - 1)]


def join_legs(legs: list[PlannedRoute]) -> np.ndarray:
    """(N, 2) waypoints of consecutive legs, the shared end/start points kept once."""
    parts = [legs[0].waypoints_xy_m]
    for leg in legs[1:]:
        parts.append(leg.waypoints_xy_m[1:])
    return np.vstack(parts)
