"""MAVLink mission protocol (upload, download, clear, set current) against a Vehicle.

Shell module (uses pymavlink). Behaviour follows ArduPilot's ``MissionItemProtocol`` and
``AP_Mission`` (``libraries/GCS_MAVLink/MissionItemProtocol*.cpp``,
``libraries/AP_Mission/AP_Mission.cpp``):

* Upload: MISSION_COUNT -> we request each item with MISSION_REQUEST_INT (MISSION_REQUEST
  once the GCS answers with float MISSION_ITEMs) -> MISSION_ITEM_INT / MISSION_ITEM ... ->
  MISSION_ACK. A request is repeated after ``request_retry_s`` without an item; the upload is
  cancelled (MISSION_ACK OPERATION_CANCELLED + STATUSTEXT) after ``upload_timeout_s`` without
  one. Another sender's MISSION_COUNT during an upload gets DENIED; the same sender may restart.
  Out-of-order items get INVALID_SEQUENCE (upload continues), a bad item ends the upload with
  its error code. Unlike ArduPilot (which truncates and writes items as they arrive) the new
  mission replaces the old one atomically when the last item is accepted, and only if
  ``Vehicle.mission_changed`` agrees.
* Download: MISSION_REQUEST_LIST -> MISSION_COUNT (items + 1 for home) -> MISSION_REQUEST_INT
  (answered with MISSION_ITEM_INT) or MISSION_REQUEST (answered with MISSION_ITEM).
  Item 0 is always the vehicle's current home (frame GLOBAL, NAV_WAYPOINT), as in ArduPilot;
  an uploaded item 0 is validated and then ignored.
* MISSION_WRITE_PARTIAL_LIST (items start..end replaced, or appended when end is one past the
  last item), MISSION_CLEAR_ALL, MISSION_SET_CURRENT; MAV_CMD_DO_SET_MISSION_CURRENT lives in
  commands.py.
* Fence and rally (mission_type 1, 2) are ``fence_rally_protocol``'s: the server routes them
  there before this manager sees them (what this one still answers for them is a fallback).
* "Guided waypoint" (MISSION_ITEM(_INT) with current == 2, sent by older MAVProxy and QGC): in GUIDED mode it becomes ``Vehicle.reposition``; MISSION_ACK ACCEPTED/ERROR.
* "Change altitude" (current == 3, MAVProxy's ``changealt``): ACCEPTED without effect, as
  ArduCopter (its ``handle_change_alt_request`` only converts the altitude; moving the target is a
  to-do there).

Item validation as ``AP_Mission::mavlink_int_to_mission_cmd``: param1..4 must be finite
(param4 may be NaN for NAV_WAYPOINT/LAND/TAKEOFF) -> INVALID_PARAMn; a command AP_Mission does
not store (``MissionCommand`` lists those it does) -> UNSUPPORTED; location commands need
|lat| <= 90, |lon| <= 180 (INVALID_PARAM5_X / INVALID_PARAM6_Y; NaN in a float MISSION_ITEM
fails too), finite |alt| < 83000 m (INVALID_PARAM7) and a MISSION, GLOBAL, GLOBAL_RELATIVE_ALT
or GLOBAL_TERRAIN_ALT (or _INT) frame (UNSUPPORTED_FRAME).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.modes import CopterMode
from autopilot_bridge.telemetry import deg_e7
from autopilot_bridge.vehicle_interface import (
    MavFrame,
    MavSeverity,
    MissionCommand,
    MissionItem,
    Vehicle,
    VehicleTelemetry,
)

logger = logging.getLogger(__name__)

MAX_MISSION_ITEMS = 700          # including home
LOCATION_ALT_MAX_M = 83000.0     # ArduPilot LOCATION_ALT_MAX_M
LAT_E7_MAX = 900_000_000
LON_E7_MAX = 1_800_000_000


class MissionResult(IntEnum):
    """MAV_MISSION_RESULT (MISSION_ACK.type)."""

    ACCEPTED = 0
    ERROR = 1
    UNSUPPORTED_FRAME = 2
    UNSUPPORTED = 3
    NO_SPACE = 4
    INVALID = 5
    INVALID_PARAM1 = 6
    INVALID_PARAM2 = 7
    INVALID_PARAM3 = 8
    INVALID_PARAM4 = 9
    INVALID_PARAM5_X = 10
    INVALID_PARAM6_Y = 11
    INVALID_PARAM7 = 12
    INVALID_SEQUENCE = 13
    DENIED = 14
    OPERATION_CANCELLED = 15


class MissionType(IntEnum):
    """MAV_MISSION_TYPE."""

    MISSION = 0
    FENCE = 1
    RALLY = 2
    ALL = 255


class GuidedItemFlag(IntEnum):
    """Special values of MISSION_ITEM.current (ArduPilot extension)."""

    GUIDED_WAYPOINT = 2
    CHANGE_ALT = 3


# Every command AP_Mission stores is accepted (what the flight core executes and what it stores
# and skips: ``autopilot_bridge.auto_mission``); any other id is UNSUPPORTED, as AP_Mission.
ACCEPTED_COMMANDS: frozenset[int] = frozenset(int(c) for c in MissionCommand)

# The messages MissionManager.handle processes (docs/mavlink.md's compatibility table lists them).
HANDLED_MESSAGES: frozenset[str] = frozenset({
    "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_LIST",
    "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_CLEAR_ALL", "MISSION_WRITE_PARTIAL_LIST",
    "MISSION_SET_CURRENT", "MISSION_ACK",
})

# Commands whose x/y/z are a location (AP_Mission::stored_in_location).
LOCATION_COMMANDS: frozenset[int] = frozenset({
    MissionCommand.NAV_WAYPOINT, MissionCommand.NAV_LOITER_UNLIM, MissionCommand.NAV_LOITER_TURNS,
    MissionCommand.NAV_LOITER_TIME, MissionCommand.NAV_LAND, MissionCommand.NAV_TAKEOFF,
    MissionCommand.NAV_CONTINUE_AND_CHANGE_ALT, MissionCommand.NAV_LOITER_TO_ALT,
    MissionCommand.NAV_SPLINE_WAYPOINT, MissionCommand.NAV_GUIDED_ENABLE,
    MissionCommand.DO_SET_HOME, MissionCommand.DO_LAND_START, MissionCommand.DO_GO_AROUND,
    MissionCommand.DO_SET_ROI, MissionCommand.DO_SET_ROI_LOCATION,
    MissionCommand.NAV_VTOL_TAKEOFF, MissionCommand.NAV_VTOL_LAND,
    MissionCommand.NAV_PAYLOAD_PLACE,
})
PARAM4_NAN_ALLOWED: frozenset[int] = frozenset({
    MissionCommand.NAV_WAYPOINT, MissionCommand.NAV_LAND, MissionCommand.NAV_TAKEOFF,
})
# x/y are not latitude/longitude for these (AP_Mission::mavlink_to_mission_cmd).
RAW_XY_COMMANDS: frozenset[int] = frozenset({
    MissionCommand.DO_DIGICAM_CONFIGURE, MissionCommand.DO_DIGICAM_CONTROL,
})
# MISSION and GLOBAL(_INT) are absolute; the terrain frames are stored as AP_Mission does (built with
# terrain support) and answered when flown as ArduCopter answers without terrain data.
LOCATION_FRAMES: frozenset[int] = frozenset({
    MavFrame.GLOBAL, MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_INT,
    MavFrame.GLOBAL_RELATIVE_ALT_INT, MavFrame.MISSION, MavFrame.GLOBAL_TERRAIN_ALT,
    MavFrame.GLOBAL_TERRAIN_ALT_INT,
})


def decode_item(msg: mavlink2.MAVLink_message, is_int: bool
                ) -> tuple[MissionItem | None, MissionResult]:
    """A MISSION_ITEM_INT (``is_int``) or MISSION_ITEM -> a validated MissionItem or an error."""
    command = int(msg.command)
    if is_int:
        x_e7, y_e7 = int(msg.x), int(msg.y)
    elif command in RAW_XY_COMMANDS:
        if not (math.isfinite(msg.x) and abs(msg.x) < 2 ** 31):
            return None, MissionResult.INVALID_PARAM5_X
        if not (math.isfinite(msg.y) and abs(msg.y) < 2 ** 31):
            return None, MissionResult.INVALID_PARAM6_Y
        x_e7, y_e7 = int(round(msg.x)), int(round(msg.y))
    else:
        # MISSION_ITEM: every command's x/y are latitude/longitude in degrees; NaN fails.
        if not abs(msg.x) <= 90.0:
            return None, MissionResult.INVALID_PARAM5_X
        if not abs(msg.y) <= 180.0:
            return None, MissionResult.INVALID_PARAM6_Y
        x_e7, y_e7 = deg_e7(msg.x), deg_e7(msg.y)

    params = (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4))
    for i, value in enumerate(params):
        nan_ok = i == 3 and command in PARAM4_NAN_ALLOWED
        if math.isinf(value) or (math.isnan(value) and not nan_ok):
            return None, MissionResult(MissionResult.INVALID_PARAM1 + i)
    if command == 0:
        return None, MissionResult.INVALID
    if command not in ACCEPTED_COMMANDS:
        return None, MissionResult.UNSUPPORTED

    z = float(msg.z)
    if command in LOCATION_COMMANDS:
        if abs(x_e7) > LAT_E7_MAX:
            return None, MissionResult.INVALID_PARAM5_X
        if abs(y_e7) > LON_E7_MAX:
            return None, MissionResult.INVALID_PARAM6_Y
        if not abs(z) < LOCATION_ALT_MAX_M:
            return None, MissionResult.INVALID_PARAM7
        if int(msg.frame) not in LOCATION_FRAMES:
            return None, MissionResult.UNSUPPORTED_FRAME
    elif not math.isfinite(z):
        z = 0.0
    item = MissionItem(seq=int(msg.seq), command=command, frame=int(msg.frame),
                       param1=params[0], param2=params[1], param3=params[2], param4=params[3],
                       lat_e7=x_e7, lon_e7=y_e7, alt_m=z, autocontinue=bool(msg.autocontinue))
    return item, MissionResult.ACCEPTED


def home_item(tel: VehicleTelemetry) -> MissionItem:
    """Item 0 as ArduPilot reports it: the current home, NAV_WAYPOINT, absolute altitude."""
    return MissionItem(seq=0, command=int(MissionCommand.NAV_WAYPOINT), frame=int(MavFrame.GLOBAL),
                       lat_e7=deg_e7(tel.home_lat_deg), lon_e7=deg_e7(tel.home_lon_deg),
                       alt_m=tel.home_alt_amsl_m if math.isfinite(tel.home_alt_amsl_m) else 0.0)


def item_int_message(item: MissionItem, target: tuple[int, int], current: bool,
                     mission_type: int = MissionType.MISSION) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_mission_item_int_message(
        target[0], target[1], item.seq, item.frame, item.command, int(current),
        int(item.autocontinue), item.param1, item.param2, item.param3, item.param4,
        item.lat_e7, item.lon_e7, item.alt_m, mission_type)


def item_float_message(item: MissionItem, target: tuple[int, int], current: bool,
                       mission_type: int = MissionType.MISSION) -> mavlink2.MAVLink_message:
    if item.command in RAW_XY_COMMANDS:
        x, y = float(item.lat_e7), float(item.lon_e7)
    else:
        x, y = item.lat_deg, item.lon_deg
    return mavlink2.MAVLink_mission_item_message(
        target[0], target[1], item.seq, item.frame, item.command, int(current),
        int(item.autocontinue), item.param1, item.param2, item.param3, item.param4,
        x, y, item.alt_m, mission_type)


class MissionOutbox(Protocol):
    """What the mission protocol needs from the server."""

    def send(self, link: object, msg: mavlink2.MAVLink_message) -> None: ...

    def statustext(self, severity: MavSeverity, text: str) -> None: ...

    def telemetry(self) -> VehicleTelemetry: ...

    def send_mission_current(self, link: object) -> None: ...


@dataclass
class _Upload:
    """An upload in progress: items ``next_seq`` .. ``last_seq`` are still to come.

    ``items`` starts empty for a full upload (MISSION_COUNT) and as the stored mission (with a
    home placeholder at 0) for a partial one (MISSION_WRITE_PARTIAL_LIST), whose items replace
    or extend it.
    """

    link: object
    sender: tuple[int, int]
    last_seq: int
    next_seq: int
    last_rx_s: float
    last_request_s: float
    use_int: bool = True
    items: list[MissionItem] = field(default_factory=list)


class MissionManager:
    """Owns the stored mission and runs the transfer state machines."""

    def __init__(self, vehicle: Vehicle, outbox: MissionOutbox,
                 max_items: int = MAX_MISSION_ITEMS, upload_timeout_s: float = 8.0,
                 request_retry_s: float = 1.0) -> None:
        self._vehicle = vehicle
        self._out = outbox
        self.max_items = max_items
        self.upload_timeout_s = upload_timeout_s
        self.request_retry_s = request_retry_s
        self._items: tuple[MissionItem, ...] = ()
        self._upload: _Upload | None = None
        # (sender, last seq) of the last completed upload, to re-ACK a repeated final item
        self._last_completed: tuple[tuple[int, int], int] | None = None

    # ----------------------------------------------------------------- state
    @property
    def items(self) -> tuple[MissionItem, ...]:
        """The stored mission without home (seq 1..n)."""
        return self._items

    @property
    def count_with_home(self) -> int:
        return len(self._items) + 1

    @property
    def receiving(self) -> bool:
        return self._upload is not None

    # ----------------------------------------------------------------- dispatch
    def handle(self, msg: mavlink2.MAVLink_message, link: object, now_s: float) -> bool:
        """Process a mission-protocol message; False if ``msg`` is not one."""
        kind = msg.get_type()
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "MISSION_COUNT":
            self._on_count(msg, link, sender, now_s)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            self._on_item(msg, link, sender, now_s, kind == "MISSION_ITEM_INT")
        elif kind == "MISSION_REQUEST_LIST":
            self._on_request_list(msg, link, sender)
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._on_request(msg, link, sender, kind == "MISSION_REQUEST_INT")
        elif kind == "MISSION_CLEAR_ALL":
            self._on_clear_all(msg, link, sender)
        elif kind == "MISSION_WRITE_PARTIAL_LIST":
            self._on_write_partial_list(msg, link, sender, now_s)
        elif kind == "MISSION_SET_CURRENT":
            self.set_current(int(msg.seq), link)
        elif kind == "MISSION_ACK":
            logger.debug("MISSION_ACK %s from %s", msg.type, sender)
        else:
            return False
        return True

    def update(self, now_s: float) -> None:
        """Request retries and the upload timeout; call every poll."""
        up = self._upload
        if up is None:
            return
        if now_s - up.last_rx_s >= self.upload_timeout_s:
            logger.warning("mission upload from %s timed out at item %d (last %d)",
                           up.sender, up.next_seq, up.last_seq)
            self._upload = None
            self._ack(up.link, up.sender, MissionResult.OPERATION_CANCELLED, MissionType.MISSION)
            self._out.statustext(MavSeverity.WARNING, "Mission upload timeout")
        elif now_s - up.last_request_s >= self.request_retry_s:
            self._request_next(up, now_s)

    def link_closed(self, link: object) -> None:
        """Abandon an upload whose link went away."""
        if self._upload is not None and self._upload.link is link:
            logger.info("mission upload abandoned: link closed")
            self._upload = None

    def set_current(self, seq: int, link: object | None) -> bool:
        """MISSION_SET_CURRENT: seq 1..n; answered with MISSION_CURRENT when accepted."""
        if not 1 <= seq <= len(self._items):
            logger.info("MISSION_SET_CURRENT %d refused: mission has %d items", seq,
                        len(self._items))
            return False
        outcome = self._vehicle.set_current_mission_item(seq)
        if not outcome.ok:
            self._out.statustext(MavSeverity.WARNING, outcome.reason or "Set current item failed")
            return False
        if link is not None:
            self._out.send_mission_current(link)
        return True

    # ----------------------------------------------------------------- upload
    def _on_count(self, msg: mavlink2.MAVLink_message, link: object, sender: tuple[int, int],
                  now_s: float) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        count = int(msg.count)
        if mtype != MissionType.MISSION:
            result = MissionResult.ACCEPTED if count == 0 else MissionResult.UNSUPPORTED
            self._ack(link, sender, result, mtype)
            return
        if self._upload is not None and self._upload.sender != sender:
            self._ack(link, sender, MissionResult.DENIED, mtype)
            return
        self._upload = None
        if count > self.max_items:
            self._ack(link, sender, MissionResult.NO_SPACE, mtype)
            self._out.statustext(MavSeverity.WARNING,
                                 f"Only {self.max_items} items are supported")
            return
        if count == 0:
            self._commit((), link, sender)
            return
        self._upload = _Upload(link=link, sender=sender, last_seq=count - 1, next_seq=0,
                               last_rx_s=now_s, last_request_s=now_s)
        self._request_next(self._upload, now_s)

    def _on_write_partial_list(self, msg: mavlink2.MAVLink_message, link: object,
                               sender: tuple[int, int], now_s: float) -> None:
        """Replace items start..end (end may be one past the last item, to append)."""
        mtype = int(getattr(msg, "mission_type", 0))
        if self._refuse_request(link, sender, mtype,
                                upload_busy=self._upload is not None and self._upload.sender != sender):
            return
        start, end = int(msg.start_index), int(msg.end_index)
        if not 0 <= start <= end <= self.count_with_home or end >= self.max_items:
            self._ack(link, sender, MissionResult.ERROR, mtype)
            return
        placeholder = MissionItem(seq=0, command=int(MissionCommand.NAV_WAYPOINT),
                                  frame=int(MavFrame.GLOBAL))
        self._upload = _Upload(link=link, sender=sender, last_seq=end, next_seq=start,
                               last_rx_s=now_s, last_request_s=now_s,
                               items=[placeholder, *self._items])
        self._request_next(self._upload, now_s)

    def _on_item(self, msg: mavlink2.MAVLink_message, link: object, sender: tuple[int, int],
                 now_s: float, is_int: bool) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        current = int(msg.current)
        if mtype == MissionType.MISSION and current == GuidedItemFlag.GUIDED_WAYPOINT:
            self._guided_item(msg, link, sender, is_int)
            return
        if mtype == MissionType.MISSION and current == GuidedItemFlag.CHANGE_ALT:
            # ArduCopter: a valid item is accepted, and nothing moves
            # (GCS_MAVLINK_Copter::handle_change_alt_request)
            _, result = decode_item(msg, is_int)
            self._ack(link, sender, result, mtype)
            return
        up = self._upload
        if up is None:
            if mtype != MissionType.MISSION:
                self._ack(link, sender, MissionResult.UNSUPPORTED, mtype)
            elif self._last_completed == (sender, int(msg.seq)):
                self._ack(link, sender, MissionResult.ACCEPTED, mtype)  # our ACK was lost
            else:
                logger.debug("MISSION_ITEM seq %d from %s outside an upload ignored",
                             msg.seq, sender)
            return
        if sender != up.sender:
            self._ack(link, sender, MissionResult.DENIED, mtype)
            return
        if self._refuse_request(link, sender, mtype, upload_busy=False):
            return
        seq = int(msg.seq)
        if seq < up.next_seq:
            logger.debug("duplicate mission item %d ignored", seq)
            return
        if seq > up.next_seq:
            self._ack(link, sender, MissionResult.INVALID_SEQUENCE, mtype)
            return
        if not is_int:
            up.use_int = False
        item, result = decode_item(msg, is_int)
        if item is None:
            logger.info("mission item %d refused: %s", seq, result.name)
            self._upload = None
            self._ack(link, sender, result, mtype)
            return
        if seq < len(up.items):
            up.items[seq] = item
        else:
            up.items.append(item)
        up.next_seq += 1
        up.last_rx_s = now_s
        if up.next_seq > up.last_seq:
            self._upload = None
            # item 0 is home: validated, not stored (ArduPilot reports its own home there)
            self._commit(tuple(up.items[1:]), link, sender)
            self._last_completed = (sender, up.last_seq)
            return
        self._request_next(up, now_s)

    def _request_next(self, up: _Upload, now_s: float) -> None:
        up.last_request_s = now_s
        if up.use_int:
            msg = mavlink2.MAVLink_mission_request_int_message(
                up.sender[0], up.sender[1], up.next_seq, MissionType.MISSION)
        else:
            msg = mavlink2.MAVLink_mission_request_message(
                up.sender[0], up.sender[1], up.next_seq, MissionType.MISSION)
        self._out.send(up.link, msg)

    def _commit(self, items: tuple[MissionItem, ...], link: object,
                sender: tuple[int, int]) -> None:
        outcome = self._vehicle.mission_changed(items)
        if not outcome.ok:
            self._ack(link, sender, MissionResult.ERROR, MissionType.MISSION)
            self._out.statustext(MavSeverity.WARNING, outcome.reason or "Mission refused")
            return
        self._items = items
        logger.info("mission stored: %d items", len(items))
        self._ack(link, sender, MissionResult.ACCEPTED, MissionType.MISSION)
        if items:
            self._out.statustext(MavSeverity.INFO, "Flight plan received")

    def _guided_item(self, msg: mavlink2.MAVLink_message, link: object,
                     sender: tuple[int, int], is_int: bool) -> None:
        item, _ = decode_item(msg, is_int)
        alt_frame = item.alt_frame if item is not None else None
        ok = False
        if (item is not None and alt_frame is not None
                and item.command == MissionCommand.NAV_WAYPOINT
                and self._out.telemetry().mode == CopterMode.GUIDED):
            outcome = self._vehicle.reposition(item.lat_deg, item.lon_deg, item.alt_m,
                                               alt_frame, None, None)
            ok = outcome.ok
            if not ok and outcome.reason:
                self._out.statustext(MavSeverity.WARNING, outcome.reason)
        self._ack(link, sender, MissionResult.ACCEPTED if ok else MissionResult.ERROR,
                  MissionType.MISSION)

    # ----------------------------------------------------------------- download / clear
    def _on_request_list(self, msg: mavlink2.MAVLink_message, link: object,
                         sender: tuple[int, int]) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if mtype in (MissionType.FENCE, MissionType.RALLY):
            self._out.send(link, mavlink2.MAVLink_mission_count_message(
                sender[0], sender[1], 0, mtype))
            return
        if self._refuse_request(link, sender, mtype, upload_busy=self._upload is not None):
            return
        self._out.send(link, mavlink2.MAVLink_mission_count_message(
            sender[0], sender[1], self.count_with_home, mtype))

    def _on_request(self, msg: mavlink2.MAVLink_message, link: object, sender: tuple[int, int],
                    is_int: bool) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if self._refuse_request(link, sender, mtype, upload_busy=self._upload is not None):
            return
        seq = int(msg.seq)
        if seq >= self.count_with_home:
            # educate the GCS on the real size, then refuse (as ArduPilot)
            self._out.send(link, mavlink2.MAVLink_mission_count_message(
                sender[0], sender[1], self.count_with_home, mtype))
            self._ack(link, sender, MissionResult.ERROR, mtype)
            return
        tel = self._out.telemetry()
        item = home_item(tel) if seq == 0 else self._items[seq - 1]
        current = seq == tel.mission_current_seq and seq != 0
        build = item_int_message if is_int else item_float_message
        self._out.send(link, build(item, sender, current, mtype))

    def _on_clear_all(self, msg: mavlink2.MAVLink_message, link: object,
                      sender: tuple[int, int]) -> None:
        mtype = int(getattr(msg, "mission_type", 0))
        if mtype in (MissionType.FENCE, MissionType.RALLY):
            self._ack(link, sender, MissionResult.ACCEPTED, mtype)
            return
        if mtype not in (MissionType.MISSION, MissionType.ALL):
            self._ack(link, sender, MissionResult.UNSUPPORTED, mtype)
            return
        if self._upload is not None:
            self._ack(link, sender, MissionResult.ERROR, mtype)
            return
        outcome = self._vehicle.mission_changed(())
        if not outcome.ok:
            self._ack(link, sender, MissionResult.ERROR, mtype)
            self._out.statustext(MavSeverity.WARNING, outcome.reason or "Mission clear refused")
            return
        self._items = ()
        logger.info("mission cleared")
        self._ack(link, sender, MissionResult.ACCEPTED, mtype)

    def _refuse_request(self, link: object, sender: tuple[int, int], mtype: int, *,
                        upload_busy: bool) -> bool:
        """ACK UNSUPPORTED for a mission type other than MISSION, DENIED while another upload
        runs (``upload_busy``); True when the request was refused."""
        if mtype != MissionType.MISSION:
            self._ack(link, sender, MissionResult.UNSUPPORTED, mtype)
            return True
        if upload_busy:
            self._ack(link, sender, MissionResult.DENIED, mtype)
            return True
        return False

    def _ack(self, link: object, sender: tuple[int, int], result: MissionResult,
             mission_type: int) -> None:
        self._out.send(link, mavlink2.MAVLink_mission_ack_message(
            sender[0], sender[1], int(result), int(mission_type) & 0xFF))
