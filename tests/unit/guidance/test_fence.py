"""The geofence as the guidance planner sees it (guidance.fence): AC_Fence's shapes from downloaded
items and FENCE_* parameters, the margin, the fence drawn into the assistant map, routes inside."""

from __future__ import annotations

import numpy as np
import pytest

from guidance.config import PlannerConfig
from guidance.fence import (
    Fence,
    FenceCommand,
    FenceItem,
    apply_fence,
    check_points_inside,
    cruise_altitude_m,
    distance_to_edges_m,
    fence_from_items,
    point_in_polygon,
)
from guidance.planner import join_legs, plan_through
from scenenav.core.errors import UserError
from scenenav.core.frames import enu_to_geodetic

LAT0, LON0 = 48.0, 11.0
SQUARE = np.array([[-100.0, -100.0], [100.0, -100.0], [100.0, 100.0], [-100.0, 100.0]])


def items_of(poly_xy, command=FenceCommand.POLYGON_VERTEX_INCLUSION) -> list[FenceItem]:
    lat, lon = enu_to_geodetic(poly_xy[:, 0], poly_xy[:, 1], LAT0, LON0)
    return [FenceItem(int(command), float(len(poly_xy)), float(a), float(o)) for a, o in zip(lat, lon, strict=True)]


def test_point_in_polygon_and_edge_distance_hand_checked():
    pts = np.array([[0.0, 0.0], [99.0, 0.0], [101.0, 0.0], [0.0, -150.0]])
    assert point_in_polygon(pts, SQUARE).tolist() == [True, True, False, False]
    assert distance_to_edges_m(pts, SQUARE) == pytest.approx([100.0, 1.0, 1.0, 50.0])


def test_fence_from_items_follows_fence_enable_type_and_margin():
    items = items_of(SQUARE)
    clat, clon = enu_to_geodetic(0.0, 0.0, LAT0, LON0)
    items.append(FenceItem(int(FenceCommand.CIRCLE_EXCLUSION), 20.0, float(clat), float(clon)))
    items.append(FenceItem(int(FenceCommand.RETURN_POINT), 0.0, float(clat), float(clon)))
    params = {"FENCE_ENABLE": 1, "FENCE_TYPE": 7, "FENCE_RADIUS": 300.0, "FENCE_MARGIN": 5.0,
              "FENCE_ALT_MAX": 80.0}
    f = fence_from_items(items, params, (0.0, 0.0), LAT0, LON0)
    assert len(f.inclusion_polygons) == 1 and f.inclusion_polygons[0] == pytest.approx(SQUARE, abs=1e-6)
    assert f.exclusion_circles == (pytest.approx((0.0, 0.0, 20.0), abs=1e-6),)
    assert f.inclusion_circles == ((0.0, 0.0, 300.0),)                # FENCE_TYPE bit 2, around home
    pts = np.array([[0.0, 10.0], [0.0, 30.0], [0.0, 96.0], [0.0, 94.0]])
    assert f.allowed(pts).tolist() == [False, True, False, True]      # 5 m margins
    assert cruise_altitude_m(100.0, f) == 75.0 and cruise_altitude_m(50.0, f) == 50.0
    assert not fence_from_items(items, dict(params, FENCE_ENABLE=0), (0.0, 0.0), LAT0, LON0).horizontal
    only_alt = fence_from_items(items, dict(params, FENCE_TYPE=1), (0.0, 0.0), LAT0, LON0)
    assert not only_alt.horizontal and only_alt.alt_max_m == 80.0
    with pytest.raises(UserError, match="incomplete"):
        fence_from_items(items_of(SQUARE)[:3] + items[4:], params, (0.0, 0.0), LAT0, LON0)


def test_routes_are_planned_inside_the_fence():
    """A straight route (-150, 0) -> (150, 0) on a good map; an exclusion polygon across the middle
    leaves a gap in the north only: the route goes through it, FENCE_MARGIN from the fence."""
    m_per_px, size = 2.0, 200
    prob = np.full((size, size), 0.9, dtype=np.float32)
    wall = np.array([[-20.0, -200.0], [20.0, -200.0], [20.0, 120.0], [-20.0, 120.0]])
    f = Fence(exclusion_polygons=(wall,), margin_m=4.0)
    fenced = apply_fence(prob, m_per_px, f)
    assert (fenced == 0.0).sum() > 0 and (prob == 0.9).all() and fenced.dtype == prob.dtype
    start, goal = (-150.0, 0.0), (150.0, 0.0)
    check_points_inside(f, [start, goal], ["start", "goal 1"])
    route = join_legs(plan_through(fenced, m_per_px, [start, goal],
                                   PlannerConfig(footprint_m=0.0, clearance_m=4.0, unvisited_weight=0.0)))
    dense = np.concatenate([np.linspace(a, b, 40) for a, b in zip(route[:-1], route[1:], strict=False)])
    assert f.allowed(dense).all()
    assert dense[:, 1].max() > 120.0
    with pytest.raises(UserError, match="outside the geofence"):
        check_points_inside(f, [(0.0, 0.0)], ["goal 1"])
