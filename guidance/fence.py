"""The autopilot's geofence as the guidance planner sees it (pure: no zenoh, no pymavlink).

The guidance node downloads the fence over MAVLink (mission_type FENCE) and reads FENCE_ENABLE,
FENCE_TYPE, FENCE_RADIUS, FENCE_MARGIN and FENCE_ALT_MAX (``guidance.mavlink_client``); this module
turns them into ENU geometry (``fence_from_items``) and into obstacles on the assistant map
(``apply_fence``: every pixel where the vehicle may not fly becomes a bad matching area, so the
planner's routes, which keep their clearance from bad areas, stay inside the fence).

The fence is ArduCopter's ``AC_Fence`` (the autopilot's ``autopilot_bridge.geofence`` enforces it):
with FENCE_ENABLE = 1, FENCE_TYPE bit 2 (circle) keeps the vehicle within FENCE_RADIUS of home, bit 4
(polygon) inside every inclusion polygon / circle and outside every exclusion one
(NAV_FENCE_POLYGON_VERTEX_INCLUSION / _EXCLUSION, param1 = the polygon's vertex count, consecutive
items; NAV_FENCE_CIRCLE_INCLUSION / _EXCLUSION, param1 = radius m; NAV_FENCE_RETURN_POINT ignored).
Routes keep FENCE_MARGIN inside the boundary; the cruise altitude stays FENCE_MARGIN below
FENCE_ALT_MAX (bit 1). Altitudes below (bit 8) concern take-off and landing, not the route.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scenenav.core.errors import UserError
from scenenav.core.fence_items import FenceCommand, FenceType  # noqa: F401  (re-exported)
from scenenav.core.frames import geodetic_to_enu, pixel_to_world

FENCE_PARAM_NAMES = ("FENCE_ENABLE", "FENCE_TYPE", "FENCE_RADIUS", "FENCE_MARGIN", "FENCE_ALT_MAX")


@dataclass(frozen=True)
class FenceItem:
    """One downloaded fence item (MISSION_ITEM_INT of mission_type FENCE), degrees."""

    command: int
    param1: float
    lat_deg: float
    lon_deg: float


@dataclass(frozen=True)
class Fence:
    """Where the vehicle may fly, in world ENU metres. An empty fence allows everything."""

    inclusion_polygons: tuple[np.ndarray, ...] = ()
    exclusion_polygons: tuple[np.ndarray, ...] = ()
    inclusion_circles: tuple[tuple[float, float, float], ...] = ()   # (x, y, radius)
    exclusion_circles: tuple[tuple[float, float, float], ...] = ()
    margin_m: float = 0.0
    alt_max_m: float | None = None           # above home
    notes: tuple[str, ...] = field(default=())

    @property
    def horizontal(self) -> bool:
        return bool(self.inclusion_polygons or self.exclusion_polygons or self.inclusion_circles
                    or self.exclusion_circles)

    def describe(self) -> str:
        parts = []
        for name, value in (("inclusion polygon", self.inclusion_polygons),
                            ("exclusion polygon", self.exclusion_polygons),
                            ("inclusion circle", self.inclusion_circles),
                            ("exclusion circle", self.exclusion_circles)):
            if value:
                parts.append(f"{len(value)} {name}{'s' if len(value) > 1 else ''}")
        if self.alt_max_m is not None:
            parts.append(f"max altitude {self.alt_max_m:.0f} m")
        return ", ".join(parts) + f", margin {self.margin_m:.1f} m" if parts else "no fence"

    def allowed(self, xy_m) -> np.ndarray:
        """(N,) True where a point (N, 2) is at least ``margin_m`` inside the fence."""
        pts = np.asarray(xy_m, dtype=float).reshape(-1, 2)
        ok = np.ones(len(pts), dtype=bool)
        m = self.margin_m
        for poly in self.inclusion_polygons:
            ok &= point_in_polygon(pts, poly) & (distance_to_edges_m(pts, poly) >= m)
        for poly in self.exclusion_polygons:
            ok &= ~point_in_polygon(pts, poly) & (distance_to_edges_m(pts, poly) >= m)
        for x, y, r in self.inclusion_circles:
            ok &= np.hypot(pts[:, 0] - x, pts[:, 1] - y) <= r - m
        for x, y, r in self.exclusion_circles:
            ok &= np.hypot(pts[:, 0] - x, pts[:, 1] - y) >= r + m
        return ok


def point_in_polygon(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule (AC_PolyFence's Polygon_outside, inverted) for points (N, 2), vertices (K, 2)."""
    inside = np.zeros(len(pts), dtype=bool)
    x, y = pts[:, 0], pts[:, 1]
    k = len(poly)
    for i in range(k):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % k]
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < x_at)
    return inside


