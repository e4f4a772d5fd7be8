"""``snap_to_good_area`` and ``plan_escaping``: a goal on a bad matching area moves to the nearest point that keeps the
route's clearance, within a limit; a goal on a good area stays where it is."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from guidance.config import PlannerConfig
from guidance.planner import plan_escaping, plan_route, snap_slack_m, snap_to_good_area
from scenenav.core.errors import UserError
from scenenav.core.frames import world_to_pixel


def test_a_goal_on_a_bad_area_moves_to_the_nearest_point_with_clearance():
    m_per_px = 1.0
    prob = np.full((200, 200), 0.9, dtype=np.float32)
    prob[:, :120] = 0.1                          # bad west of column 120 (x < 20 m)
    cfg = PlannerConfig(footprint_m=0.0, clearance_m=10.0)
    good = snap_to_good_area(prob, m_per_px, (50.0, 0.0), cfg, 100.0)
    assert good == (50.0, 0.0)                   # already good, 30 m from the bad area
    near = snap_to_good_area(prob, m_per_px, (25.0, 0.0), cfg, 100.0)
    assert near == (25.0, 0.0)                   # good, if nearer than the clearance: it stays
    moved = snap_to_good_area(prob, m_per_px, (0.0, 30.0), cfg, 100.0)
    assert moved is not None
    u, _v = world_to_pixel(moved[0], moved[1], 200, 200, m_per_px)
    slack = snap_slack_m(200, 200, m_per_px, cfg)   # the planning grid's conservative margin
    assert 129.0 + slack <= u <= 132.0 + slack   # 10 m (pixel centre to pixel centre) east of the edge, + slack
    assert abs(moved[1] - 30.0) < 1.0            # straight east: the nearest such point
    assert snap_to_good_area(prob, m_per_px, (-90.0, 0.0), cfg, 50.0) is None   # too far to move
    assert math.isfinite(moved[0])


def test_a_start_on_a_bad_area_is_left_by_the_shortest_way():
    m_per_px = 1.0
    prob = np.full((200, 200), 0.9, dtype=np.float32)
    prob[:, :120] = 0.1                          # bad west of x = 20 m
    cfg = PlannerConfig(footprint_m=0.0, clearance_m=10.0, unvisited_weight=0.0)
    start, goal = (0.0, 0.0), (60.0, 60.0)
    legs, route, escaped = plan_escaping(prob, m_per_px, [start, goal], cfg, 100.0)
    slack = snap_slack_m(200, 200, m_per_px, cfg)
    assert escaped is not None and 29.0 + slack <= escaped[0] <= 32.0 + slack and abs(escaped[1]) < 1.0
    assert np.allclose(route[0], start) and np.allclose(route[1], escaped)   # the straight hop out
    assert np.allclose(route[-1], goal) and np.allclose(legs[0].waypoints_xy_m[0], escaped)
    # a start on a good area plans from itself; no escape within reach: the planner says why
    _, route2, none = plan_escaping(prob, m_per_px, [(50.0, 0.0), goal], cfg, 100.0)
    assert none is None and np.allclose(route2[0], (50.0, 0.0))
    with pytest.raises(UserError, match="start .* lies in a bad matching area"):
        plan_escaping(prob, m_per_px, [(-90.0, 0.0), goal], cfg, 50.0)
    with pytest.raises(UserError, match="start .* lies in a bad matching area"):
        plan_escaping(prob, m_per_px, [start, goal], cfg, 0.0)


def test_a_snapped_goal_keeps_the_camera_footprint_inside_the_map():
    m_per_px = 1.0
    prob = np.full((300, 300), 0.9, dtype=np.float32)
    prob[100:, :] = 0.1                          # bad south of y = 50 m: good only in a northern strip
    cfg = PlannerConfig(footprint_m=0.0, clearance_m=10.0, altitude_m=50.0)   # footprint radius 28.9 m
    radius = cfg.camera_footprint_radius_m
    assert radius == pytest.approx(50.0 * math.tan(math.radians(30.0)))
    slack = snap_slack_m(300, 300, m_per_px, cfg)
    moved = snap_to_good_area(prob, m_per_px, (0.0, 40.0), cfg, 200.0)
    assert moved is not None
    assert abs(moved[1] - 60.0 - slack) < 1.0    # 10 m (+ slack) clear of the bad area, straight north
    # west of it the good strip reaches the map's west edge: the nearest good point there would
    # put half the capture off the map; the snapped goal keeps the whole footprint on it
    edge = snap_to_good_area(prob, m_per_px, (-149.0, 40.0), cfg, 200.0)
    assert edge is not None and edge[0] >= -150.0 + radius + slack - 1.0 and abs(edge[1] - 60.0 - slack) < 1.5
    # the moved goal is free for the planner, even with the map edge as an obstacle: no escape
    kept = dataclasses.replace(cfg, keep_footprint_on_map=True)
    route = plan_route(prob, m_per_px, (0.0, 110.0), edge, kept)
    assert route.escape_length_m == 0.0
    # a strip narrower than the footprint near the north edge: nothing qualifies
    thin = np.full((300, 300), 0.1, dtype=np.float32)
    thin[:20, :] = 0.9
    assert snap_to_good_area(thin, m_per_px, (0.0, 100.0), PlannerConfig(footprint_m=0.0, clearance_m=1.0,
                                                                         altitude_m=50.0), 200.0) is None
