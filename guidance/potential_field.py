"""Obstacle fields on the coarse planning grid and the classic potential field (pure numpy/scipy).

Bad matching areas of the assistant map (probability of a true match < 0.5, seed paper 5.4) are
obstacles; unvisited (NaN) cells are weaker obstacles weighted by ``unvisited_weight``. The
planner works on a coarse grid whose square cells are ``factor`` x ``factor`` map pixels
(~2-5 m) so that a 8000x8000 px map plans in seconds.

Grid coordinates are continuous (gx, gy) = (column, row) in cells, row 0 north, the centre of
cell (row i, column j) at (j + 0.5, i + 0.5): the map's pixel coordinates divided by ``factor``
(see scenenav/core/frames.py for pixels <-> world ENU metres).

Conservative coarse distances: a coarse cell is bad when ANY of its pixels is bad, and
``dist_bad_m`` is the Euclidean distance between coarse cell centres. For any point p in a cell,
the true distance from p to the nearest bad pixel centre is >= dist_bad_m - margin_m with
margin_m = cell_m * sqrt(2) (half a diagonal for p, half for the bad pixel), and <= dist_bad_m +
margin_m. Every clearance test of the planner uses the lower bound, so a route that passes it
keeps its clearance at full resolution.

Unvisited ground (NaN cells, and the world beyond the map border) is a soft obstacle measured by
``unvisited_share``: the share of a footprint-sized square window (box filter) over unvisited
ground, in [0, 1]. With ``unvisited_weight`` = 1 unvisited cells are hard obstacles like bad cells.

Classic potential field (Khatib-style): U = U_att + U_rep + U_unv with
  U_att = attractive_gain * (d - d_q / 2) for d > d_q, attractive_gain * d^2 / (2 d_q) inside
  (conic far from the goal, quadratic within ``attractive_quadratic_radius_m`` = d_q);
  U_rep = repulsive_gain_m * r(rho) * f_goal,
  r(rho) = (rho_0 / rho - 1)^2 for 0 < rho < rho_0, 0 beyond (capped at REPULSIVE_CAP),
  where rho is the clearance beyond the required one (conservative distance from the footprint
  edge to the nearest bad pixel, minus ``clearance_m``) and rho_0 = ``influence_distance_m``;
  U_unv = unvisited_weight * footprint_m / 2 * unvisited_share * f_goal, whose slope stays
  below the attraction, so unvisited ground deflects the descent but never traps it;
  f_goal = min(1, d / rho_0)^2 with d the distance to the goal: this goal factor (Ge & Cui's
  fix for goals near obstacles) makes the goal the global minimum even when it lies within the
  influence distance of bad or unvisited ground.
The repulsive gradient is taken by finite differences (numpy.gradient) and interpolated
bilinearly; descent takes normalised steps of ``step_m`` and reports local minima (no potential
decrease of ``min_progress_m`` over ``stall_window_steps``), oscillation (a cell entered more
than ``max_cell_visits`` times), a step into the clearance zone, or running out of steps.
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from guidance.config import PlannerConfig
from scenenav.core.frames import metres_to_whole_px

log = logging.getLogger(__name__)

# Cap of the dimensionless repulsive term r(rho): reached at rho = rho_0 / (1 + sqrt(cap)).
REPULSIVE_CAP = 100.0
_NO_OBSTACLE_DISTANCE_M = np.inf


class DescentStatus(str, enum.Enum):
    """Outcome of a gradient descent on the classic potential field."""

    REACHED = "reached"
    LOCAL_MINIMUM = "local_minimum"
    OSCILLATION = "oscillation"
    CLEARANCE = "clearance"
    MAX_STEPS = "max_steps"


@dataclass(frozen=True)
class PlanningGrid:
    """Coarse planning grid over an assistant map (arrays are rows x columns of cells)."""

    factor: int                 # map pixels per cell side
    m_per_px: float
    width_px: int
    height_px: int
    bad: np.ndarray             # bool: any pixel of the cell is bad (or unvisited when weight >= 1)
    inside: np.ndarray          # bool: the cell centre lies on the map
    dist_bad_m: np.ndarray      # float64: distance between cell centres to the nearest bad cell
    unvisited_share: np.ndarray  # float32 in [0, 1]: footprint share over unvisited/off-map ground

    @property
    def shape(self) -> tuple[int, int]:
        return self.bad.shape

    @property
    def cell_m(self) -> float:
        return self.factor * self.m_per_px

    @property
    def margin_m(self) -> float:
        """Bound on |true pixel distance - coarse distance| for any point of a cell."""
        return self.cell_m * math.sqrt(2.0)

    def xy_to_grid(self, xy_m: np.ndarray) -> np.ndarray:
        """World ENU metres (..., 2) -> continuous grid coordinates (gx, gy)."""
        xy = np.asarray(xy_m, dtype=float)
        gx = (xy[..., 0] / self.m_per_px + self.width_px / 2.0) / self.factor
        gy = (self.height_px / 2.0 - xy[..., 1] / self.m_per_px) / self.factor
        return np.stack([gx, gy], axis=-1)

    def grid_to_xy(self, g: np.ndarray) -> np.ndarray:
        """Continuous grid coordinates (gx, gy) (..., 2) -> world ENU metres."""
        g = np.asarray(g, dtype=float)
        x = (g[..., 0] * self.factor - self.width_px / 2.0) * self.m_per_px
        y = (self.height_px / 2.0 - g[..., 1] * self.factor) * self.m_per_px
        return np.stack([x, y], axis=-1)

    def cell_centre_xy(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """World metres of the centres of cells (rows, cols)."""
        g = np.stack([np.asarray(cols, dtype=float) + 0.5, np.asarray(rows, dtype=float) + 0.5], axis=-1)
        return self.grid_to_xy(g)

    def cells_of_xy(self, xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Row and column indices of the cells containing world points (clipped to the grid)."""
        g = self.xy_to_grid(xy_m)
        rows = np.clip(np.floor(g[..., 1]).astype(np.int64), 0, self.shape[0] - 1)
        cols = np.clip(np.floor(g[..., 0]).astype(np.int64), 0, self.shape[1] - 1)
        return rows, cols

    def clearance_lb_m(self, footprint_radius_m: float) -> np.ndarray:
        """Per cell: lower bound of the distance from the footprint edge to the nearest bad pixel."""
        return self.dist_bad_m - self.margin_m - footprint_radius_m

    def edge_distance_lb_m(self) -> np.ndarray:
        """Per cell: lower bound of the distance from any point of the cell to the nearest map edge."""
        rows, cols = self.shape
        v = (np.arange(rows) + 0.5) * self.factor
        u = (np.arange(cols) + 0.5) * self.factor
        dv = np.minimum(v, self.height_px - v)[:, None]
        du = np.minimum(u, self.width_px - u)[None, :]
        return np.minimum(dv, du) * self.m_per_px - self.margin_m


