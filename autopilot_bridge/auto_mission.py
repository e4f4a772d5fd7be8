"""AUTO missions (part of ``FlightCore``): NAV_TAKEOFF, runs of NAV_WAYPOINT flown with one tracker
(hold time in param1), NAV_LAND (here or at a position), NAV_RETURN_TO_LAUNCH, DO_CHANGE_SPEED; other
stored commands are skipped. Also the mission's upload, start and current item (the MAVLink side).

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from autopilot_bridge.control import stopping_point
from autopilot_bridge.ekf import NavState
from autopilot_bridge.flight_laws import Hold, Land, LawKind, Tracker
from autopilot_bridge.guidance_law import GuidanceEventKind, Waypoint, make_takeoff
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    MavSeverity,
    MissionCommand,
    MissionItem,
    MissionItemReachedEvent,
    MissionState,
    Outcome,
    SpeedType,
)


class AutoStage(Enum):
    """Where AUTO is in the current mission item."""

    IDLE = "idle"
    TAKEOFF = "takeoff"
    WAYPOINTS = "waypoints"
    WP_DELAY = "wp_delay"
    LAND_APPROACH = "land_approach"
    LAND = "land"
    RTL = "rtl"
    COMPLETE = "complete"


NAV_COMMANDS = frozenset({MissionCommand.NAV_WAYPOINT, MissionCommand.NAV_TAKEOFF,
                          MissionCommand.NAV_LAND, MissionCommand.NAV_RETURN_TO_LAUNCH})


TAKEOFF_DONE_TOLERANCE_M = 0.5


class AutoMissionMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_auto(self) -> None:
        """The stored mission and where AUTO is in it."""
        self._mission: tuple[MissionItem, ...] = ()
        self._mission_index = 0
        self._mission_state = MissionState.NO_MISSION
        self._auto_stage = AutoStage.IDLE
        self._auto_group: list[int] = []
        self._auto_group_speeds: list[float | None] = []
        self._auto_delay_until_s = 0.0
        self._auto_land_xy: tuple[float, float] | None = None

    def mission_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        self._mission = tuple(items)
        self._tel = None
        running = self._mode == CopterMode.AUTO and self._mission_state == MissionState.ACTIVE
        if not items:
            self._mission_index = 0
            self._mission_state = MissionState.NO_MISSION
            if running and self.nav.aligned:
                self._mission_complete(self.nav.state())
                self._mission_state = MissionState.NO_MISSION
            return Outcome(True)
        self._mission_index = min(self._mission_index, len(items) - 1)
        if running and self.nav.aligned and self._armed:
            self._announce(MavSeverity.CRITICAL, "Auto mission changed, restarted command")
            self._auto_start(self._mission_index, self.nav.state())
        else:
            self._mission_index = 0
            self._mission_state = MissionState.NOT_STARTED
            self._auto_stage = AutoStage.IDLE
        return Outcome(True)

    def start_mission(self, first_seq: int, last_seq: int) -> Outcome:
        if not self._mission:
            return self._refuse("Mission start failed: no mission")
        if self._mission_state == MissionState.COMPLETE:
            self._mission_state = MissionState.NOT_STARTED
        if self._mode == CopterMode.AUTO:
            if self.nav.aligned and self._mission_state != MissionState.ACTIVE:
                self._auto_enter(self.nav.state())
            return Outcome(True)
        return self._enter_mode(CopterMode.AUTO, from_gcs=True)

    def set_current_mission_item(self, seq: int) -> Outcome:
        index = int(seq) - 1
        if not 0 <= index < len(self._mission):
            return self._refuse(f"Mission: no item {seq}")
        self._mission_index = index
        self._tel = None
        if self._mode == CopterMode.AUTO and self._armed and self.nav.aligned \
                and self._mission_state == MissionState.ACTIVE:
            self._auto_start(index, self.nav.state())
        elif self._mission_state == MissionState.COMPLETE:
            self._mission_state = MissionState.PAUSED
        return Outcome(True)

    def _mission_starts_with_takeoff(self) -> bool:
        for item in self._mission:
            if item.command in NAV_COMMANDS:
                return item.command == MissionCommand.NAV_TAKEOFF
        return False

    def _auto_enter(self, est: NavState) -> None:
        if self._mission_state in (MissionState.PAUSED, MissionState.ACTIVE):
            index = self._mission_index
        else:
            index = 0
        self._mission_state = MissionState.ACTIVE
        self._speed_xy = None
        self._auto_start(index, est)

    def _auto_start(self, index: int, est: NavState) -> None:
        """Start the first NAV command at or after ``index`` (running the DO commands that follow it)."""
        items = self._mission
        nav_index = index
        while nav_index < len(items) and items[nav_index].command not in NAV_COMMANDS:
            self._run_do_command(items[nav_index])
            nav_index += 1
        if nav_index >= len(items):
            self._mission_complete(est)
            return
        self._mission_index = nav_index
        self._mission_state = MissionState.ACTIVE
        self._tel = None
        item = items[nav_index]
        self._run_do_commands_after(nav_index)
        prev = self._last_target_position(est)
        heading = float(est.heading_rad)
        self._bus_text(MavSeverity.INFO, f"mission: item {nav_index + 1} "
                                         f"{MissionCommand(item.command).name}")
        if item.command == MissionCommand.NAV_TAKEOFF:
            goal_z = self._item_z(item, prev)
            here = np.array(est.position_enu_m, dtype=float)
            if not self.fc.landed and here[2] >= goal_z - TAKEOFF_DONE_TOLERANCE_M:
                self._auto_stage = AutoStage.TAKEOFF
                self._law = Hold(here, heading)
                self._item_reached(nav_index)
                self._auto_advance(nav_index)
                return
            start = here if self.fc.landed else np.array(self._last_target_position(est))
            climb = max(goal_z - float(start[2]), 1.0)
            self._law = make_takeoff(self._gcfg, start, climb)
            self._law.kind = LawKind.TAKEOFF
            self._auto_stage = AutoStage.TAKEOFF
        elif item.command == MissionCommand.NAV_WAYPOINT:
            self._auto_waypoints(nav_index, est, prev)
        elif item.command == MissionCommand.NAV_LAND:
            if item.lat_e7 == 0 and item.lon_e7 == 0:
                self._auto_land_xy = None
                stop = stopping_point(est.position_enu_m, est.velocity_enu_m_s,
                                      self._gcfg.wp_accel_m_s2)
                self._law = Land(self._gcfg, stop, self._home_z(), heading_rad=heading)
                self._auto_stage = AutoStage.LAND
            else:
                x, y = self.geo.to_enu(item.lat_deg, item.lon_deg)
                self._auto_land_xy = (x, y)
                z = float(self._last_target_position(est)[2])
                self._law = self._new_tracker([Waypoint((x, y, z))], est,
                                              start=self._last_target_position(est))
                self._auto_stage = AutoStage.LAND_APPROACH
        elif item.command == MissionCommand.NAV_RETURN_TO_LAUNCH:
            self._law = self._make_rtl(est)
            self._auto_stage = AutoStage.RTL

    def _auto_waypoints(self, first: int, est: NavState, prev: np.ndarray) -> None:
        """Fly a run of consecutive NAV_WAYPOINTs with one tracker (corners without stopping)."""
        items = self._mission
        group: list[int] = []
        speeds: list[float | None] = []
        positions: list[tuple[float, float, float]] = []
        speed = self._speed_xy
        i = first
        last_pos = prev
        while i < len(items):
            item = items[i]
            if item.command != MissionCommand.NAV_WAYPOINT:
                if item.command in NAV_COMMANDS:
                    break
                i += 1
                continue
            if group:
                speed = self._speed_after(i, speed)
            else:
                speed = self._speed_xy
            pos = self._item_position(item, last_pos)
            group.append(i)
            speeds.append(speed)
            positions.append(pos)
            last_pos = np.array(pos)
            if item.param1 > 0.0:
                break
            i += 1
        start = self._last_target_position(est) if not self.fc.landed else est.position_enu_m
        wps = [Waypoint(p, speed_m_s=s) for p, s in zip(positions, speeds, strict=False)]
        self._law = Tracker(self._gcfg, wps, start)
        self._auto_group = group
        self._auto_group_speeds = speeds
        self._auto_stage = AutoStage.WAYPOINTS

    def _speed_after(self, index: int, speed: float | None) -> float | None:
        """The horizontal speed after the DO_CHANGE_SPEED commands that follow nav item ``index``."""
        for item in self._mission[index + 1:]:
            if item.command in NAV_COMMANDS:
                break
            if item.command == MissionCommand.DO_CHANGE_SPEED and item.param1 in (
                    SpeedType.AIRSPEED, SpeedType.GROUNDSPEED) and item.param2 > 0:
                speed = self._speed_limit(SpeedType.GROUNDSPEED, float(item.param2))
        return speed

    def _run_do_commands_after(self, nav_index: int) -> None:
        for item in self._mission[nav_index + 1:]:
            if item.command in NAV_COMMANDS:
                break
            self._run_do_command(item)

    def _run_do_command(self, item: MissionItem) -> None:
        if item.command == MissionCommand.DO_CHANGE_SPEED and item.param2 > 0:
            try:
                kind = SpeedType(int(item.param1))
            except ValueError:
                kind = SpeedType.GROUNDSPEED
            self._apply_speed(kind, self._speed_limit(kind, float(item.param2)))

    def _auto_events(self, events: list, est: NavState) -> None:
        stage = self._auto_stage
        for ev in events:
            if stage == AutoStage.WAYPOINTS and ev.kind == GuidanceEventKind.WAYPOINT_REACHED:
                if 0 <= ev.index < len(self._auto_group):
                    index = self._auto_group[ev.index]
                    self._item_reached(index)
                    if ev.index + 1 < len(self._auto_group):
                        self._mission_index = self._auto_group[ev.index + 1]
                        self._speed_xy = self._auto_group_speeds[ev.index + 1]
                        self._tel = None
            elif ev.kind == GuidanceEventKind.MISSION_COMPLETE:
                if stage == AutoStage.TAKEOFF:
                    self._item_reached(self._mission_index)
                    self._auto_advance(self._mission_index)
                elif stage == AutoStage.WAYPOINTS:
                    last = self._auto_group[-1] if self._auto_group else self._mission_index
                    self._mission_index = last
                    hold_s = self._mission[last].param1 if last < len(self._mission) else 0.0
                    if hold_s > 0.0:
                        self._auto_stage = AutoStage.WP_DELAY
                        self._auto_delay_until_s = self._now_s + hold_s
                        self._law = Hold(self._law.destination, None)
                    else:
                        self._auto_advance(last)
                elif stage == AutoStage.LAND_APPROACH and self._auto_land_xy is not None:
                    x, y = self._auto_land_xy
                    self._law = Land(self._gcfg, (x, y, float(est.position_enu_m[2])),
                                      self._home_z(), heading_rad=None)
                    self._auto_stage = AutoStage.LAND
            elif ev.kind == GuidanceEventKind.PHASE_CHANGED:
                self._bus_text(MavSeverity.INFO, f"AUTO RTL: {ev.detail}")
            stage = self._auto_stage
        if self._auto_stage == AutoStage.WP_DELAY and self._now_s >= self._auto_delay_until_s:
            self._auto_advance(self._mission_index)

    def _auto_advance(self, index: int) -> None:
        est = self.nav.state()
        if index + 1 >= len(self._mission):
            self._mission_complete(est)
            return
        self._auto_start(index + 1, est)

    def _item_reached(self, index: int) -> None:
        seq = index + 1
        self._events.append(MissionItemReachedEvent(seq))
        self._announce(MavSeverity.INFO, f"Reached command #{seq}")

    def _mission_complete(self, est: NavState) -> None:
        if self._mission_state != MissionState.COMPLETE:
            self._announce(MavSeverity.INFO, "Mission complete")
        self._mission_state = MissionState.COMPLETE
        self._auto_stage = AutoStage.COMPLETE
        self._tel = None
        if self.fc.landed or not self._armed:
            self._law = None
        else:
            self._law = Hold(self._last_target_position(est), None)

    def _last_target_position(self, est: NavState) -> np.ndarray:
        if self._last_target is not None and not self.fc.landed:
            return np.array(self._last_target.position_enu_m, dtype=float)
        return np.array(est.position_enu_m, dtype=float)

    def _item_z(self, item: MissionItem, default: np.ndarray) -> float:
        if item.alt_m == 0.0:
            return float(default[2])
        if item.alt_frame == AltFrame.AMSL:
            return float(item.alt_m) - self.geo.origin_alt_amsl_m
        return self._home_z() + float(item.alt_m)

    def _item_position(self, item: MissionItem, default: np.ndarray) -> tuple[float, float, float]:
        if item.lat_e7 == 0 and item.lon_e7 == 0:
            x, y = float(default[0]), float(default[1])
        else:
            x, y = self.geo.to_enu(item.lat_deg, item.lon_deg)
        return (float(x), float(y), self._item_z(item, default))
