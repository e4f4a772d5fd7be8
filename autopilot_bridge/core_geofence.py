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
from scenenav.core.fence_items import FenceEnable


class GeofenceMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_geofence(self) -> None:
        self.fence = FenceMonitor()
        self._rally_items: tuple[MissionItem, ...] = ()
        # DO_FENCE_ENABLE: ArduPilot's runtime switch over FENCE_ENABLE, not stored as a parameter
        # (AC_Fence ``enable``): None = as FENCE_ENABLE says (all FENCE_TYPE fences or none),
        # else the fence types switched on
        self._fences_enabled: FenceType | None = None

    def _fences_on(self) -> FenceType:
        if self._fences_enabled is not None:
            return self._fences_enabled
        return FenceType.all_fences() if self.params.get_int("FENCE_ENABLE") == 1 else FenceType.NONE

    def _fences_present(self) -> FenceType:
        """AC_Fence ``present``: the FENCE_TYPE fences that can be checked (a polygon fence only
        with an uploaded fence)."""
        present = FenceType(self.params.get_int("FENCE_TYPE") & FenceType.all_fences())
        if self.fence.geometry.empty:
            present &= ~FenceType.POLYGON
        return present

    def fence_enable(self, action: int, fence_mask: int = 0) -> Outcome:
        """DO_FENCE_ENABLE (command or mission item): ``action`` 0 disables, 1 enables, 2 disables
        the floor (ALT_MIN) only; ``fence_mask`` the FENCE_TYPE bits it applies to (0 = all), as
        ArduPilot's GCS_Fence / AP_Mission. Enabling with none of them present fails; an unknown
        action is refused."""
        fences = FenceType(fence_mask & FenceType.all_fences()) or FenceType.all_fences()
        on = self._fences_on()
        if action == FenceEnable.DISABLE:
            self._fences_enabled = on & ~fences
            self._announce(MavSeverity.INFO, "Fence disabled")
        elif action == FenceEnable.ENABLE:
            if not self._fences_present() & fences:
                return self._refuse("Fence: no fence present to enable")
            self._fences_enabled = on | fences
            self._announce(MavSeverity.INFO, "Fence enabled")
        elif action == FenceEnable.DISABLE_FLOOR:
            self._fences_enabled = on & ~FenceType.ALT_MIN
            self._announce(MavSeverity.INFO, "Fence floor disabled")
        else:
            return self._refuse(f"Fence: unknown DO_FENCE_ENABLE action {action}")
        return Outcome(True)

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
        key = (p.generation, self._fences_enabled)
        cached = self._settings_cache.get("fence")
        if cached is not None and cached[0] == key:
            return cached[1]
        settings = self._build_fence_settings()
        self._settings_cache["fence"] = (key, settings)
        return settings

    def _build_fence_settings(self) -> FenceSettings:
        p = self.params
        on = self._fences_on()
        types = FenceType(p.get_int("FENCE_TYPE") & 0xF) & on
        enabled = bool(on)
        return FenceSettings(enabled=enabled, types=types,
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
