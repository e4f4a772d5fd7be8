"""Geofence and rally points in the flight core (part of ``FlightCore``): the uploaded fence and
rally lists, the breach check each tick and where RTL goes. The rules are ``geofence``'s.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import numpy as np

from autopilot_bridge.failsafe import FailsafeEvent
from autopilot_bridge.geofence import (
    FenceGeometry,
    FenceMonitor,
    FenceSettings,
    FenceType,
    parse_fence,
    rally_or_home,
    rally_points_local,
)
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import MavSeverity, MissionItem, Outcome


class GeofenceMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_geofence(self) -> None:
        self.fence = FenceMonitor()
        self._rally_items: tuple[MissionItem, ...] = ()

    def fence_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        geometry, reason = parse_fence(items, self.geo.to_enu)
        if geometry is None:
            return self._refuse(reason)
        self.fence.geometry = geometry
        self._bus_text(MavSeverity.INFO, f"fence: {len(geometry.polygons)} polygons, "
                                         f"{len(geometry.circles)} circles")
        return Outcome(True)

    def rally_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        self._rally_items = tuple(items)
        self._bus_text(MavSeverity.INFO, f"rally: {len(items)} points")
        return Outcome(True)

    @property
    def fence_geometry(self) -> FenceGeometry:
        return self.fence.geometry

    def fence_settings(self) -> FenceSettings:
        p = self.params
        return FenceSettings(enabled=p.get_int("FENCE_ENABLE") == 1,
                             types=FenceType(p.get_int("FENCE_TYPE") & 0xF),
                             action=p.get_int("FENCE_ACTION"), alt_max_m=p.get("FENCE_ALT_MAX"),
                             alt_min_m=p.get("FENCE_ALT_MIN"), radius_m=p.get("FENCE_RADIUS"),
                             margin_m=p.get("FENCE_MARGIN"))

    def _fence_events(self, flying: bool, landing: bool, position_enu_m) -> list[FailsafeEvent]:
        return self.fence.update(self._now_s, self._armed, flying, landing,
                                 self._mode == CopterMode.LAND, position_enu_m, self._home,
                                 self.fence_settings())

    def _rtl_destination(self, est) -> np.ndarray:
        """Home, or the rally point ArduCopter's RTL would choose."""
        home = self._home if self._home is not None else np.asarray(est.position_enu_m, dtype=float)
        if not self._rally_items:
            return home
        points = rally_points_local(self._rally_items, self.geo.to_enu, float(home[2]))
        return rally_or_home(points, est.position_enu_m, home, self.params.get("RALLY_LIMIT_KM"),
                             self.params.get_int("RALLY_INCL_HOME") == 1)
