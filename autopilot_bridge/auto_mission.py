"""AUTO missions (part of ``FlightCore``): the mission's upload, start and current item (the MAVLink
side), and its execution the way ArduPilot's ``AP_Mission`` sequences it and ArduCopter's
``mode_auto.cpp`` flies it.

Sequencing (AP_Mission): navigation commands (ids up to 95, and NAV_SET_YAW_SPEED, NAV_SCRIPT_TIME,
NAV_ATTITUDE_TIME) run one at a time; DO_JUMP is followed while the next command is searched for
(repeat count param2, -1 for ever; a target outside the mission ends it; each jump taken is
announced "Mission: N Jump k/n"); when a navigation command starts, the "do" and "condition"
commands after it run one after the other until the next navigation command: a condition
(CONDITION_DELAY seconds, CONDITION_DISTANCE metres from the destination, CONDITION_YAW the
heading reached) holds back the commands after it, not the vehicle; those not run when the
navigation command completes are dropped. As in AP_Mission, of the do commands before the first
navigation command the first starts with it and the rest follow it (a quirk kept: the do commands
after that navigation command are then not run).

Flown (ArduCopter): NAV_TAKEOFF; runs of NAV_WAYPOINT / NAV_SPLINE_WAYPOINT with one tracker
(corners without stopping; hold time param1 ends a run; the leg into a spline waypoint is a
smooth curve: ``spline_samples``); NAV_LOITER_UNLIM (fly there, hold for ever); NAV_LOITER_TIME (fly there,
hold param1 s); NAV_LOITER_TURNS (circle param1 turns of radius |param3| m, CIRCLE_RADIUS when 0,
counter-clockwise when param3 < 0; ``circle``); NAV_DELAY (hold param1 s; differs: param1 < 0,
a time of day, is not implemented: no delay); NAV_LAND; NAV_RETURN_TO_LAUNCH. Executed do
commands: DO_CHANGE_SPEED, DO_SET_HOME (param1 1 or no location: here), DO_SET_ROI /
DO_SET_ROI_LOCATION (face the location; a zero location or DO_SET_ROI_NONE ends it),
DO_LAND_START (a marker), DO_FENCE_ENABLE (``core_geofence.fence_enable``), CONDITION_*. Every other stored command is skipped, as ArduCopter does
for commands the frame cannot run (camera, gimbal, servo, relay, gripper, ...).

Terrain frames (GLOBAL_TERRAIN_ALT): stored; flown as ArduCopter without terrain data flies them:
a waypoint / loiter destination cannot be set, so "Failsafe: Terrain data missing" and RTL (LAND
without a position; disarm on the ground); a takeoff climbs its altitude above where it is.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from autopilot_bridge.circle import Circle, CircleSettings
from autopilot_bridge.control import stopping_point
from autopilot_bridge.ekf import NavState
from autopilot_bridge.flight_laws import Hold, Land, LawKind, Tracker
from autopilot_bridge.guidance_law import GuidanceEventKind, Waypoint, make_takeoff
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    HomeChangedEvent,
    MavSeverity,
    MissionCommand,
    MissionItem,
    MissionItemReachedEvent,
    MissionState,
    ModeChangedEvent,
    Outcome,
    SpeedType,
)

MC = MissionCommand

class AutoStage(Enum):
    """Where AUTO is in the current mission item."""

    IDLE = "idle"
    TAKEOFF = "takeoff"
    WAYPOINTS = "waypoints"
    WP_DELAY = "wp_delay"
    LOITER_UNLIM = "loiter_unlim"
    CIRCLE = "circle"
    LAND_APPROACH = "land_approach"
    LAND = "land"
    RTL = "rtl"
    COMPLETE = "complete"


# AP_Mission: ids up to MAV_CMD_NAV_LAST are navigation commands, and these three.
NAV_LAST = 95
EXTRA_NAV_COMMANDS = frozenset({MC.NAV_SET_YAW_SPEED, MC.NAV_SCRIPT_TIME, MC.NAV_ATTITUDE_TIME})
# Navigation commands flown (the rest are skipped) and those flown as waypoints.
FLOWN_NAV_COMMANDS = frozenset({MC.NAV_WAYPOINT, MC.NAV_SPLINE_WAYPOINT, MC.NAV_TAKEOFF, MC.NAV_LAND,
                                MC.NAV_RETURN_TO_LAUNCH, MC.NAV_LOITER_UNLIM, MC.NAV_LOITER_TIME,
                                MC.NAV_LOITER_TURNS, MC.NAV_DELAY})
WAYPOINT_COMMANDS = frozenset({MC.NAV_WAYPOINT, MC.NAV_SPLINE_WAYPOINT})
# Navigation commands with a destination (terrain frames matter for them).
DESTINATION_COMMANDS = frozenset({MC.NAV_WAYPOINT, MC.NAV_SPLINE_WAYPOINT, MC.NAV_LOITER_UNLIM,
                                  MC.NAV_LOITER_TIME, MC.NAV_LOITER_TURNS})
CONDITION_COMMANDS = frozenset({MC.CONDITION_DELAY, MC.CONDITION_DISTANCE, MC.CONDITION_YAW})
# AP_Mission: AP_MISSION_JUMP_REPEAT_FOREVER, and the most jumps one search may follow.
JUMP_REPEAT_FOREVER = -1
MAX_JUMPS_PER_SEARCH = 64
# ArduCopter ModeAuto::verify_yaw: the heading is reached within 2 degrees.
YAW_REACHED_RAD = math.radians(2.0)
# The heading towards a region of interest is held once the vehicle is this close to it.
ROI_MIN_DISTANCE_M = 1.0

TAKEOFF_DONE_TOLERANCE_M = 0.5


# A spline leg is flown through samples this far apart along its chord (at least two per leg).
SPLINE_SAMPLE_M = 2.0


def spline_samples(points: list[np.ndarray], k: int) -> list[tuple[float, float, float]]:
    """The curve from ``points[k - 1]`` into ``points[k]`` (without its ends): a cubic Hermite
    segment whose tangents are those of a Catmull-Rom spline through the neighbours (the chord at
    the ends of the run), so consecutive spline legs join without a corner, as ArduCopter's
    spline waypoints do (``SplineCurve``; its tangents and speed profile differ in detail)."""
    p0, p1 = points[k - 1], points[k]
    chord = p1 - p0
    length = float(np.linalg.norm(chord))
    if length < SPLINE_SAMPLE_M:
        return []
    m0 = (p1 - points[k - 2]) * 0.5 if k >= 2 else chord
    m1 = (points[k + 1] - p0) * 0.5 if k + 1 < len(points) else chord
    n = max(2, int(math.ceil(length / SPLINE_SAMPLE_M)))
    out = []
    for j in range(1, n):
        t = j / n
        h00, h10 = 2 * t ** 3 - 3 * t ** 2 + 1, t ** 3 - 2 * t ** 2 + t
        h01, h11 = -2 * t ** 3 + 3 * t ** 2, t ** 3 - t ** 2
        q = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
        out.append((float(q[0]), float(q[1]), float(q[2])))
    return out


def is_nav_command(command: int) -> bool:
    """AP_Mission::is_nav_cmd."""
    return int(command) <= NAV_LAST or int(command) in EXTRA_NAV_COMMANDS


def heading_error_rad(target: float, heading: float) -> float:
    return abs((target - heading + math.pi) % (2.0 * math.pi) - math.pi)


@dataclass
class DoCommandState:
    """The do/condition command being run after the current navigation command (AP_Mission's
    ``_do_cmd`` and its flags)."""

    index: int | None = None      # the last do command started (None: none yet)
    loaded: bool = False          # it has not verified yet
    all_done: bool = False        # the next command is a navigation command
    until_s: float = 0.0          # CONDITION_DELAY
    distance_m: float = 0.0       # CONDITION_DISTANCE


class AutoMissionMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_auto(self) -> None:
        """The stored mission and where AUTO is in it."""
        self._mission: tuple[MissionItem, ...] = ()
        self._mission_index = 0
        self._mission_state = MissionState.NO_MISSION
        self._auto_stage = AutoStage.IDLE
        # the tracker's waypoints: mission index (-1 for a spline sample), speed, destination
        self._auto_group: list[int] = []
        self._auto_group_speeds: list[float | None] = []
        self._auto_group_positions: list[tuple[float, float, float]] = []
        self._auto_delay_until_s = 0.0
        self._auto_land_xy: tuple[float, float] | None = None
        self._jump_runs: dict[int, int] = {}
        self._do = DoCommandState()
        self._nav_dest: np.ndarray | None = None
        self._loiter_hold_s = 0.0
        # heading targets of CONDITION_YAW and DO_SET_ROI (AUTO and GUIDED; ArduCopter's auto_yaw)
        self._auto_heading: float | None = None
        self._roi_enu: np.ndarray | None = None
        # AUTO jumped to a landing sequence (DO_LAND_START command or a failsafe): reported as
        # mode AUTO_RTL until the mode changes or the mission is restarted, moved or replaced
        self._auto_rtl = False

    def mission_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        self._mission = tuple(items)
        self._auto_rtl = False
        self._tel = None
        self._jump_runs = {}
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
        self._auto_rtl = False
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
        self._auto_rtl = False
        if self._mode == CopterMode.AUTO and self._armed and self.nav.aligned \
                and self._mission_state == MissionState.ACTIVE:
            self._auto_start(index, self.nav.state())
        elif self._mission_state == MissionState.COMPLETE:
            self._mission_state = MissionState.PAUSED
        return Outcome(True)

    # ------------------------------------------------------------ landing sequence (AUTO_RTL)
    def _landing_sequence_start(self, est: NavState) -> int | None:
        """AP_Mission ``get_landing_sequence_start``: the DO_LAND_START item nearest to the stopping
        point by its location (one without a location counts as far away; the first wins a tie)."""
        stop = stopping_point(est.position_enu_m, est.velocity_enu_m_s, self._gcfg.wp_accel_m_s2)
        best, best_d = None, math.inf
        for i, item in enumerate(self._mission):
            if item.command != MC.DO_LAND_START:
                continue
            d = math.inf
            if item.lat_e7 != 0 or item.lon_e7 != 0:
                x, y = self.geo.to_enu(item.lat_deg, item.lon_deg)
                d = math.hypot(x - float(stop[0]), y - float(stop[1]))
            if best is None or d < best_d:
                best, best_d = i, d
        return best

    def jump_to_landing_sequence(self) -> Outcome:
        return self._jump_to_landing_sequence(from_gcs=True)

    def _jump_to_landing_sequence(self, from_gcs: bool) -> Outcome:
        """ArduCopter ``ModeAuto::jump_to_landing_sequence_auto_RTL``: continue the mission in AUTO
        at the nearest DO_LAND_START (resumed there whatever MIS_RESTART says), reported as
        AUTO_RTL; refused without one or when AUTO cannot be entered."""
        if not self._position_ok():
            return self._refuse("Mode change to AUTO RTL failed: requires position")
        est = self.nav.state()
        index = self._landing_sequence_start(est)
        if index is None:
            self._announce(MavSeverity.WARNING, "Unable to start landing sequence")
            return self._refuse("Mode change to AUTO RTL failed: No landing sequence found")
        self._announce(MavSeverity.INFO, "Landing sequence start")
        self._mission_index = index
        self._tel = None
        if self._mode == CopterMode.AUTO:
            self._mission_state = MissionState.ACTIVE
            if self._armed:
                self._auto_start(index, est)
        else:
            self._mission_state = MissionState.PAUSED      # AP_Mission's force resume
            outcome = self._enter_mode(CopterMode.AUTO, from_gcs=from_gcs)
            if not outcome.ok:
                return outcome
        self._auto_rtl = True
        self._events.append(ModeChangedEvent(CopterMode.AUTO_RTL))
        return Outcome(True)

    def _reported_mode(self) -> CopterMode:
        """The mode the ground stations see: AUTO on a landing sequence is AUTO_RTL."""
        return CopterMode.AUTO_RTL if self._auto_rtl and self._mode == CopterMode.AUTO else self._mode

    def _mission_starts_with_takeoff(self) -> bool:
        index = self._next_command(0, increment_jumps=False)
        while index is not None and not is_nav_command(self._mission[index].command):
            index = self._next_command(index + 1, increment_jumps=False)
        return index is not None and self._mission[index].command == MC.NAV_TAKEOFF

    def _auto_enter(self, est: NavState) -> None:
        if self._mission_state in (MissionState.PAUSED, MissionState.ACTIVE):
            index = self._mission_index
        else:
            index = 0
            self._jump_runs = {}
        self._mission_state = MissionState.ACTIVE
        self._speed_xy = None
        self._auto_start(index, est)

    # ------------------------------------------------------------------ sequencing (AP_Mission)
    def _next_command(self, start: int, increment_jumps: bool) -> int | None:
        """AP_Mission::get_next_cmd: the index of the first command at or after ``start`` that is
        not a DO_JUMP, following the jumps that still have repeats (counted when
        ``increment_jumps``); None at the end or for a jump outside the mission."""
        items = self._mission
        i = start
        first_jump: int | None = None
        jumps = MAX_JUMPS_PER_SEARCH
        while 0 <= i < len(items):
            item = items[i]
            if item.command != MC.DO_JUMP:
                return i
            jumps -= 1
            if jumps < 0:
                return None
            target = int(item.param1)
            if not 1 <= target <= len(items):
                return None
            if not increment_jumps and first_jump == i:
                return None            # a loop of jumps that can never end
            if first_jump is None:
                first_jump = i
            repeat = int(item.param2)
            runs = self._jump_runs.get(i, 0)
            if repeat == JUMP_REPEAT_FOREVER:
                i = target - 1
            elif runs < repeat:
                if increment_jumps:
                    self._jump_runs[i] = runs + 1
                    self._announce(MavSeverity.INFO, f"Mission: {i + 1} Jump {runs + 1}/{repeat}")
                i = target - 1
            else:
                i += 1
        return None

    def _auto_start(self, index: int, est: NavState) -> None:
        """Start the first flown navigation command at or after ``index`` (AP_Mission's
        advance_current_nav_cmd): the first do command met on the way starts with it."""
        items = self._mission
        self._do = DoCommandState()
        i: int | None = index
        guard = len(items) + MAX_JUMPS_PER_SEARCH
        while True:
            i = self._next_command(i, increment_jumps=True) if i is not None else None
            guard -= 1
            if i is None or guard < 0:
                self._mission_complete(est)
                return
            item = items[i]
            if not is_nav_command(item.command):
                if not self._do.loaded:
                    self._do.index, self._do.loaded = i, True
                    self._start_do(item, est)
                i += 1
                continue
            if item.command not in FLOWN_NAV_COMMANDS:
                self._bus_text(MavSeverity.INFO, f"mission: item {i + 1} skipped "
                                                 f"({self._command_name(item.command)})")
                i += 1
                continue
            break
        self._begin_nav(i)
        self._start_nav(i, item, est)
        if self._mode == CopterMode.AUTO and self._mission_state == MissionState.ACTIVE:
            self._service_do_commands(est)

    def _begin_nav(self, index: int) -> None:
        """``index`` is now the navigation command: the do commands after it come next."""
        self._mission_index = index
        self._mission_state = MissionState.ACTIVE
        self._tel = None
        self._nav_dest = None
        # ArduCopter wp_start: the heading goes back to WP_YAW_BEHAVIOR unless an ROI is set
        # (or a fixed heading with WP_YAW_BEHAVIOR 0)
        if self.params.get_int("WP_YAW_BEHAVIOR") != 0:
            self._auto_heading = None

    def _start_nav(self, nav_index: int, item: MissionItem, est: NavState) -> None:
        prev = self._last_target_position(est)
        heading = float(est.heading_rad)
        self._bus_text(MavSeverity.INFO, f"mission: item {nav_index + 1} "
                                         f"{self._command_name(item.command)}")
        if item.command in DESTINATION_COMMANDS and item.terrain_frame:
            self._terrain_failsafe()
            return
        if item.command == MC.NAV_TAKEOFF:
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
        elif item.command in WAYPOINT_COMMANDS:
            self._auto_waypoints(nav_index, est, prev)
        elif item.command == MC.NAV_LAND:
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
        elif item.command == MC.NAV_RETURN_TO_LAUNCH:
            self._law = self._make_rtl(est)
            self._auto_stage = AutoStage.RTL
        elif item.command in (MC.NAV_LOITER_UNLIM, MC.NAV_LOITER_TIME):
            dest = self._item_position(item, prev)
            self._nav_dest = np.array(dest)
            start = self._last_target_position(est) if not self.fc.landed else est.position_enu_m
            self._law = Tracker(self._gcfg, [Waypoint(dest, speed_m_s=self._speed_xy)], start)
            self._auto_group, self._auto_group_speeds = [nav_index], [self._speed_xy]
            self._auto_group_positions = [dest]
            self._loiter_hold_s = max(0.0, float(item.param1)) \
                if item.command == MC.NAV_LOITER_TIME else math.inf
            self._auto_stage = AutoStage.WAYPOINTS
        elif item.command == MC.NAV_LOITER_TURNS:
            centre = self._item_position(item, prev)
            self._nav_dest = np.array(centre)
            p = self.params
            radius = abs(float(item.param3)) or p.get("CIRCLE_RADIUS") / 100.0
            rate = abs(p.get("CIRCLE_RATE")) * (-1.0 if item.param3 < 0 else 1.0)
            start = self._last_target_position(est) if not self.fc.landed else est.position_enu_m
            self._law = Circle(self._gcfg, centre[:2], centre[2], CircleSettings(radius, rate), start,
                               turns=max(0.0, float(item.param1)), heading_rad=heading)
            self._auto_stage = AutoStage.CIRCLE
        elif item.command == MC.NAV_DELAY:
            self._law = Hold(self._last_target_position(est), None)
            self._auto_delay_until_s = self._now_s + max(0.0, float(item.param1))
            self._auto_stage = AutoStage.WP_DELAY

    def _auto_waypoints(self, first: int, est: NavState, prev: np.ndarray) -> None:
        """Fly a run of consecutive waypoints with one tracker (corners without stopping); a run
        ends at a hold time, at any other navigation command and at a DO_JUMP."""
        items = self._mission
        group: list[int] = []
        speeds: list[float | None] = []
        positions: list[tuple[float, float, float]] = []
        speed = self._speed_xy
        i = first
        last_pos = prev
        while i < len(items):
            item = items[i]
            if item.command not in WAYPOINT_COMMANDS:
                if is_nav_command(item.command) or item.command == MC.DO_JUMP:
                    break
                i += 1
                continue
            if group and item.terrain_frame:
                break                  # flown (and refused) when it becomes the current item
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
        splines = [items[k].command == MC.NAV_SPLINE_WAYPOINT for k in group]
        points = [np.asarray(start, dtype=float)[:3]] + [np.array(p) for p in positions]
        wps: list[Waypoint] = []
        self._auto_group, self._auto_group_speeds, self._auto_group_positions = [], [], []
        for k, (pos, s) in enumerate(zip(positions, speeds, strict=True)):
            if splines[k]:
                for q in spline_samples(points, k + 1):        # the curve into waypoint k
                    wps.append(Waypoint(q, speed_m_s=s))
                    self._auto_group.append(-1)
                    self._auto_group_speeds.append(s)
                    self._auto_group_positions.append(pos)
            wps.append(Waypoint(pos, speed_m_s=s))
            self._auto_group.append(group[k])
            self._auto_group_speeds.append(s)
            self._auto_group_positions.append(pos)
        self._law = Tracker(self._gcfg, wps, start)
        self._nav_dest = np.array(positions[0])
        self._loiter_hold_s = 0.0
        self._auto_stage = AutoStage.WAYPOINTS

    def _speed_after(self, index: int, speed: float | None) -> float | None:
        """The horizontal speed after the DO_CHANGE_SPEED commands that follow nav item ``index``."""
        for item in self._mission[index + 1:]:
            if is_nav_command(item.command) or item.command == MC.DO_JUMP:
                break
            if item.command == MC.DO_CHANGE_SPEED and item.param1 in (
                    SpeedType.AIRSPEED, SpeedType.GROUNDSPEED) and item.param2 > 0:
                speed = self._speed_limit(SpeedType.GROUNDSPEED, float(item.param2))
        return speed

    # ------------------------------------------------------------------ do / condition commands
    def _service_do_commands(self, est: NavState) -> None:
        """AP_Mission's do-command loop: verify the running one, start the next (several per
        tick when they complete at once)."""
        d = self._do
        for _ in range(len(self._mission) + 1):
            if d.loaded:
                if not self._verify_do(est):
                    return
                d.loaded = False
            if d.all_done:
                return
            start = self._mission_index + 1 if d.index is None else d.index + 1
            i = self._next_command(start, increment_jumps=False)
            if i is None or is_nav_command(self._mission[i].command):
                d.all_done = True
                return
            d.index, d.loaded = i, True
            self._start_do(self._mission[i], est)

    def _start_do(self, item: MissionItem, est: NavState) -> None:
        d = self._do
        cmd = item.command
        if cmd == MC.DO_CHANGE_SPEED and item.param2 > 0:
            try:
                kind = SpeedType(int(item.param1))
            except ValueError:
                kind = SpeedType.GROUNDSPEED
            self._apply_speed(kind, self._speed_limit(kind, float(item.param2)))
        elif cmd == MC.CONDITION_DELAY:
            d.until_s = self._now_s + max(0.0, float(item.param1))
        elif cmd == MC.CONDITION_DISTANCE:
            d.distance_m = max(0.0, float(item.param1))
        elif cmd == MC.CONDITION_YAW:
            self._set_fixed_heading(float(item.param1), float(item.param3), float(item.param4) > 0, est)
        elif cmd in (MC.DO_SET_ROI, MC.DO_SET_ROI_LOCATION):
            if item.lat_e7 == 0 and item.lon_e7 == 0:
                self._roi_enu = None
            else:
                self._roi_enu = np.array(self._item_position(item, est.position_enu_m))
        elif cmd == MC.DO_SET_ROI_NONE:
            self._roi_enu = None
        elif cmd == MC.DO_SET_HOME:
            if item.param1 == 1.0 or (item.lat_e7 == 0 and item.lon_e7 == 0 and item.alt_m == 0.0):
                home = np.array(est.position_enu_m, dtype=float)
            else:
                # the altitude as given (relative 0 = the old home's height), not "unchanged"
                x, y = self.geo.to_enu(item.lat_deg, item.lon_deg)
                frame = item.alt_frame if item.alt_frame is not None else AltFrame.RELATIVE_HOME
                home = np.array([x, y, self._alt_to_z(item.alt_m, frame)])
            self._set_home_enu(home)
        elif cmd == MC.DO_FENCE_ENABLE:
            # AP_Mission ``start_command_fence``: an unknown action fails the item, which is moved past
            self.fence_enable(int(item.param1), int(item.param2))

    def _verify_do(self, est: NavState) -> bool:
        """Whether the running do command is done (ArduCopter's verify_command)."""
        d = self._do
        if d.index is None:
            return True
        cmd = self._mission[d.index].command
        if cmd == MC.CONDITION_DELAY:
            return self._now_s >= d.until_s
        if cmd == MC.CONDITION_DISTANCE:
            if self._nav_dest is None:
                return True
            return float(np.linalg.norm(self._nav_dest - np.asarray(est.position_enu_m))) < d.distance_m
        if cmd == MC.CONDITION_YAW and self._auto_heading is not None:
            return heading_error_rad(self._auto_heading, float(est.heading_rad)) <= YAW_REACHED_RAD
        return True

    def _set_fixed_heading(self, angle_deg: float, direction: float, relative: bool,
                           est: NavState) -> None:
        """CONDITION_YAW (ArduCopter auto_yaw.set_fixed_yaw): an absolute heading, or an offset from
        the current heading target (negative ``direction``: counter-clockwise); ends an ROI."""
        if relative:
            base = self._auto_heading if self._auto_heading is not None else float(est.heading_rad)
            offset = math.radians(angle_deg) * (-1.0 if direction < 0 else 1.0)
            self._auto_heading = (base + offset) % (2.0 * math.pi)
        else:
            self._auto_heading = math.radians(angle_deg) % (2.0 * math.pi)
        self._roi_enu = None

    def _commanded_heading(self, est: NavState) -> float | None:
        """The heading an ROI or CONDITION_YAW asks for (None: the mode's own)."""
        if self._roi_enu is not None:
            d = self._roi_enu[:2] - np.asarray(est.position_enu_m, dtype=float)[:2]
            if float(np.hypot(d[0], d[1])) < ROI_MIN_DISTANCE_M:
                return None
            return math.atan2(float(d[0]), float(d[1])) % (2.0 * math.pi)
        return self._auto_heading

    def _set_home_enu(self, home: np.ndarray) -> None:
        self._home = np.array(home, dtype=float)
        self._events.append(HomeChangedEvent())
        self._tel = None
        self._bus_text(MavSeverity.INFO, f"home set to ({home[0]:.1f}, {home[1]:.1f}, {home[2]:.1f}) m")

    def _terrain_failsafe(self) -> None:
        """ArduCopter's failsafe_terrain_on_event without terrain data: RTL (LAND), disarm landed."""
        self._announce(MavSeverity.CRITICAL, "Failsafe: Terrain data missing")
        self.stats["failsafe_terrain"] += 1
        if self.fc.landed:
            self._mission_complete(self.nav.state())
            self._disarm("terrain failsafe")
        elif not self._enter_mode(CopterMode.RTL, from_gcs=False).ok:
            self._enter_mode(CopterMode.LAND, from_gcs=False)

    @staticmethod
    def _command_name(command: int) -> str:
        try:
            return MissionCommand(command).name
        except ValueError:
            return str(command)

    def _auto_events(self, events: list, est: NavState) -> None:
        stage = self._auto_stage
        for ev in events:
            if stage == AutoStage.WAYPOINTS and ev.kind == GuidanceEventKind.WAYPOINT_REACHED:
                group = self._auto_group
                if 0 <= ev.index < len(group) and group[ev.index] >= 0:   # not a spline sample
                    self._item_reached(group[ev.index])
                    nxt = next((j for j in range(ev.index + 1, len(group)) if group[j] >= 0), None)
                    if nxt is not None:
                        # the next waypoint of the run is now the navigation command
                        self._do = DoCommandState()
                        self._begin_nav(group[nxt])
                        self._speed_xy = self._auto_group_speeds[nxt]
                        self._nav_dest = np.array(self._auto_group_positions[nxt])
            elif ev.kind == GuidanceEventKind.MISSION_COMPLETE:
                if stage == AutoStage.TAKEOFF:
                    self._item_reached(self._mission_index)
                    self._auto_advance(self._mission_index)
                elif stage == AutoStage.WAYPOINTS:
                    last = self._auto_group[-1] if self._auto_group else self._mission_index
                    self._mission_index = last
                    hold_s = self._loiter_hold_s
                    if self._mission[last].command in WAYPOINT_COMMANDS:
                        hold_s = self._mission[last].param1
                    if math.isinf(hold_s):
                        self._auto_stage = AutoStage.LOITER_UNLIM      # NAV_LOITER_UNLIM: for ever
                        self._law = Hold(self._law.destination, None)
                    elif hold_s > 0.0:
                        self._auto_stage = AutoStage.WP_DELAY
                        self._auto_delay_until_s = self._now_s + hold_s
                        self._law = Hold(self._law.destination, None)
                    else:
                        self._auto_advance(last)
                elif stage == AutoStage.CIRCLE:
                    self._item_reached(self._mission_index)
                    self._auto_advance(self._mission_index)
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
        if self._mode == CopterMode.AUTO and self._mission_state == MissionState.ACTIVE:
            self._service_do_commands(est)

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
