"""Geofence and rally points as ArduCopter 4.5 runs them (pure: no zenoh, no pymavlink).

Fence items come from a mission_type FENCE upload (``fence_rally_protocol``), as QGC's and MAVProxy's
``fence`` send them (``AC_PolyFence_loader``): NAV_FENCE_POLYGON_VERTEX_INCLUSION / _EXCLUSION
(param1 = the polygon's vertex count, consecutive items), NAV_FENCE_CIRCLE_INCLUSION / _EXCLUSION
(param1 = radius, m), NAV_FENCE_RETURN_POINT (stored, not used by copters). Rally points are
NAV_RALLY_POINT items of a mission_type RALLY upload (``AP_Rally``).

The breach check (``AC_Fence::check``, ``ArduCopter/fence.cpp``) runs at 25 Hz while armed with
``FENCE_ENABLE`` = 1 and ``FENCE_TYPE`` bits: 1 maximum altitude (``FENCE_ALT_MAX`` above home),
2 circle (``FENCE_RADIUS`` around home), 4 polygons and circles uploaded (outside every inclusion
shape, or inside an exclusion one), 8 minimum altitude (``FENCE_ALT_MIN``; not checked while
landing, as ArduCopter). A new breach while flying is announced "Fence Breached" (NOTICE in
ArduCopter; CRITICAL here like every failsafe) and runs ``FENCE_ACTION``: 0 report only, 1 RTL
(LAND if RTL is refused), 2 LAND, 3 SmartRTL or RTL (RTL here), 4 BRAKE, 5 SmartRTL or LAND (LAND
here); more than 100 m outside the breached fence (``AC_FENCE_GIVE_UP_DISTANCE``) -> LAND. In LAND
nothing changes. All breaches gone -> "Fence breach cleared". On the ground no action (ArduCopter
disarms a landed vehicle on a breach).

Rally (``AP_Rally::calc_best_rally_or_home_location``): RTL goes to the nearest rally point, except
to home when that point is beyond ``RALLY_LIMIT_KM`` (0 = no limit) and home is nearer, or when
``RALLY_INCL_HOME`` = 1 and home is nearer. Differs: the return altitude is RTL's (ArduCopter flies
at the rally point's altitude), and the vehicle lands at the rally point at home's height.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from autopilot_bridge.failsafe import FailsafeAction, FailsafeEvent, FailsafeKind
from autopilot_bridge.vehicle_interface import MavSeverity, MissionItem
from scenenav.core.fence_items import FenceCommand, FenceType  # noqa: F401  (re-exported)

FENCE_CHECK_PERIOD_S = 0.04        # ArduCopter checks the fence at 25 Hz
FENCE_GIVE_UP_DISTANCE_M = 100.0   # AC_Fence: further outside than this -> LAND instead of RTL
MAX_FENCE_ITEMS = 100              # differs: ArduPilot's limit is its storage (AC_PolyFence_loader)
MAX_RALLY_POINTS = 100             # differs: ArduPilot's limit is its storage (AP_Rally)


FENCE_COMMANDS = frozenset({FenceCommand.RETURN_POINT, FenceCommand.POLYGON_VERTEX_INCLUSION,
                            FenceCommand.POLYGON_VERTEX_EXCLUSION, FenceCommand.CIRCLE_INCLUSION,
                            FenceCommand.CIRCLE_EXCLUSION})
RALLY_COMMANDS = frozenset({FenceCommand.RALLY_POINT})


class FenceAction(IntEnum):
    """FENCE_ACTION (ArduCopter 4.5)."""

    REPORT_ONLY = 0
    RTL_OR_LAND = 1
    ALWAYS_LAND = 2
    SMARTRTL_OR_RTL_OR_LAND = 3
    BRAKE_OR_LAND = 4
    SMARTRTL_OR_LAND = 5


_ACTIONS = {
    FenceAction.RTL_OR_LAND: FailsafeAction.RTL,
    FenceAction.ALWAYS_LAND: FailsafeAction.LAND,
    FenceAction.SMARTRTL_OR_RTL_OR_LAND: FailsafeAction.RTL,
    FenceAction.BRAKE_OR_LAND: FailsafeAction.BRAKE,
    FenceAction.SMARTRTL_OR_LAND: FailsafeAction.LAND,
}


@dataclass(frozen=True)
class Polygon:
    inclusion: bool
    vertices_xy_m: tuple[tuple[float, float], ...]     # ENU metres from the EKF origin


@dataclass(frozen=True)
class Circle:
    inclusion: bool
    center_xy_m: tuple[float, float]
    radius_m: float


@dataclass(frozen=True)
class FenceGeometry:
    """The uploaded fence in local metres (ENU, EKF origin)."""

    polygons: tuple[Polygon, ...] = ()
    circles: tuple[Circle, ...] = ()

    @property
    def empty(self) -> bool:
        return not self.polygons and not self.circles


ToLocal = Callable[[float, float], tuple[float, float]]   # (lat, lon) degrees -> ENU x, y metres


def parse_fence(items: Sequence[MissionItem], to_local: ToLocal) -> tuple[FenceGeometry | None, str]:
    """Fence items -> geometry, or (None, reason) as ``AC_PolyFence_loader`` refuses an upload."""
    polygons: list[Polygon] = []
    circles: list[Circle] = []
    i = 0
    while i < len(items):
        item = items[i]
        cmd = item.command
        if cmd in (FenceCommand.POLYGON_VERTEX_INCLUSION, FenceCommand.POLYGON_VERTEX_EXCLUSION):
            count = int(item.param1)
            if count < 3 or item.param1 != count:
                return None, f"Fence: polygon at item {i} needs >= 3 vertices"
            block = items[i:i + count]
            if len(block) != count or any(b.command != cmd or int(b.param1) != count for b in block):
                return None, f"Fence: polygon at item {i} is incomplete"
            polygons.append(Polygon(cmd == FenceCommand.POLYGON_VERTEX_INCLUSION,
                                    tuple(to_local(b.lat_deg, b.lon_deg) for b in block)))
            i += count
            continue
        if cmd in (FenceCommand.CIRCLE_INCLUSION, FenceCommand.CIRCLE_EXCLUSION):
            if not (math.isfinite(item.param1) and item.param1 > 0.0):
                return None, f"Fence: circle at item {i} needs a positive radius"
            circles.append(Circle(cmd == FenceCommand.CIRCLE_INCLUSION,
                                  to_local(item.lat_deg, item.lon_deg), float(item.param1)))
        elif cmd != FenceCommand.RETURN_POINT:
            return None, f"Fence: item {i} is not a fence command"
        i += 1
    return FenceGeometry(tuple(polygons), tuple(circles)), ""


def _inside_polygon(x: float, y: float, vertices: Sequence[tuple[float, float]]) -> bool:
    inside = False
    n = len(vertices)
    for k in range(n):
        x1, y1 = vertices[k]
        x2, y2 = vertices[(k + 1) % n]
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def _distance_to_polygon_edge(x: float, y: float, vertices: Sequence[tuple[float, float]]) -> float:
    best = math.inf
    p = np.array([x, y])
    n = len(vertices)
    for k in range(n):
        a, b = np.array(vertices[k]), np.array(vertices[(k + 1) % n])
        ab = b - a
        t = float(np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0))
        best = min(best, float(np.linalg.norm(p - (a + t * ab))))
    return best


@dataclass(frozen=True)
class FenceSettings:
    """The FENCE_* parameters."""

    enabled: bool = False            # FENCE_ENABLE
    types: FenceType = FenceType.ALT_MAX | FenceType.CIRCLE | FenceType.POLYGON   # FENCE_TYPE 7
    action: int = int(FenceAction.RTL_OR_LAND)   # FENCE_ACTION
    alt_max_m: float = 100.0         # FENCE_ALT_MAX (above home)
    alt_min_m: float = -10.0         # FENCE_ALT_MIN
    radius_m: float = 150.0          # FENCE_RADIUS (around home)
    margin_m: float = 2.0            # FENCE_MARGIN (guidance keeps this far inside)


def breaches(s: FenceSettings, geometry: FenceGeometry, pos_enu_m: Sequence[float],
             home_enu_m: Sequence[float], landing: bool) -> tuple[FenceType, float]:
    """The breached fence types at a position and how far outside the worst one is (m)."""
    x, y, z = (float(v) for v in pos_enu_m[:3])
    hx, hy, hz = (float(v) for v in home_enu_m[:3])
    found, distance = FenceType.NONE, 0.0
    alt = z - hz
    if s.types & FenceType.ALT_MAX and alt > s.alt_max_m:
        found |= FenceType.ALT_MAX
        distance = max(distance, alt - s.alt_max_m)
    if s.types & FenceType.ALT_MIN and not landing and alt < s.alt_min_m:
        found |= FenceType.ALT_MIN
        distance = max(distance, s.alt_min_m - alt)
    if s.types & FenceType.CIRCLE:
        r = math.hypot(x - hx, y - hy)
        if r > s.radius_m:
            found |= FenceType.CIRCLE
            distance = max(distance, r - s.radius_m)
    if s.types & FenceType.POLYGON and not geometry.empty:
        out = polygon_breach_distance(geometry, x, y)
        if out is not None:
            found |= FenceType.POLYGON
            distance = max(distance, out)
    return found, distance


def polygon_breach_distance(geometry: FenceGeometry, x: float, y: float) -> float | None:
    """None when (x, y) satisfies the uploaded shapes, else the distance back to an allowed area."""
    worst: float | None = None
    inclusions = [p for p in geometry.polygons if p.inclusion]
    circles_in = [c for c in geometry.circles if c.inclusion]
    for p in inclusions:
        if not _inside_polygon(x, y, p.vertices_xy_m):
            worst = max(worst or 0.0, _distance_to_polygon_edge(x, y, p.vertices_xy_m))
    for c in circles_in:
        d = math.hypot(x - c.center_xy_m[0], y - c.center_xy_m[1])
        if d > c.radius_m:
            worst = max(worst or 0.0, d - c.radius_m)
    for p in geometry.polygons:
        if not p.inclusion and _inside_polygon(x, y, p.vertices_xy_m):
            worst = max(worst or 0.0, _distance_to_polygon_edge(x, y, p.vertices_xy_m))
    for c in geometry.circles:
        d = math.hypot(x - c.center_xy_m[0], y - c.center_xy_m[1])
        if not c.inclusion and d < c.radius_m:
            worst = max(worst or 0.0, c.radius_m - d)
    return worst


class FenceMonitor:
    """Breach detection and the FENCE_ACTION event (see the module docstring)."""

    def __init__(self) -> None:
        self.geometry = FenceGeometry()
        self._breaches = FenceType.NONE
        self._next_check_s: float | None = None
        self.breach_count = 0

    @property
    def breached(self) -> FenceType:
        return self._breaches

    def update(self, now_s: float, armed: bool, flying: bool, landing: bool, in_land_mode: bool,
               pos_enu_m: Sequence[float], home_enu_m: Sequence[float] | None,
               s: FenceSettings) -> list[FailsafeEvent]:
        if not s.enabled or home_enu_m is None:
            self._breaches = FenceType.NONE
            return []
        if self._next_check_s is not None and now_s < self._next_check_s:
            return []
        self._next_check_s = now_s + FENCE_CHECK_PERIOD_S
        found, distance = breaches(s, self.geometry, pos_enu_m, home_enu_m, landing)
        new = found & ~self._breaches
        had = self._breaches
        self._breaches = found
        if not armed:
            return []
        if new:
            self.breach_count += 1
            if not flying:
                return []
            try:
                setting = FenceAction(int(s.action))
            except ValueError:
                setting = FenceAction.RTL_OR_LAND
            action = _ACTIONS.get(setting, FailsafeAction.REPORT)
            if action != FailsafeAction.REPORT and distance > FENCE_GIVE_UP_DISTANCE_M:
                action = FailsafeAction.LAND
            if in_land_mode:
                action = FailsafeAction.REPORT
            return [FailsafeEvent(FailsafeKind.FENCE, action, MavSeverity.CRITICAL, "Fence Breached")]
        if had and not found and flying:
            return [FailsafeEvent(FailsafeKind.FENCE, FailsafeAction.CLEARED, MavSeverity.NOTICE,
                                  "Fence breach cleared")]
        return []


def rally_points_local(items: Sequence[MissionItem], to_local: ToLocal,
                       home_z_m: float) -> tuple[tuple[float, float, float], ...]:
    """Rally items -> ENU points (x, y, z above home's z using the item's relative altitude)."""
    return tuple((*to_local(it.lat_deg, it.lon_deg), home_z_m + float(it.alt_m)) for it in items)


def rally_or_home(points: Sequence[tuple[float, float, float]], pos_enu_m: Sequence[float],
                  home_enu_m: Sequence[float], limit_km: float, include_home: bool) -> np.ndarray:
    """Where RTL goes (AP_Rally::calc_best_rally_or_home_location); z is home's (RTL lands)."""
    home = np.asarray(home_enu_m, dtype=float)[:3]
    pos = np.asarray(pos_enu_m, dtype=float)[:2]
    best: np.ndarray | None = None
    best_d = math.inf
    for p in points:
        d = float(np.linalg.norm(np.array(p[:2]) - pos))
        if d < best_d:
            best, best_d = np.array([p[0], p[1], home[2]]), d
    home_d = float(np.linalg.norm(home[:2] - pos))
    if best is None or (limit_km > 0.0 and best_d > limit_km * 1000.0 and home_d < best_d):
        return home.copy()
    if include_home and home_d < best_d:
        return home.copy()
    return best