def choose_factor(height_px: int, width_px: int, m_per_px: float, cfg: PlannerConfig) -> int:
    """Pixels per cell: the cell is at least ``grid_cell_m`` and the grid at most ``max_grid_cells``."""
    factor = metres_to_whole_px(cfg.grid_cell_m, m_per_px)
    while math.ceil(height_px / factor) * math.ceil(width_px / factor) > cfg.max_grid_cells:
        factor += 1
    return factor


def _pool_any(mask: np.ndarray, factor: int) -> np.ndarray:
    rows = math.ceil(mask.shape[0] / factor)
    cols = math.ceil(mask.shape[1] / factor)
    padded = np.zeros((rows * factor, cols * factor), dtype=bool)
    padded[:mask.shape[0], :mask.shape[1]] = mask
    return padded.reshape(rows, factor, cols, factor).any(axis=(1, 3))


def _pool_fraction(mask: np.ndarray, factor: int, pad_value: bool) -> np.ndarray:
    """Share of set pixels per cell (padding beyond the map counted as ``pad_value``)."""
    rows = math.ceil(mask.shape[0] / factor)
    cols = math.ceil(mask.shape[1] / factor)
    padded = np.full((rows * factor, cols * factor), pad_value, dtype=bool)
    padded[:mask.shape[0], :mask.shape[1]] = mask
    counts = padded.reshape(rows, factor, cols, factor).sum(axis=(1, 3), dtype=np.int64)
    return (counts / float(factor * factor)).astype(np.float32)


def _distance_m(obstacle: np.ndarray, cell_m: float) -> np.ndarray:
    """Distance (metres, between cell centres) from every cell to the nearest obstacle cell."""
    if not obstacle.any():
        return np.full(obstacle.shape, _NO_OBSTACLE_DISTANCE_M)
    return ndimage.distance_transform_edt(~obstacle, sampling=cell_m)


def bad_pixel_mask(probability: np.ndarray, cfg: PlannerConfig) -> np.ndarray:
    """Full-resolution hard obstacles: p < threshold, plus unvisited pixels when the weight is 1."""
    with np.errstate(invalid="ignore"):
        bad = probability < cfg.bad_probability_threshold
    if cfg.unvisited_weight >= 1.0:
        bad |= np.isnan(probability)
    return bad


