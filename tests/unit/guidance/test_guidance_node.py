"""Pure parts of the guidance node: legs through via-points, drift and replan decisions, config."""

from __future__ import annotations

import numpy as np
import pytest

from guidance.config import PlannerConfig
from guidance.node import ARRIVING_M, cross_track_m, remaining_goals, replan_reason
from guidance.planner import join_legs, plan_through
from scenenav.core.errors import UserError
from scenenav.core.frames import pixel_to_world

M_PER_PX = 2.0


def lake_map(size_px: int = 300, r_m: float = 80.0) -> np.ndarray:
    prob = np.full((size_px, size_px), 0.9, dtype=np.float32)
    v, u = np.mgrid[0:size_px, 0:size_px]
    x, y = pixel_to_world(u + 0.5, v + 0.5, size_px, size_px, M_PER_PX)
    prob[np.hypot(x, y) <= r_m] = 0.1
    return prob


def test_cross_track_is_distance_to_the_polyline():
    route = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0]])
    assert cross_track_m(route, np.array([50.0, 7.0])) == pytest.approx(7.0)
    assert cross_track_m(route, np.array([110.0, 50.0])) == pytest.approx(10.0)
    assert cross_track_m(route, np.array([-3.0, -4.0])) == pytest.approx(5.0)   # beyond the start
    assert cross_track_m(route[:1], np.array([3.0, 4.0])) == pytest.approx(5.0)


def test_replan_reason_drift_map_change_and_arrival():
    route = np.array([[0.0, 0.0], [500.0, 0.0]])
    goal = (500.0, 0.0)
    assert replan_reason(route, (200.0, 10.0), goal, 40.0, map_changed=False) is None
    assert "drifted 60 m" in replan_reason(route, (200.0, 60.0), goal, 40.0, map_changed=False)
    assert replan_reason(route, (200.0, 0.0), goal, 40.0, map_changed=True) == "assistant map changed"
    # arriving: neither drift nor a new map triggers a replan
    near = (500.0 - ARRIVING_M / 2, 0.0)
    assert replan_reason(route, near, goal, 1.0, map_changed=True) is None


def test_remaining_goals_keeps_the_final_goal():
    goals = ((1.0, 1.0), (2.0, 2.0), (3.0, 3.0))
    assert remaining_goals(goals, 0) == goals
    assert remaining_goals(goals, 2) == ((3.0, 3.0),)
    assert remaining_goals(goals, 7) == ((3.0, 3.0),)


def test_legs_through_via_points_avoid_the_lake():
    prob = lake_map()
    cfg = PlannerConfig(footprint_m=0.0, clearance_m=10.0, unvisited_weight=0.0)
    pts = [(-250.0, 0.0), (0.0, 200.0), (250.0, 0.0)]
    legs = plan_through(prob, M_PER_PX, pts, cfg)
    assert len(legs) == 2
    route = join_legs(legs)
    assert np.allclose(route[0], pts[0]) and np.allclose(route[-1], pts[-1])
    assert any(np.allclose(p, pts[1]) for p in route)             # passes the via-point
    assert len(route) == len(legs[0].waypoints_xy_m) + len(legs[1].waypoints_xy_m) - 1
    dense = np.concatenate([np.linspace(a, b, 20) for a, b in zip(route[:-1], route[1:], strict=False)])
    assert np.min(np.hypot(dense[:, 0], dense[:, 1])) >= 80.0 + 10.0 - 2.0 * M_PER_PX


def test_legs_need_a_goal_and_reject_goals_in_bad_area():
    prob = lake_map()
    with pytest.raises(UserError, match="at least one goal"):
        plan_through(prob, M_PER_PX, [(-250.0, 0.0)])
    with pytest.raises(UserError, match="goal 1"):
        plan_through(prob, M_PER_PX, [(-250.0, 0.0), (0.0, 0.0)], PlannerConfig(footprint_m=0.0))


def test_distance_to_polyline_vectorised():
    from scenenav.core.geometry import distance_to_polyline_m
    route = [(0.0, 0.0), (100.0, 0.0), (100.0, 100.0)]
    pts = np.array([[50.0, 7.0], [110.0, 50.0], [-3.0, -4.0], [100.0, 100.0]])
    assert np.allclose(distance_to_polyline_m(pts, route), [7.0, 10.0, 5.0, 0.0])
