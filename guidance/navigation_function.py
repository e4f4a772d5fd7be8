"""Navigation function without local minima: weighted wavefront (Dijkstra) distance-to-goal.

The value of a cell is the least integrated cost of reaching the goal over traversable cells of
the planning grid, moving to one of the 8 neighbours (a diagonal move needs both orthogonal
neighbours traversable, so paths never squeeze between two diagonal obstacle cells). The cost
per metre of a cell is

    c = 1 + nav_repulsive_weight * r(rho) + UNVISITED_COST_SCALE * unvisited_weight * unvisited_share

with r(rho) the dimensionless repulsion of :func:`guidance.potential_field.repulsive_field` and
unvisited_share the footprint share over unvisited ground (so a metre with the footprint fully
over unvisited ground costs 1 + 4 * unvisited_weight), times ``ESCAPE_COST_FACTOR`` on escape cells (cells
closer to bad area than the required clearance, usable only to leave a start or reach a goal
that lies there). Every cell with a finite value other than the goal has a neighbour with a
strictly smaller value, so descending it (following the Dijkstra predecessors) always reaches
the goal: there are no local minima. An unreachable start means start and goal lie in different
free components.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from guidance.config import PlannerConfig
from guidance.potential_field import PlanningGrid, repulsive_field

log = logging.getLogger(__name__)

# Cost multiplier of escape cells: leaving a clearance zone costs 1000x a normal metre, so the
# route spends the least possible length there.
ESCAPE_COST_FACTOR = 1000.0
# Extra cost per metre of a footprint fully over unvisited ground, at unvisited_weight = 1.
UNVISITED_COST_SCALE = 4.0
_UNREACHABLE = -9999  # scipy.sparse.csgraph predecessor sentinel


def cost_per_m(grid: PlanningGrid, cfg: PlannerConfig) -> np.ndarray:
    """Cost per metre of every cell (before the escape factor)."""
    cost = 1.0 + cfg.nav_repulsive_weight * repulsive_field(grid, cfg)
    if cfg.unvisited_weight > 0.0:
        cost += UNVISITED_COST_SCALE * cfg.unvisited_weight * grid.unvisited_share
    return cost


@dataclass(frozen=True)
class GridEdges:
    """Undirected 8-neighbour edges between traversable cells (node = row * cols + col)."""

    shape: tuple[int, int]
    heads: np.ndarray
    tails: np.ndarray
    lengths_m: np.ndarray


def grid_edges(traversable: np.ndarray, cell_m: float) -> GridEdges:
    """Edges of the 8-connected grid; a diagonal needs both orthogonal neighbours traversable."""
    rows, cols = traversable.shape
    index = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
    heads, tails, lengths = [], [], []
    diagonal = math.sqrt(2.0) * cell_m
    # (d_row, d_col, length): east, south, south-east, south-west.
    for d_row, d_col, length in ((0, 1, cell_m), (1, 0, cell_m), (1, 1, diagonal), (1, -1, diagonal)):
        r0, r1 = 0, rows - d_row
        c0, c1 = max(0, -d_col), cols - max(0, d_col)
        a = (slice(r0, r1), slice(c0, c1))
        b = (slice(r0 + d_row, r1 + d_row), slice(c0 + d_col, c1 + d_col))
        ok = traversable[a] & traversable[b]
        if d_row and d_col:
            ok &= traversable[(slice(r0, r1), slice(c0 + d_col, c1 + d_col))]
            ok &= traversable[(slice(r0 + d_row, r1 + d_row), slice(c0, c1))]
        heads.append(index[a][ok])
        tails.append(index[b][ok])
        lengths.append(np.full(int(ok.sum()), length))
    return GridEdges(shape=(rows, cols), heads=np.concatenate(heads), tails=np.concatenate(tails),
                     lengths_m=np.concatenate(lengths))


def build_graph(edges: GridEdges, cost_per_m: np.ndarray) -> sparse.csr_matrix:
    """Sparse graph; edge weight = length * mean cost per metre of its two cells."""
    flat = cost_per_m.ravel()
    w = edges.lengths_m * 0.5 * (flat[edges.heads] + flat[edges.tails])
    n = edges.shape[0] * edges.shape[1]
    return sparse.csr_matrix((w, (edges.heads, edges.tails)), shape=(n, n))


def navigation_function(graph: sparse.csr_matrix, goal_index: int) -> tuple[np.ndarray, np.ndarray]:
    """Cost-to-goal of every node and the predecessor pointing one step towards the goal."""
    dist, pred = csgraph.dijkstra(graph, directed=False, indices=goal_index, return_predecessors=True)
    return dist, pred


def descend(pred: np.ndarray, start_index: int, goal_index: int) -> np.ndarray | None:
    """Node indices from start to goal following the predecessors; None when unreachable."""
    if start_index == goal_index:
        return np.array([start_index], dtype=np.int64)
    if pred[start_index] == _UNREACHABLE:
        return None
    out = [start_index]
    node = start_index
    limit = pred.size
    while node != goal_index:
        node = int(pred[node])
        if node == _UNREACHABLE or len(out) > limit:
            return None
        out.append(node)
    return np.asarray(out, dtype=np.int64)


def plan_on_grid(edges: GridEdges, cost_per_m: np.ndarray, start_rc: tuple[int, int],
                 goal_rc: tuple[int, int]) -> tuple[np.ndarray | None, float]:
    """Descend the navigation function from start to goal.

    Returns the (N, 2) array of (row, col) cells and the cost-to-goal of the start (inf when
    start and goal are not connected, and then the path is None).
    """
    cols = edges.shape[1]
    graph = build_graph(edges, cost_per_m)
    start_i = start_rc[0] * cols + start_rc[1]
    goal_i = goal_rc[0] * cols + goal_rc[1]
    dist, pred = navigation_function(graph, goal_i)
    nodes = descend(pred, start_i, goal_i)
    if nodes is None:
        return None, math.inf
    log.debug("navigation function: %d cells, cost %.1f", nodes.size, dist[start_i])
    return np.stack([nodes // cols, nodes % cols], axis=1), float(dist[start_i])
