"""COMMAND_LONG / COMMAND_INT / SET_MODE dispatch with MAV_RESULT codes, ArduCopter style.

Shell module (uses pymavlink constants only through ``mavlink2``). Both command messages are
normalised into a :class:`CommandRequest`; every handler validates its parameters (NaN,
infinity, ranges) and never raises. Result codes follow ArduPilot
(``GCS_MAVLINK::handle_command_*``, ``GCS_MAVLINK_Copter::handle_command_int_packet``) and the
MAVLink meaning: DENIED = invalid parameters, FAILED = valid but the vehicle refused (its
reason goes out as STATUSTEXT), UNSUPPORTED = unknown command, COMMAND_INT_ONLY = only
meaningful as COMMAND_INT.

Supported: COMPONENT_ARM_DISARM (param2 2989 or 21196 forces arming, 21196 forces disarming),
NAV_TAKEOFF (param7 / z metres above home; COMMAND_INT needs a GLOBAL_RELATIVE_ALT frame),
NAV_LAND, NAV_RETURN_TO_LAUNCH, NAV_LOITER_UNLIM (-> LOITER), DO_SET_MODE (base_mode with
CUSTOM_MODE_ENABLED + custom_mode), MISSION_START (param1 = param2 = 0 only, as ArduCopter),
DO_SET_MISSION_CURRENT, DO_REPOSITION (COMMAND_INT), DO_CHANGE_SPEED, CONDITION_YAW (param1
0..360, param4 0/1, else FAILED), DO_SET_ROI_LOCATION / DO_SET_ROI (location in x/y/z or
param5..7) / DO_SET_ROI_NONE, DO_PAUSE_CONTINUE (param1 0 pause, 1 continue; FAILED with
"Failed to pause/resume"), SET_MESSAGE_INTERVAL, GET_MESSAGE_INTERVAL, REQUEST_MESSAGE,
REQUEST_AUTOPILOT_CAPABILITIES, GET_HOME_POSITION.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Callable, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.modes import SUPPORTED_MODES, CopterMode, mode_from_number
from autopilot_bridge.params import DEFAULT_PARAM_SPECS
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    MavFrame,
    MavSeverity,
    SpeedType,
    Vehicle,
    VehicleTelemetry,
)

logger = logging.getLogger(__name__)

# ArduPilot GCS.h: magic_force_arm_value / magic_force_disarm_value
FORCE_ARM_MAGIC = 2989.0
FORCE_ARM_DISARM_MAGIC = 21196.0
MAX_TAKEOFF_ALT_M = 10_000.0
# DO_CHANGE_SPEED above the range of the parameter it overrides is DENIED (cm/s -> m/s; ArduCopter
# accepts any positive speed): WPNAV_SPEED 20 m/s, WPNAV_SPEED_UP 10 m/s, WPNAV_SPEED_DN 5 m/s.
_SPEED_PARAMS = {0: "WPNAV_SPEED", 1: "WPNAV_SPEED", 2: "WPNAV_SPEED_UP", 3: "WPNAV_SPEED_DN"}
MAX_CHANGE_SPEED_M_S = {kind: next(s.max_value for s in DEFAULT_PARAM_SPECS if s.name == name) / 100.0
                        for kind, name in _SPEED_PARAMS.items()}
MAX_MSG_ID = 2 ** 24 - 1


class MavResult(IntEnum):
    """MAV_RESULT (COMMAND_ACK.result)."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5
    COMMAND_LONG_ONLY = 7
    COMMAND_INT_ONLY = 8


class RepositionFlag(IntEnum):
    """MAV_DO_REPOSITION_FLAGS (DO_REPOSITION param2)."""

    CHANGE_MODE = 1


