"""What the world's buildings do to the sensors (pure numpy): the surface height under the vehicle,
the range along a ray to the first roof, wall or ground it meets (the range finder), a seeded
magnetic anomaly field around the buildings, and the share of the sky the buildings hide from a GPS
antenna. Sensor models in sitl.sensors read these; only their noisy outputs reach the bus.

Positions are world ENU metres around the map centre (scenenav.core.frames.world_to_pixel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from scenenav.core.frames import world_to_pixel
from worlds.raycast import HeightField, first_hits

#: GPS elevation mask: satellites below it are not used anyway (u-blox default minimum elevation
#: 10 deg; 15 deg is the common survey-grade mask), so buildings hide sky only above it.
SKY_MASK_ELEVATION_DEG = 15.0
#: Imported worlds have no land cover: a DSM pixel higher than this counts as built (the
#: generator's lowest buildings, outbuildings, are 3-6 m; worlds.blocks).
BUILDING_MIN_HEIGHT_M = 2.5
#: Azimuths and ray steps of the sky-obstruction scan.
SKY_AZIMUTHS = 16
SKY_RAY_STEP_M = 10.0
SKY_RAY_LENGTH_M = 200.0


@dataclass(frozen=True, eq=False)   # numpy fields
class Surface:
    """The world's surface model: ``dsm_m`` (H, W) metres above the ground per map pixel and
    ``built`` (H, W) bool, the pixels of buildings (magnetic anomaly sources)."""

    dsm_m: np.ndarray
    built: np.ndarray
    m_per_px: float

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.dsm_m.shape[0]), int(self.dsm_m.shape[1])

    def _index(self, x_m, y_m):
        h, w = self.shape
        u, v = world_to_pixel(x_m, y_m, w, h, self.m_per_px)
        col = np.floor(np.asarray(u)).astype(int)
        row = np.floor(np.asarray(v)).astype(int)
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        return row, col, inside

    def height_at(self, x_m, y_m):
        """Surface height (m above the ground) at ENU points; 0 outside the map."""
        row, col, inside = self._index(x_m, y_m)
        out = np.zeros(np.shape(row), dtype=float)
        out[inside] = self.dsm_m[row[inside], col[inside]]
        return float(out) if out.ndim == 0 else out

    @cached_property
    def height_field(self) -> HeightField:
        """The DSM ready for ray casting, built on first use."""
        return HeightField(self.dsm_m, self.m_per_px)

    def range_m(self, origin_enu_m, direction_enu) -> float:
        """Distance (m) from ``origin_enu_m`` along ``direction_enu`` (any length) to the first
        surface it meets (roof, wall or ground; the ground plane z = 0 outside the map); inf if the
        ray never comes down. The same ray caster as the camera (worlds.raycast)."""
        d = np.asarray(direction_enu, dtype=float)[:3]
        norm = float(np.linalg.norm(d))
        if not norm > 0.0:
            return math.inf
        hits = first_hits(self.height_field, np.asarray(origin_enu_m, dtype=float)[None, :3], (d / norm)[None, :])
        s = float(hits.range_s[0])
        return s if math.isfinite(s) and not bool(hits.miss[0]) else math.inf

    def sky_obstruction(self, position_enu_m) -> float:
        """Share (0..1) of azimuths in which a building rises above the GPS elevation mask as seen
        from ``position_enu_m`` (rays of SKY_RAY_LENGTH_M every SKY_RAY_STEP_M on SKY_AZIMUTHS)."""
        x, y, z = (float(c) for c in position_enu_m[:3])
        az = np.arange(SKY_AZIMUTHS) * (2.0 * math.pi / SKY_AZIMUTHS)
        dist = np.arange(1, int(SKY_RAY_LENGTH_M / SKY_RAY_STEP_M) + 1) * SKY_RAY_STEP_M
        px = x + np.outer(np.sin(az), dist)
        py = y + np.outer(np.cos(az), dist)
        rise = np.asarray(self.height_at(px, py)) - z
        tan_mask = math.tan(math.radians(SKY_MASK_ELEVATION_DEG))
        blocked = np.any(rise > tan_mask * dist[None, :], axis=1)
        return float(np.mean(blocked))


class MagneticAnomalyField:
    """Local magnetic anomalies of the buildings (steel, reinforced concrete), seeded.

    The map is cut into square cells of ``cell_m``; a cell whose built share is ``f`` gets a random
    ground-level anomaly vector ~ N(0, (strength f)^2 I) (ENU, mGauss), bilinearly interpolated
    between cell centres. Above the surface it decays like ArduPilot SITL's SIM_MAG_ALY:
    ``(h0 / (h0 + h))^3``, h the height above the DSM below the vehicle, h0 the height where it has
    fallen to 1/8. The cube is the far field of a dipole (|B| ~ 1/r^3); h0 places the effective
    source below the surface, which keeps the field finite on the roof.
    """

    def __init__(self, surface: Surface, strength_mgauss: float, decay_height_m: float,
                 cell_m: float, rng: np.random.Generator) -> None:
        self.surface = surface
        self.decay_height_m = float(decay_height_m)
        self.cell_m = float(cell_m)
        h, w = surface.shape
        cell_px = max(1, int(round(cell_m / surface.m_per_px)))
        ny, nx = -(-h // cell_px), -(-w // cell_px)
        padded = np.zeros((ny * cell_px, nx * cell_px), dtype=float)
        padded[:h, :w] = surface.built
        share = padded.reshape(ny, cell_px, nx, cell_px).mean(axis=(1, 3))
        self._cell_px = cell_px
        self._cells = strength_mgauss * share[..., None] * rng.standard_normal((ny, nx, 3))

    def ground_level_enu_mgauss(self, x_m: float, y_m: float) -> np.ndarray:
        """The anomaly at the surface below (x, y), ENU mGauss (zeros off the map)."""
        h, w = self.surface.shape
        u, v = world_to_pixel(x_m, y_m, w, h, self.surface.m_per_px)
        cu = u / self._cell_px - 0.5
        cv = v / self._cell_px - 0.5
        ny, nx = self._cells.shape[:2]
        if not (-0.5 <= cu <= nx - 0.5 and -0.5 <= cv <= ny - 0.5):
            return np.zeros(3)
        cu = min(max(cu, 0.0), nx - 1.0)
        cv = min(max(cv, 0.0), ny - 1.0)
        i0, j0 = int(cv), int(cu)
        i1, j1 = min(i0 + 1, ny - 1), min(j0 + 1, nx - 1)
        fv, fu = cv - i0, cu - j0
        c = self._cells
        return ((1 - fv) * ((1 - fu) * c[i0, j0] + fu * c[i0, j1])
                + fv * ((1 - fu) * c[i1, j0] + fu * c[i1, j1]))

    def decay(self, height_above_surface_m: float) -> float:
        """Attenuation at a height above the surface: 1 on it, 1/8 at ``decay_height_m``."""
        h = max(0.0, float(height_above_surface_m))
        return (self.decay_height_m / (self.decay_height_m + h)) ** 3

    def at(self, position_enu_m) -> np.ndarray:
        """The anomaly (ENU, mGauss) at a 3-D position."""
        x, y, z = (float(c) for c in position_enu_m[:3])
        ground = self.surface.height_at(x, y)
        return self.ground_level_enu_mgauss(x, y) * self.decay(z - ground)
