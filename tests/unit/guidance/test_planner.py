"""plan_route on synthetic maps: fallback, clearance at full resolution, errors, smoothing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from guidance.config import FallbackReason, PlannerConfig, PlannerMethod
from guidance.planner import NoPathError, plan_route
from guidance.smoothing import densify, polyline_length, subdivide
from scenenav.core.errors import UserError
from scenenav.core.frames import pixel_to_world

GOOD, BAD = 0.9, 0.1
M_PER_PX = 2.0
LAKE_R_M = 80.0


def u_trap_map() -> np.ndarray:
    """400 m x 400 m at 2 m/px; a U of bad area opening west, in front of a goal in the east."""
    prob = np.full((200, 200), GOOD, dtype=np.float32)
    prob[20:181, 120:126] = BAD     # bottom of the U: x 40..52 m, y -160..160 m
    prob[20:26, 60:126] = BAD       # north arm
    prob[175:181, 60:126] = BAD     # south arm
    return prob


def u_trap_cfg() -> PlannerConfig:
    return PlannerConfig(footprint_m=20.0, clearance_m=5.0, grid_cell_m=2.0, unvisited_weight=0.0)


def lake_map(size_px: int = 300) -> np.ndarray:
    """600 m square at 2 m/px with a round lake (bad) of radius 80 m at the centre."""
    prob = np.full((size_px, size_px), GOOD, dtype=np.float32)
    v, u = np.mgrid[0:size_px, 0:size_px]
    x, y = pixel_to_world(u + 0.5, v + 0.5, size_px, size_px, M_PER_PX)
    prob[np.hypot(x, y) <= LAKE_R_M] = BAD
    return prob


def lake_cfg(**kw) -> PlannerConfig:
    base = dict(footprint_m=60.0, clearance_m=10.0, unvisited_weight=0.0)
    base.update(kw)
    return PlannerConfig(**base)


def distances_to_bad_m(prob: np.ndarray, m_per_px: float, points_xy: np.ndarray) -> np.ndarray:
    """Exact distance from points to the nearest bad pixel centre, full resolution (independent)."""
    h, w = prob.shape
    rows, cols = np.nonzero(prob < 0.5)
    bx, by = pixel_to_world(cols + 0.5, rows + 0.5, w, h, m_per_px)
    d, _ = cKDTree(np.column_stack([bx, by])).query(points_xy)
    return d


def test_u_trap_falls_back_to_navigation_function_and_reaches_goal():
    cfg = u_trap_cfg()
    prob = u_trap_map()
    route = plan_route(prob, M_PER_PX, (-150.0, 0.0), (150.0, 0.0), cfg)
    assert route.fallback_used
    assert route.method is PlannerMethod.NAVIGATION_FUNCTION
    assert route.fallback_reason in (FallbackReason.LOCAL_MINIMUM, FallbackReason.OSCILLATION)
    wp = route.waypoints_xy_m
    assert wp[0] == pytest.approx([-150.0, 0.0]) and wp[-1] == pytest.approx([150.0, 0.0])
    d = distances_to_bad_m(prob, M_PER_PX, densify(wp, 0.5))
    assert d.min() - cfg.footprint_width_m / 2.0 >= cfg.clearance_m - 1e-6
    assert route.length_m <= 1.5 * route.shortest_free_length_m


def test_lake_route_keeps_clearance_and_is_short():
    cfg = lake_cfg()
    prob = lake_map()
    start, goal = (-250.0, 0.0), (250.0, 0.0)
    route = plan_route(prob, M_PER_PX, start, goal, cfg)
    assert route.straight_line_bad_fraction == pytest.approx(2 * LAKE_R_M / 500.0, abs=0.02)
    assert route.route_bad_fraction == 0.0
    wp = route.waypoints_xy_m
    assert wp[0] == pytest.approx(start) and wp[-1] == pytest.approx(goal)
    # Clearance = distance from the footprint edge (radius 30 m) to the nearest bad pixel centre,
    # checked at full resolution on the flown polyline, not only at the waypoints.
    clearance = distances_to_bad_m(prob, M_PER_PX, densify(wp, 0.25)) - cfg.footprint_width_m / 2.0
    assert clearance.min() >= cfg.clearance_m - 1e-6
    assert route.min_clearance_m == pytest.approx(clearance.min(), abs=0.3)
    # Shortest free path by hand: around a disc of radius 80 + 30 + 10 = 120 m from 250 m away,
    # 2 * sqrt(250^2 - 120^2) + 120 * (pi - 2 acos(120/250)) = 558.8 m (plus grid margins).
    assert 555.0 <= route.shortest_free_length_m <= 600.0
    assert route.length_m <= 1.5 * route.shortest_free_length_m
    assert route.escape_length_m == 0.0
    # Waypoints: consecutive spacing at most the configured spacing.
    assert np.hypot(*np.diff(wp, axis=0).T).max() <= cfg.waypoint_spacing_m + 1e-6


def test_enclosed_goal_raises_no_path():
    prob = np.full((200, 200), GOOD, dtype=np.float32)
    v, u = np.mgrid[0:200, 0:200]
    x, y = pixel_to_world(u + 0.5, v + 0.5, 200, 200, M_PER_PX)
    ring = np.hypot(x - 100.0, y)
    prob[(ring >= 50.0) & (ring <= 60.0)] = BAD
    with pytest.raises(NoPathError) as exc:
        plan_route(prob, M_PER_PX, (-150.0, 0.0), (100.0, 0.0), lake_cfg(footprint_m=10.0, clearance_m=2.0))
    assert isinstance(exc.value, UserError) and "\n" not in str(exc.value)
    assert "different free components" in str(exc.value)


def test_gap_narrower_than_footprint_raises_no_path():
    prob = np.full((200, 200), GOOD, dtype=np.float32)
    prob[:, 95:105] = BAD                  # a north-south wall ...
    prob[95:105, 95:105] = GOOD            # ... with a 20 m gap, narrower than the 60 m footprint
    with pytest.raises(NoPathError):
        plan_route(prob, M_PER_PX, (-100.0, 0.0), (100.0, 0.0), lake_cfg())
    route = plan_route(prob, M_PER_PX, (-100.0, 0.0), (100.0, 0.0), lake_cfg(footprint_m=0.0, clearance_m=0.0))
    assert route.route_bad_fraction == 0.0  # a point footprint fits through the gap


@pytest.mark.parametrize("start, message", [
    ((0.0, 0.0), "bad matching area"),
    ((700.0, 0.0), "outside the map"),
    ((-250.0, -300.0), "outside the map"),
])
def test_bad_start_raises_user_error(start, message):
    with pytest.raises(UserError, match=message) as exc:
        plan_route(lake_map(), M_PER_PX, start, (250.0, 0.0), lake_cfg())
    assert not isinstance(exc.value, NoPathError) and "\n" not in str(exc.value)
    assert str(exc.value).startswith("start")


def test_bad_maps_raise_user_error():
    with pytest.raises(UserError, match="NaN"):
        plan_route(np.full((50, 50), np.nan, np.float32), 1.0, (0.0, 0.0), (5.0, 5.0), lake_cfg())
    with pytest.raises(UserError, match="dtype"):
        plan_route(np.ones((50, 50), np.uint8), 1.0, (0.0, 0.0), (5.0, 5.0), lake_cfg())
    with pytest.raises(UserError, match="2-D"):
        plan_route(np.ones((50, 50, 3), np.float32), 1.0, (0.0, 0.0), (5.0, 5.0), lake_cfg())


def test_start_inside_clearance_zone_escapes():
    cfg = lake_cfg()
    prob = lake_map()
    route = plan_route(prob, M_PER_PX, (-100.0, 0.0), (250.0, 0.0), cfg)   # 20 m from the lake edge
    assert route.fallback_reason is FallbackReason.START_OR_GOAL_IN_CLEARANCE_ZONE
    assert 0.0 < route.escape_length_m < 60.0
    assert route.route_bad_fraction == 0.0
    wp = route.waypoints_xy_m
    assert wp[-1] == pytest.approx([250.0, 0.0])


def test_unvisited_weight_zero_is_free_and_one_is_hard():
    prob = lake_map()
    prob[prob < 0.5] = np.nan            # the lake is unvisited instead of bad
    start, goal = (-250.0, 0.0), (250.0, 0.0)
    free = plan_route(prob, M_PER_PX, start, goal, lake_cfg(unvisited_weight=0.0))
    assert free.length_m == pytest.approx(500.0, abs=1.0)
    assert free.route_unvisited_fraction > 0.2
    hard = plan_route(prob, M_PER_PX, start, goal, lake_cfg(unvisited_weight=1.0))
    assert hard.route_unvisited_fraction == 0.0
    assert hard.min_clearance_m >= 10.0 - 1e-6
    soft = plan_route(prob, M_PER_PX, start, goal, lake_cfg(unvisited_weight=0.5))
    assert soft.route_unvisited_fraction < free.route_unvisited_fraction


def test_corners_are_rounded_to_turn_radius():
    prob = np.full((300, 300), GOOD, dtype=np.float32)
    prob[0:200, 140:160] = BAD                # wall from the north edge down to y = -100 m
    cfg = lake_cfg(footprint_m=20.0, clearance_m=5.0)
    route = plan_route(prob, M_PER_PX, (-200.0, 200.0), (200.0, 200.0), cfg)
    assert cfg.turn_radius_m == pytest.approx(40.0)
    assert route.min_turn_radius_m > 0.0
    wp = route.waypoints_xy_m
    headings = np.arctan2(*np.diff(wp, axis=0).T[::-1])
    turns = np.abs((np.diff(headings) + math.pi) % (2 * math.pi) - math.pi)
    # No sharp corner: each waypoint turns by at most the angle of a 40 m-radius arc chord.
    assert turns.max() < math.radians(60.0)


def test_subdivide_keeps_vertices_and_spacing():
    pts = np.array([[0.0, 0.0], [120.0, 0.0], [120.0, 10.0]])
    out = subdivide(pts, 50.0)
    assert len(out) == 5 and out[3] == pytest.approx([120.0, 0.0])
    assert polyline_length(out) == pytest.approx(130.0)


def test_offset_lake_is_passed_by_the_potential_field_itself():
    prob = np.full((300, 300), GOOD, dtype=np.float32)
    v, u = np.mgrid[0:300, 0:300]
    x, y = pixel_to_world(u + 0.5, v + 0.5, 300, 300, M_PER_PX)
    prob[np.hypot(x, y - 40.0) <= LAKE_R_M] = BAD     # lake north of the straight line
    cfg = lake_cfg()
    route = plan_route(prob, M_PER_PX, (-250.0, 0.0), (250.0, 0.0), cfg)
    assert route.method is PlannerMethod.POTENTIAL_FIELD and not route.fallback_used
    assert route.fallback_reason is FallbackReason.NONE
    assert route.straight_line_bad_fraction > 0.2
    clearance = distances_to_bad_m(prob, M_PER_PX, densify(route.waypoints_xy_m, 0.25)) - 30.0
    assert clearance.min() >= cfg.clearance_m - 1e-6
    assert float(route.waypoints_xy_m[:, 1].max()) < 1e-6    # went around the south side
    assert route.length_m <= 1.5 * route.shortest_free_length_m


def _edge_distance_m(points: np.ndarray, half_w: float, half_h: float) -> float:
    return float(np.min(np.minimum(half_w - np.abs(points[:, 0]), half_h - np.abs(points[:, 1]))))


def test_keep_footprint_on_map_steers_the_route_away_from_the_edge():
    # 300 x 300 m at 1 m/px; a bad band across the middle from x = -110 to x = 60 m leaves a
    # corridor along the west edge (the short way) and a wider one on the east side
    prob = np.full((300, 300), 0.9, dtype=np.float32)
    prob[130:170, 40:210] = 0.1
    start, goal = (-100.0, -100.0), (-100.0, 100.0)
    base = dict(footprint_m=0.0, clearance_m=10.0, altitude_m=50.0, unvisited_weight=0.0)
    near = plan_route(prob, 1.0, start, goal, PlannerConfig(**base))
    kept = plan_route(prob, 1.0, start, goal, PlannerConfig(**base, keep_footprint_on_map=True))
    radius = PlannerConfig(**base).camera_footprint_radius_m        # 28.9 m
    near_pts = densify(near.waypoints_xy_m, 0.5)
    kept_pts = densify(kept.waypoints_xy_m, 0.5)
    assert _edge_distance_m(near_pts, 150.0, 150.0) < radius        # hugs the west edge
    assert float(np.min(near_pts[:, 0])) < -110.0
    assert _edge_distance_m(kept_pts, 150.0, 150.0) >= radius - 1e-6  # the footprint stays on the map
    assert float(np.max(kept_pts[:, 0])) > 60.0                     # round the east end instead
    assert kept.min_clearance_m >= 10.0 - 1e-6 and kept.length_m > near.length_m
    assert kept.planner_params()["keep_footprint_on_map"] is True


def test_a_goal_reachable_only_along_the_edge_is_planned_without_keeping_the_footprint_on_the_map():
    from guidance.planner import plan_keeping_on_map
    # 300 x 300 m at 1 m/px; a bad band across the middle leaves only a 30 m corridor on the west edge
    prob = np.full((300, 300), 0.9, dtype=np.float32)
    prob[130:170, 30:] = 0.1
    cfg = PlannerConfig(footprint_m=0.0, clearance_m=5.0, altitude_m=50.0, unvisited_weight=0.0,
                        keep_footprint_on_map=True)
    points = [(-100.0, -100.0), (-100.0, 100.0)]
    with pytest.raises(NoPathError):
        plan_route(prob, 1.0, points[0], points[1], cfg)
    legs, route, escaped, kept = plan_keeping_on_map(prob, 1.0, points, cfg, 0.0)
    assert not kept and escaped is None and legs[0].cfg.keep_footprint_on_map is False
    assert np.allclose(route[0], points[0]) and np.allclose(route[-1], points[1])
    assert float(np.min(route[:, 0])) < -120.0                       # through the edge corridor
    # where the footprint can stay on the map, it does
    open_map = np.full((300, 300), 0.9, dtype=np.float32)
    _, _, _, kept2 = plan_keeping_on_map(open_map, 1.0, points, cfg, 0.0)
    assert kept2
    # no route either way: the planner's error
    closed = prob.copy()
    closed[130:170, :] = 0.1
    with pytest.raises(NoPathError):
        plan_keeping_on_map(closed, 1.0, points, cfg, 0.0)
