"""The guidance laws a mode runs (on ``autopilot_bridge.guidance_law``): hold a point, track
waypoints (with in-flight speed and destination changes), RTL with RTL_ALT_FINAL, land.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import dataclasses
from enum import Enum
from typing import Sequence

import numpy as np

from autopilot_bridge.config import GuidanceConfig
from autopilot_bridge.control import PositionTarget
from autopilot_bridge.ekf import NavState
from autopilot_bridge.guidance_law import (
    GuidanceEventKind,
    GuidanceLaw,
    Lander,
    ReturnToLaunch,
    RtlPhase,
    Waypoint,
    WaypointTracker,
)


class LawKind(Enum):
    """What the active guidance law is doing (decides e.g. whether it may leave the ground)."""

    HOLD = "hold"
    TAKEOFF = "takeoff"
    TRACK = "track"
    LAND = "land"
    RTL = "rtl"
    CIRCLE = "circle"
    SMART_RTL = "smart_rtl"


class Hold:
    """Hold a fixed point (LOITER, GUIDED without a target, end of mission, vision failsafe)."""

    kind = LawKind.HOLD

    def __init__(self, position_enu_m, heading_rad: float | None) -> None:
        p = np.asarray(position_enu_m, dtype=float)
        self.position = np.array([p[0], p[1], p[2]])
        self.heading = heading_rad

    @property
    def complete(self) -> bool:
        return True

    def pop_events(self) -> list:
        return []

    def handle_position_reset(self, delta_xy_m) -> None:
        self.position[0] += float(delta_xy_m[0])
        self.position[1] += float(delta_xy_m[1])

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        p = self.position
        return PositionTarget((float(p[0]), float(p[1]), float(p[2])), heading_rad=self.heading)


class Tracker(WaypointTracker):
    """WaypointTracker that can change speed and destination in flight (DO_CHANGE_SPEED,
    WPNAV_SPEED, streamed GUIDED targets) without restarting the carrot from rest.

    Relies on WaypointTracker's protected state (``_wps``, ``_index``, ``_origin``, ``_s``, ``_v``,
    ``_setup_segment``): the carrot keeps its along-track speed, capped by the new limits.
    """

    kind = LawKind.TRACK

    @property
    def destination(self) -> np.ndarray:
        return np.array(self._wps[-1].position_enu_m)

    def retune(self, cfg: GuidanceConfig) -> None:
        self._cfg = cfg
        self._restart_segment(keep_origin=True)

    def set_speed(self, speed_m_s: float | None) -> None:
        """Horizontal speed of the current and the remaining legs (None: WPNAV_SPEED)."""
        self._wps = [Waypoint(w.position_enu_m, w.acceptance_radius_m, speed_m_s) for w in self._wps]
        self._restart_segment(keep_origin=True)

    def redirect(self, waypoints: Sequence[Waypoint]) -> None:
        """New destination(s) from the current carrot, keeping its speed."""
        carrot = self._carrot()
        self._wps = [Waypoint(tuple(float(a) for a in w.position_enu_m), w.acceptance_radius_m,
                              w.speed_m_s) for w in waypoints]
        self._index = 0
        self._complete = False
        self._origin = carrot
        self._s = 0.0
        self._restart_segment(keep_origin=True)

    def _restart_segment(self, keep_origin: bool) -> None:
        if self._complete:
            return
        v = self._v
        s = self._s
        self._setup_segment()
        self._s = min(s, self._length)
        self._v = min(v, self._v_max)


class Rtl(GuidanceLaw):
    """ReturnToLaunch plus RTL_ALT_FINAL (hold above home instead of landing when > 0)."""

    kind = LawKind.RTL

    def __init__(self, cfg: GuidanceConfig, home_enu_m, nav: NavState, final_alt_m: float,
                 heading_rad: float | None) -> None:
        self._rtl = ReturnToLaunch(cfg, home_enu_m, nav)
        self._home = np.asarray(home_enu_m, dtype=float)
        self._final_alt_m = final_alt_m
        self._final: Hold | None = None
        self._heading = heading_rad
        self._events: list = []

    @property
    def landing(self) -> bool:
        return self._final is None and self._rtl.phase == RtlPhase.LAND

    @property
    def phase_name(self) -> str:
        return "final" if self._final is not None else self._rtl.phase.value

    def handle_position_reset(self, delta_xy_m) -> None:
        if self._final is not None:
            self._final.handle_position_reset(delta_xy_m)
        else:
            self._rtl.handle_position_reset(delta_xy_m)

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        if self._final is not None:
            return self._final.update(nav, dt_s)
        target = self._rtl.update(nav, dt_s)
        for ev in self._rtl.pop_events():
            self._events.append(ev)
            if (ev.kind == GuidanceEventKind.PHASE_CHANGED and ev.detail == RtlPhase.LAND.value
                    and self._final_alt_m > 0.0):
                h = self._home
                self._final = Hold((h[0], h[1], h[2] + self._final_alt_m), target.heading_rad)
        if target.heading_rad is None and self._heading is not None:
            target = dataclasses.replace(target, heading_rad=self._heading)
        return target


class Land(Lander):
    kind = LawKind.LAND
