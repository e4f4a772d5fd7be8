"""Classic potential field and navigation function on small hand-checked grids."""

from __future__ import annotations

import math

import numpy as np
import pytest

from guidance.config import PlannerConfig
from guidance.navigation_function import build_graph, grid_edges, navigation_function
from guidance.potential_field import (
    REPULSIVE_CAP,
    DescentStatus,
    PotentialField,
    attractive_gradient,
    build_grid,
    descend,
    repulsive_term,
)

GOOD, BAD = 0.9, 0.1


def point_cfg(**kw) -> PlannerConfig:
    """1 m cells, point footprint, no clearance: distances are easy to check by hand."""
    base = dict(footprint_m=0.0, clearance_m=0.0, grid_cell_m=1.0, influence_distance_m=10.0,
                unvisited_weight=0.0)
    base.update(kw)
    return PlannerConfig(**base)


def u_trap_map() -> np.ndarray:
    """400 m x 400 m at 2 m/px; a U of bad area opening west, in front of a goal in the east."""
    prob = np.full((200, 200), GOOD, dtype=np.float32)
    # x = (col - 100) * 2, y = (100 - row) * 2
    prob[20:181, 120:126] = BAD     # bottom of the U: x 40..52 m, y -160..160 m
    prob[20:26, 60:126] = BAD       # north arm: y 150..160 m, x -80..52 m
    prob[175:181, 60:126] = BAD     # south arm: y -160..-150 m
    return prob


def u_trap_cfg() -> PlannerConfig:
    return PlannerConfig(footprint_m=20.0, clearance_m=5.0, grid_cell_m=2.0, unvisited_weight=0.0)


def test_repulsive_term_hand_values():
    rho0 = 10.0
    r = repulsive_term(np.array([10.0, 12.0, 5.0, 2.5, 0.0, -3.0]), rho0)
    assert r[0] == 0.0 and r[1] == 0.0               # at and beyond the influence distance
    assert r[2] == pytest.approx(1.0)                # (10/5 - 1)^2
    assert r[3] == pytest.approx(9.0)                # (10/2.5 - 1)^2
    assert r[4] == REPULSIVE_CAP and r[5] == REPULSIVE_CAP


def test_repulsive_field_value_and_gradient_point_away_from_obstacle():
    prob = np.full((41, 41), GOOD, dtype=np.float32)
    prob[20, 20] = BAD                               # one bad pixel at the map centre (0.5, -0.5) m
    cfg = point_cfg(attractive_gain=1e-9)
    grid = build_grid(prob, 1.0, cfg)
    assert grid.factor == 1 and grid.margin_m == pytest.approx(math.sqrt(2.0))
    field = PotentialField.build(grid, (-20.0, 20.0), cfg)   # goal 28 m away: goal factor 1 nearby
    # Cell (20, 25) is 5 m east of the bad cell: rho = 5 - sqrt(2), r = (10 / rho - 1)^2.
    rho = 5.0 - math.sqrt(2.0)
    assert field.repulsive[20, 25] == pytest.approx(cfg.repulsive_gain_m * (10.0 / rho - 1.0) ** 2)
    centre = np.array([0.5, -0.5])
    for offset in ([4.0, 0.0], [0.0, 4.0], [-3.0, -3.0], [3.0, -2.0]):
        force = field.force_xy(centre + np.array(offset))
        away = np.array(offset) / np.hypot(*offset)
        assert float(np.dot(force, away)) / np.hypot(*force) > 0.95, (offset, force)


def test_attraction_points_to_goal():
    cfg = point_cfg(attractive_quadratic_radius_m=20.0)
    goal = np.array([0.0, 0.0])
    assert attractive_gradient(np.array([100.0, 0.0]), goal, cfg) == pytest.approx([1.0, 0.0])  # conic
    assert attractive_gradient(np.array([10.0, 0.0]), goal, cfg) == pytest.approx([0.5, 0.0])   # quadratic
    prob = np.full((60, 60), GOOD, dtype=np.float32)
    field = PotentialField.build(build_grid(prob, 1.0, cfg), (10.0, -5.0), cfg)
    force = field.force_xy((-12.0, 17.0))
    to_goal = np.array([22.0, -22.0]) / np.hypot(22.0, 22.0)
    assert float(np.dot(force, to_goal)) / np.hypot(*force) == pytest.approx(1.0, abs=1e-6)


def test_descent_reaches_goal_on_free_map():
    cfg = point_cfg()
    prob = np.full((100, 100), GOOD, dtype=np.float32)
    grid = build_grid(prob, 1.0, cfg)
    result = descend(PotentialField.build(grid, (30.0, 20.0), cfg), (-30.0, -25.0), np.ones(grid.shape, bool))
    assert result.status is DescentStatus.REACHED
    assert result.path_xy_m[-1] == pytest.approx([30.0, 20.0])


def test_plain_descent_is_trapped_by_u_obstacle():
    cfg = u_trap_cfg()
    prob = u_trap_map()
    grid = build_grid(prob, 2.0, cfg)
    lb = grid.clearance_lb_m(cfg.footprint_width_m / 2.0)
    free = grid.inside & ~grid.bad & (lb - grid.cell_m / 4.0 >= cfg.clearance_m)
    result = descend(PotentialField.build(grid, (150.0, 0.0), cfg), (-150.0, 0.0), free)
    assert result.status in (DescentStatus.LOCAL_MINIMUM, DescentStatus.OSCILLATION)
    x, y = result.path_xy_m[-1]
    assert -80.0 < x < 40.0 and abs(y) < 150.0       # stuck inside the cup


def test_navigation_function_has_no_local_minima():
    cfg = u_trap_cfg()
    grid = build_grid(u_trap_map(), 2.0, cfg)
    lb = grid.clearance_lb_m(cfg.footprint_width_m / 2.0)
    free = grid.inside & ~grid.bad & (lb >= cfg.clearance_m)
    rows, cols = grid.shape
    goal_rc = tuple(int(v) for v in grid.cells_of_xy(np.array([150.0, 0.0])))
    dist, _ = navigation_function(build_graph(grid_edges(free, grid.cell_m), np.ones(grid.shape)),
                                  goal_rc[0] * cols + goal_rc[1])
    value = dist.reshape(rows, cols)
    padded = np.pad(value, 1, constant_values=np.inf)
    neighbours = np.stack([padded[1 + dr:rows + 1 + dr, 1 + dc:cols + 1 + dc]
                           for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc])
    reachable = np.isfinite(value)
    reachable[goal_rc] = False
    assert reachable.sum() > 1000
    assert np.all(neighbours.min(axis=0)[reachable] < value[reachable])