def distance_to_edges_m(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance (N,) from each point to the nearest edge of the closed polygon."""
    best = np.full(len(pts), np.inf)
    k = len(poly)
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        ab = b - a
        denom = float(ab @ ab)
        t = np.zeros(len(pts)) if denom == 0.0 else np.clip(((pts - a) @ ab) / denom, 0.0, 1.0)
        nearest = a + t[:, None] * ab
        best = np.minimum(best, np.hypot(pts[:, 0] - nearest[:, 0], pts[:, 1] - nearest[:, 1]))
    return best


def fence_from_items(items: list[FenceItem] | tuple[FenceItem, ...], params: dict[str, float],
                     home_xy_m, origin_lat_deg: float, origin_lon_deg: float) -> Fence:
    """The fence the autopilot enforces: ``items`` as downloaded, ``params`` the FENCE_* values
    (``FENCE_PARAM_NAMES``), home (the take-off point) for FENCE_RADIUS. FENCE_ENABLE 0 = no fence."""
    if int(params.get("FENCE_ENABLE", 0)) != 1:
        return Fence(notes=("FENCE_ENABLE is 0",))
    kind = FenceType(int(params.get("FENCE_TYPE", 0)) & 0xF)
    margin = max(float(params.get("FENCE_MARGIN", 0.0)), 0.0)
    alt_max = float(params["FENCE_ALT_MAX"]) if kind & FenceType.ALT_MAX and "FENCE_ALT_MAX" in params \
        else None
    inc_poly: list[np.ndarray] = []
    exc_poly: list[np.ndarray] = []
    inc_circ: list[tuple[float, float, float]] = []
    exc_circ: list[tuple[float, float, float]] = []
    if kind & FenceType.CIRCLE and float(params.get("FENCE_RADIUS", 0.0)) > 0.0:
        hx, hy = (float(v) for v in home_xy_m)
        inc_circ.append((hx, hy, float(params["FENCE_RADIUS"])))
    if kind & FenceType.POLYGON:
        i = 0
        while i < len(items):
            it = items[i]
            if it.command in (FenceCommand.POLYGON_VERTEX_INCLUSION, FenceCommand.POLYGON_VERTEX_EXCLUSION):
                count = int(it.param1)
                verts = items[i:i + count]
                if count < 3 or len(verts) < count or any(v.command != it.command for v in verts):
                    raise UserError(f"fence: polygon at item {i} is incomplete; expected {count} "
                                    "consecutive vertices (at least 3)")
                lat = np.array([v.lat_deg for v in verts])
                lon = np.array([v.lon_deg for v in verts])
                x, y = geodetic_to_enu(lat, lon, origin_lat_deg, origin_lon_deg)
                poly = np.column_stack([x, y])
                (inc_poly if it.command == FenceCommand.POLYGON_VERTEX_INCLUSION else exc_poly).append(poly)
                i += count
                continue
            if it.command in (FenceCommand.CIRCLE_INCLUSION, FenceCommand.CIRCLE_EXCLUSION):
                x, y = geodetic_to_enu(it.lat_deg, it.lon_deg, origin_lat_deg, origin_lon_deg)
                circle = (float(x), float(y), float(it.param1))
                (inc_circ if it.command == FenceCommand.CIRCLE_INCLUSION else exc_circ).append(circle)
            i += 1
    return Fence(tuple(inc_poly), tuple(exc_poly), tuple(inc_circ), tuple(exc_circ), margin, alt_max)


def apply_fence(probability: np.ndarray, m_per_px: float, fence: Fence) -> np.ndarray:
    """The assistant map with every pixel outside the fence (or within its margin) a bad matching
    area (probability 0; a copy, same dtype): the planner routes around it as around any bad area.
    Without a horizontal fence the map itself."""
    if not fence.horizontal:
        return probability
    prob = np.array(probability, copy=True)
    h, w = prob.shape
    rows, cols = np.mgrid[0:h, 0:w]
    x, y = pixel_to_world(cols.ravel() + 0.5, rows.ravel() + 0.5, w, h, m_per_px)
    allowed = fence.allowed(np.column_stack([x, y])).reshape(h, w)
    prob[~allowed] = 0.0
    return prob


def check_points_inside(fence: Fence, points_xy_m, names: list[str]) -> None:
    """UserError for a route point (start, goals) where the fence forbids flying."""
    pts = np.asarray(points_xy_m, dtype=float).reshape(-1, 2)
    for name, p, ok in zip(names, pts, fence.allowed(pts), strict=True):
        if not ok:
            raise UserError(f"{name} ({p[0]:.1f}, {p[1]:.1f}) m is outside the geofence "
                            f"({fence.describe()}); expected a point at least FENCE_MARGIN inside it")


def cruise_altitude_m(altitude_m: float, fence: Fence) -> float:
    """The route altitude, at most FENCE_MARGIN below FENCE_ALT_MAX (never below 1 m)."""
    if fence.alt_max_m is None or not math.isfinite(fence.alt_max_m):
        return altitude_m
    return max(1.0, min(altitude_m, fence.alt_max_m - fence.margin_m))