def build_grid(probability: np.ndarray, m_per_px: float, cfg: PlannerConfig) -> PlanningGrid:
    """Coarsen an assistant map into a :class:`PlanningGrid` (pooling + distance transforms)."""
    height_px, width_px = probability.shape
    factor = choose_factor(height_px, width_px, m_per_px, cfg)
    cell_m = factor * m_per_px
    bad = _pool_any(bad_pixel_mask(probability, cfg), factor)
    rows, cols = bad.shape
    centres_v = (np.arange(rows) + 0.5) * factor
    centres_u = (np.arange(cols) + 0.5) * factor
    inside = (centres_v[:, None] < height_px) & (centres_u[None, :] < width_px)
    if cfg.unvisited_weight < 1.0:
        unvisited = _pool_fraction(np.isnan(probability), factor, pad_value=True)
    else:  # unvisited pixels are already bad; only the world beyond the border is unknown
        unvisited = _pool_fraction(np.zeros(probability.shape, dtype=bool), factor, pad_value=True)
    window = max(1, int(round(cfg.footprint_width_m / cell_m)))
    window += 1 - window % 2
    # Beyond the map border the ground is unknown: counted as unvisited.
    share = ndimage.uniform_filter(unvisited, size=window, mode="constant", cval=1.0)
    grid = PlanningGrid(factor=factor, m_per_px=float(m_per_px), width_px=int(width_px),
                        height_px=int(height_px), bad=bad, inside=inside,
                        dist_bad_m=_distance_m(bad, cell_m), unvisited_share=np.clip(share, 0.0, 1.0))
    log.debug("planning grid %dx%d cells of %.2f m (factor %d)", rows, cols, cell_m, factor)
    return grid


def repulsive_term(rho_m: np.ndarray, influence_distance_m: float) -> np.ndarray:
    """Dimensionless repulsion r(rho) = (rho_0/rho - 1)^2 inside the influence distance, capped."""
    rho = np.asarray(rho_m, dtype=float)
    out = np.zeros_like(rho)
    near = rho < influence_distance_m
    with np.errstate(divide="ignore", invalid="ignore"):
        vals = (influence_distance_m / rho[near] - 1.0) ** 2
    vals = np.where(rho[near] > 0, vals, REPULSIVE_CAP)
    out[near] = np.minimum(vals, REPULSIVE_CAP)
    return out


def repulsive_field(grid: PlanningGrid, cfg: PlannerConfig) -> np.ndarray:
    """Dimensionless repulsion r(rho) per cell from bad cells (no goal factor)."""
    rho_bad = grid.clearance_lb_m(cfg.footprint_width_m / 2.0) - cfg.clearance_m
    return repulsive_term(rho_bad, cfg.influence_distance_m)


def unvisited_scale_m(grid: PlanningGrid, cfg: PlannerConfig) -> float:
    """Potential (metres) of a footprint entirely over unvisited ground, at weight 1."""
    return max(cfg.footprint_width_m, grid.cell_m) / 2.0


def attractive_potential(dist_m: np.ndarray | float, cfg: PlannerConfig) -> np.ndarray | float:
    """Conic attraction, quadratic within ``attractive_quadratic_radius_m`` (continuous, C1)."""
    d = np.asarray(dist_m, dtype=float)
    dq = cfg.attractive_quadratic_radius_m
    if dq <= 0:
        out = cfg.attractive_gain * d
    else:
        out = np.where(d > dq, cfg.attractive_gain * (d - dq / 2.0),
                       cfg.attractive_gain * d * d / (2.0 * dq))
    return float(out) if out.ndim == 0 else out


def attractive_gradient(p_m: np.ndarray, goal_m: np.ndarray, cfg: PlannerConfig) -> np.ndarray:
    """Gradient of the attractive potential at p (metres; points away from the goal)."""
    diff = np.asarray(p_m, dtype=float) - np.asarray(goal_m, dtype=float)
    d = float(np.hypot(diff[0], diff[1]))
    if d == 0.0:
        return np.zeros(2)
    dq = cfg.attractive_quadratic_radius_m
    if d > dq:
        return cfg.attractive_gain * diff / d
    return cfg.attractive_gain * diff / dq