@dataclass(frozen=True)
class CommandRequest:
    """COMMAND_LONG or COMMAND_INT, normalised. ``params`` are param1..param7 as floats; for
    COMMAND_INT params[4:6] are x, y (degE7 as floats) and params[6] is z."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    is_int: bool
    frame: int = int(MavFrame.GLOBAL)
    x: int = 0
    y: int = 0
    confirmation: int = 0

    @classmethod
    def from_message(cls, msg: mavlink2.MAVLink_message) -> CommandRequest:
        if msg.get_type() == "COMMAND_INT":
            return cls(int(msg.command), (msg.param1, msg.param2, msg.param3, msg.param4,
                                          float(msg.x), float(msg.y), msg.z),
                       True, int(msg.frame), int(msg.x), int(msg.y))
        return cls(int(msg.command), (msg.param1, msg.param2, msg.param3, msg.param4,
                                      msg.param5, msg.param6, msg.param7),
                   False, confirmation=int(msg.confirmation))

    def p(self, i: int) -> float:
        """param ``i`` (1-based)."""
        return float(self.params[i - 1])


@dataclass(frozen=True)
class CommandResult:
    """What to answer: the COMMAND_ACK result, then messages to send to the requester."""

    result: MavResult
    then_send: tuple[int, ...] = ()
    reply: mavlink2.MAVLink_message | None = None


class CommandServices(Protocol):
    """Server facilities the command handlers use."""

    def telemetry(self) -> VehicleTelemetry: ...

    def statustext(self, severity: MavSeverity, text: str) -> None: ...

    def can_send(self, msg_id: int) -> bool: ...

    def ardupilot_has(self, msg_id: int) -> bool: ...

    def set_message_interval(self, link: object, msg_id: int, interval_us: float) -> bool: ...

    def message_interval_us(self, link: object, msg_id: int) -> int: ...

    def mission_item_count(self) -> int: ...

    def set_mission_current(self, seq: int) -> bool: ...


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _as_int(value: float, lo: int, hi: int) -> int | None:
    """An exactly integral finite value within [lo, hi], else None."""
    if not math.isfinite(value) or value != int(value):
        return None
    v = int(value)
    return v if lo <= v <= hi else None


class CommandHandler:
    """Validates commands and forwards them to the vehicle."""

    def __init__(self, vehicle: Vehicle, services: CommandServices) -> None:
        self._vehicle = vehicle
        self._svc = services
        m = mavlink2
        self._handlers: dict[int, Callable[[CommandRequest, object], CommandResult]] = {
            m.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
            m.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            m.MAV_CMD_NAV_LAND: self._land,
            m.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._rtl,
            m.MAV_CMD_NAV_LOITER_UNLIM: self._loiter_unlim,
            m.MAV_CMD_DO_SET_MODE: self._do_set_mode,
            m.MAV_CMD_MISSION_START: self._mission_start,
            m.MAV_CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
            m.MAV_CMD_DO_LAND_START: self._land_start,
            m.MAV_CMD_DO_FENCE_ENABLE: self._fence_enable,
            m.MAV_CMD_DO_REPOSITION: self._reposition,
            m.MAV_CMD_DO_CHANGE_SPEED: self._change_speed,
            m.MAV_CMD_CONDITION_YAW: self._condition_yaw,
            m.MAV_CMD_DO_SET_ROI_LOCATION: self._set_roi,
            m.MAV_CMD_DO_SET_ROI: self._set_roi,
            m.MAV_CMD_DO_SET_ROI_NONE: self._set_roi_none,
            m.MAV_CMD_DO_PAUSE_CONTINUE: self._pause_continue,
            m.MAV_CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
            m.MAV_CMD_GET_MESSAGE_INTERVAL: self._get_message_interval,
            m.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._request_capabilities,
            m.MAV_CMD_GET_HOME_POSITION: self._get_home_position,
        }

    def register(self, handlers: dict[int, Callable[[CommandRequest, object], CommandResult]]) -> None:
        """Add handlers kept in their own modules (``system_commands``)."""
        self._handlers.update(handlers)

    @property
    def supported_commands(self) -> frozenset[int]:
        return frozenset(self._handlers)

    def handle(self, req: CommandRequest, link: object) -> CommandResult:
        handler = self._handlers.get(req.command)
        if handler is None:
            return CommandResult(MavResult.UNSUPPORTED)
        result = handler(req, link)
        logger.info("command %d -> %s", req.command, result.result.name)
        return result

    # ----------------------------------------------------------------- modes
    def set_mode_common(self, base_mode: float, custom_mode: float) -> MavResult:
        """DO_SET_MODE / SET_MODE: only custom modes (ArduPilot ``_set_mode_common``)."""
        base = _as_int(base_mode, 0, 255)
        if base is None or not base & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return MavResult.DENIED
        number = _as_int(custom_mode, 0, 2 ** 32 - 1)
        if number is None:
            return MavResult.DENIED
        mode = mode_from_number(number)
        if mode is None:
            self._svc.statustext(MavSeverity.WARNING, f"No such mode {number}")
            return MavResult.FAILED
        return self.change_mode(mode)

    def change_mode(self, mode: CopterMode) -> MavResult:
        if self._svc.telemetry().mode == mode:
            return MavResult.ACCEPTED
        if mode not in SUPPORTED_MODES:
            self._svc.statustext(MavSeverity.WARNING,
                                 f"Flight mode change failed: {mode.name} not supported")
            return MavResult.FAILED
        outcome = self._vehicle.set_mode(mode)
        if outcome.ok:
            return MavResult.ACCEPTED
        self._svc.statustext(MavSeverity.WARNING,
                             outcome.reason or f"Flight mode change failed: {mode.name}")
        return MavResult.FAILED

    def _do_set_mode(self, req: CommandRequest, link: object) -> CommandResult:
        return CommandResult(self.set_mode_common(req.p(1), req.p(2)))

    def _loiter_unlim(self, req: CommandRequest, link: object) -> CommandResult:
        return CommandResult(self.change_mode(CopterMode.LOITER))

    # ----------------------------------------------------------------- arming & flight
    def _outcome(self, outcome: tuple[bool, str], severity: MavSeverity = MavSeverity.WARNING,
                 default_reason: str = "") -> MavResult:
        ok, reason = outcome
        if ok:
            return MavResult.ACCEPTED
        if reason or default_reason:
            self._svc.statustext(severity, reason or default_reason)
        return MavResult.FAILED

    def _arm_disarm(self, req: CommandRequest, link: object) -> CommandResult:
        action, magic = req.p(1), req.p(2)
        armed = self._svc.telemetry().armed
        if action == 1.0:
            if armed:
                return CommandResult(MavResult.ACCEPTED)
            force = magic in (FORCE_ARM_MAGIC, FORCE_ARM_DISARM_MAGIC)
            return CommandResult(self._outcome(self._vehicle.arm(force), MavSeverity.CRITICAL,
                                               "Arm: refused"))
        if action == 0.0:
            if not armed:
                return CommandResult(MavResult.ACCEPTED)
            force = magic == FORCE_ARM_DISARM_MAGIC
            return CommandResult(self._outcome(self._vehicle.disarm(force), MavSeverity.CRITICAL,
                                               "Disarm: refused"))
        return CommandResult(MavResult.DENIED)

    def _takeoff(self, req: CommandRequest, link: object) -> CommandResult:
        if req.is_int and req.frame not in (MavFrame.GLOBAL_RELATIVE_ALT,
                                            MavFrame.GLOBAL_RELATIVE_ALT_INT):
            return CommandResult(MavResult.DENIED)
        alt = req.p(7)
        if not (math.isfinite(alt) and 0.0 < alt <= MAX_TAKEOFF_ALT_M):
            return CommandResult(MavResult.DENIED)
        # param3 0: the mode must navigate horizontally (ArduCopter do_user_takeoff(alt, is_zero(p3)))
        must_navigate = not (math.isfinite(req.p(3)) and req.p(3) != 0.0)
        return CommandResult(self._outcome(self._vehicle.takeoff(alt, must_navigate)))

    def _land(self, req: CommandRequest, link: object) -> CommandResult:
        return CommandResult(self._outcome(self._vehicle.land()))

    def _rtl(self, req: CommandRequest, link: object) -> CommandResult:
        return CommandResult(self._outcome(self._vehicle.return_to_launch()))

    def _mission_start(self, req: CommandRequest, link: object) -> CommandResult:
        first, last = req.p(1), req.p(2)
        if first != 0.0 or last != 0.0:
            return CommandResult(MavResult.DENIED)  # first/last item not supported (ArduCopter)
        if self._svc.mission_item_count() == 0:
            self._svc.statustext(MavSeverity.WARNING, "Mission start failed: no mission")
            return CommandResult(MavResult.FAILED)
        return CommandResult(self._outcome(self._vehicle.start_mission(0, 0)))

    def _set_mission_current(self, req: CommandRequest, link: object) -> CommandResult:
        seq = _as_int(req.p(1), 1, self._svc.mission_item_count())
        if seq is None:
            return CommandResult(MavResult.DENIED)
        return CommandResult(MavResult.ACCEPTED if self._svc.set_mission_current(seq)
                             else MavResult.FAILED)

    def _land_start(self, req: CommandRequest, link: object) -> CommandResult:
        """DO_LAND_START: the mission's landing sequence in AUTO (reported AUTO_RTL), FAILED without
        one (ArduCopter ``handle_command_long``: ``jump_to_landing_sequence_auto_RTL``)."""
        return CommandResult(self._outcome(self._vehicle.jump_to_landing_sequence()))

    def _fence_enable(self, req: CommandRequest, link: object) -> CommandResult:
        """DO_FENCE_ENABLE: param1 the action (0, 1, 2; else FAILED), param2 the FENCE_TYPE mask
        (0 = all); ENABLE with no such fence present is FAILED (ArduPilot GCS_Fence)."""
        action = _as_int(req.p(1), 0, 255)
        mask = _as_int(req.p(2), 0, 0xFFFF)
        if action is None or mask is None:
            return CommandResult(MavResult.FAILED)
        return CommandResult(self._outcome(self._vehicle.fence_enable(action, mask)))

    def _reposition(self, req: CommandRequest, link: object) -> CommandResult:
        if not req.is_int:
            return CommandResult(MavResult.COMMAND_INT_ONLY)
        if req.frame in (MavFrame.GLOBAL, MavFrame.GLOBAL_INT):
            alt_frame = AltFrame.AMSL
        elif req.frame in (MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_RELATIVE_ALT_INT):
            alt_frame = AltFrame.RELATIVE_HOME
        else:
            return CommandResult(MavResult.DENIED)
        # ArduCopter ignores param1 (speed) and param4 (yaw): handle_command_int_do_reposition
        # calls mode_guided.set_destination(loc, use_yaw=false, 0, use_yaw_rate=false, 0), and
        # clients rely on it (MAVProxy's `guided` sends p4 = 0, MAVSDK's goto_location sends its
        # yaw in degrees, QGC NaN).
        flags, alt = req.p(2), req.p(7)
        if not (abs(req.x) <= 900_000_000 and abs(req.y) <= 1_800_000_000
                and math.isfinite(alt) and abs(alt) < 83_000.0):
            return CommandResult(MavResult.DENIED)
        change_mode = math.isfinite(flags) and int(flags) & RepositionFlag.CHANGE_MODE
        if self._svc.telemetry().mode != CopterMode.GUIDED:
            if not change_mode:
                return CommandResult(MavResult.DENIED)
            if self.change_mode(CopterMode.GUIDED) != MavResult.ACCEPTED:
                return CommandResult(MavResult.FAILED)
        return CommandResult(self._outcome(self._vehicle.reposition(
            req.x * 1e-7, req.y * 1e-7, alt, alt_frame, None, None)))

    def _change_speed(self, req: CommandRequest, link: object) -> CommandResult:
        kind = _as_int(req.p(1), 0, max(SpeedType))
        speed = req.p(2)
        if kind is None or not (math.isfinite(speed) and 0.0 < speed <= MAX_CHANGE_SPEED_M_S[kind]):
            return CommandResult(MavResult.DENIED)
        return CommandResult(self._outcome(self._vehicle.change_speed(SpeedType(kind), speed)))

    # ----------------------------------------------------------------- steering the mode
    def _condition_yaw(self, req: CommandRequest, link: object) -> CommandResult:
        # ArduCopter: param1 0..360 and param4 0 or 1, else FAILED
        angle, relative = req.p(1), req.p(4)
        if not (math.isfinite(angle) and 0.0 <= angle <= 360.0 and relative in (0.0, 1.0)):
            return CommandResult(MavResult.FAILED)
        rate = req.p(2) if math.isfinite(req.p(2)) else 0.0
        direction = int(req.p(3)) if math.isfinite(req.p(3)) else 0
        return CommandResult(self._outcome(self._vehicle.condition_yaw(
            angle, rate, direction, relative == 1.0)))

    def _set_roi(self, req: CommandRequest, link: object) -> CommandResult:
        """DO_SET_ROI_LOCATION / DO_SET_ROI: the location in x, y, z (COMMAND_INT, degE7) or
        param5..7 (COMMAND_LONG, degrees); FAILED for a latitude / longitude out of range."""
        if req.is_int:
            lat, lon = req.x * 1e-7, req.y * 1e-7
            alt_frame = AltFrame.AMSL if req.frame in (MavFrame.GLOBAL, MavFrame.GLOBAL_INT) \
                else AltFrame.RELATIVE_HOME
        else:
            lat, lon = req.p(5), req.p(6)
            alt_frame = AltFrame.RELATIVE_HOME
        alt = req.p(7) if math.isfinite(req.p(7)) else 0.0
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90.0 and abs(lon) <= 180.0):
            return CommandResult(MavResult.FAILED)
        return CommandResult(self._outcome(self._vehicle.set_roi(lat, lon, alt, alt_frame)))

    def _set_roi_none(self, req: CommandRequest, link: object) -> CommandResult:
        return CommandResult(self._outcome(self._vehicle.set_roi(0.0, 0.0, 0.0,
                                                                 AltFrame.RELATIVE_HOME)))

    def _pause_continue(self, req: CommandRequest, link: object) -> CommandResult:
        action = _as_int(req.p(1), 0, 1)
        if action is None:
            return CommandResult(MavResult.DENIED)
        return CommandResult(self._outcome(self._vehicle.pause_continue(action == 0), MavSeverity.INFO))

    # ----------------------------------------------------------------- messages
    def _set_message_interval(self, req: CommandRequest, link: object) -> CommandResult:
        msg_id = _as_int(req.p(1), 0, MAX_MSG_ID)
        interval = req.p(2)
        if msg_id is None or not math.isfinite(interval):
            return CommandResult(MavResult.DENIED)
        if not self._svc.can_send(msg_id) and self._svc.ardupilot_has(msg_id):
            return CommandResult(MavResult.ACCEPTED)   # ArduPilot without the sensor: nothing sent
        if not self._svc.can_send(msg_id):
            # as GCS_MAVLINK::set_mavlink_message_id_interval for an id it has no ap_message for
            self._svc.statustext(MavSeverity.INFO, f"No ap_message for mavlink id ({msg_id})")
            return CommandResult(MavResult.DENIED)
        ok = self._svc.set_message_interval(link, msg_id, interval)
        return CommandResult(MavResult.ACCEPTED if ok else MavResult.DENIED)

    def _get_message_interval(self, req: CommandRequest, link: object) -> CommandResult:
        msg_id = _as_int(req.p(1), 0, MAX_MSG_ID)
        if msg_id is None:
            return CommandResult(MavResult.DENIED)
        reply = mavlink2.MAVLink_message_interval_message(
            msg_id & 0xFFFF, self._svc.message_interval_us(link, msg_id))
        return CommandResult(MavResult.ACCEPTED, reply=reply)

    def _request_message(self, req: CommandRequest, link: object) -> CommandResult:
        msg_id = _as_int(req.p(1), 0, MAX_MSG_ID)
        if msg_id is None or not self._svc.can_send(msg_id):
            return CommandResult(MavResult.DENIED)
        if msg_id == mavlink2.MAVLINK_MSG_ID_HOME_POSITION and not self._svc.telemetry().home_set:
            return CommandResult(MavResult.FAILED)
        return CommandResult(MavResult.ACCEPTED, then_send=(msg_id,))

    def _request_capabilities(self, req: CommandRequest, link: object) -> CommandResult:
        return CommandResult(MavResult.ACCEPTED,
                             then_send=(mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION,))

    def _get_home_position(self, req: CommandRequest, link: object) -> CommandResult:
        if not self._svc.telemetry().home_set:
            return CommandResult(MavResult.FAILED)
        return CommandResult(MavResult.ACCEPTED, then_send=(mavlink2.MAVLINK_MSG_ID_HOME_POSITION,))