@dataclass(frozen=True)
class PotentialField:
    """Repulsive potential (metres) and its finite-difference gradient on the grid, plus the goal."""

    grid: PlanningGrid
    cfg: PlannerConfig
    repulsive: np.ndarray       # U_rep + U_unv per cell, metres of attraction-equivalent
    grad_gx: np.ndarray         # dU_rep / d(gx) per metre of gx (east)
    grad_gy: np.ndarray         # dU_rep / d(gy) per metre of gy (south)
    goal_g: np.ndarray          # goal in grid coordinates

    @classmethod
    def build(cls, grid: PlanningGrid, goal_xy_m, cfg: PlannerConfig) -> "PotentialField":
        goal_g = grid.xy_to_grid(np.asarray(goal_xy_m, dtype=float))
        rows, cols = grid.shape
        d_goal = np.hypot((np.arange(rows)[:, None] + 0.5 - goal_g[1]),
                          (np.arange(cols)[None, :] + 0.5 - goal_g[0])) * grid.cell_m
        goal_factor = np.minimum(1.0, d_goal / cfg.influence_distance_m) ** 2
        rep = cfg.repulsive_gain_m * repulsive_field(grid, cfg)
        if cfg.unvisited_weight > 0.0:
            rep = rep + cfg.unvisited_weight * unvisited_scale_m(grid, cfg) * grid.unvisited_share
        rep = rep * goal_factor
        d_rows, d_cols = np.gradient(rep, grid.cell_m)
        return cls(grid=grid, cfg=cfg, repulsive=rep, grad_gx=d_cols, grad_gy=d_rows, goal_g=goal_g)

    def _bilinear(self, field: np.ndarray, g: np.ndarray) -> float:
        rows, cols = field.shape
        x = min(max(g[0] - 0.5, 0.0), cols - 1.0)
        y = min(max(g[1] - 0.5, 0.0), rows - 1.0)
        c0, r0 = int(x), int(y)
        c1, r1 = min(c0 + 1, cols - 1), min(r0 + 1, rows - 1)
        fx, fy = x - c0, y - r0
        top = field[r0, c0] * (1 - fx) + field[r0, c1] * fx
        bottom = field[r1, c0] * (1 - fx) + field[r1, c1] * fx
        return float(top * (1 - fy) + bottom * fy)

    def potential(self, g: np.ndarray) -> float:
        """Total potential (metres) at grid point g."""
        d_m = float(np.hypot(*(np.asarray(g) - self.goal_g))) * self.grid.cell_m
        return float(attractive_potential(d_m, self.cfg)) + self._bilinear(self.repulsive, g)

    def gradient(self, g: np.ndarray) -> np.ndarray:
        """Gradient of the total potential at grid point g, per metre, in grid axes (gx, gy)."""
        cell = self.grid.cell_m
        att = attractive_gradient(np.asarray(g) * cell, self.goal_g * cell, self.cfg)
        rep = np.array([self._bilinear(self.grad_gx, g), self._bilinear(self.grad_gy, g)])
        return att + rep

    def force_xy(self, xy_m) -> np.ndarray:
        """Negative gradient at a world point, in world axes (east, north), per metre."""
        grad = self.gradient(self.grid.xy_to_grid(np.asarray(xy_m, dtype=float)))
        return np.array([-grad[0], grad[1]])  # grid gy grows southwards


@dataclass(frozen=True)
class DescentResult:
    """Path of a potential-field descent in world metres and how it ended."""

    path_xy_m: np.ndarray
    status: DescentStatus
    steps: int


def descend(field: PotentialField, start_xy_m, allowed: np.ndarray) -> DescentResult:
    """Normalised gradient descent from ``start_xy_m`` towards the field's goal.

    ``allowed`` (bool per cell) is the clearance-respecting free space; stepping outside it ends
    the descent with ``CLEARANCE``. Local minima and oscillation are detected as documented in
    the module docstring.
    """
    cfg = field.cfg
    grid = field.grid
    cell = grid.cell_m
    step_g = cfg.step_m / cell
    g = grid.xy_to_grid(np.asarray(start_xy_m, dtype=float))
    goal_g = field.goal_g
    path = [g.copy()]
    best_u = field.potential(g)
    last_improvement = 0
    visits: dict[tuple[int, int], int] = {}
    rows, cols = grid.shape
    status = DescentStatus.MAX_STEPS
    step = 0
    for step in range(1, cfg.max_steps + 1):
        if float(np.hypot(*(g - goal_g))) * cell <= cfg.goal_tolerance_m:
            path.append(goal_g.copy())
            status = DescentStatus.REACHED
            break
        grad = field.gradient(g)
        norm = float(np.hypot(grad[0], grad[1]))
        if norm < 1e-12:
            status = DescentStatus.LOCAL_MINIMUM
            break
        g = g - step_g * grad / norm
        g[0] = min(max(g[0], 0.0), cols - 1e-9)
        g[1] = min(max(g[1], 0.0), rows - 1e-9)
        path.append(g.copy())
        cell_rc = (int(g[1]), int(g[0]))
        if not allowed[cell_rc]:
            status = DescentStatus.CLEARANCE
            break
        visits[cell_rc] = visits.get(cell_rc, 0) + 1
        if visits[cell_rc] > cfg.max_cell_visits:
            status = DescentStatus.OSCILLATION
            break
        u = field.potential(g)
        if u < best_u - cfg.min_progress_m:
            best_u = u
            last_improvement = step
        elif step - last_improvement >= cfg.stall_window_steps:
            status = DescentStatus.LOCAL_MINIMUM
            break
    log.debug("potential-field descent: %s after %d steps", status.value, step)
    return DescentResult(path_xy_m=grid.grid_to_xy(np.asarray(path)), status=status, steps=step)
