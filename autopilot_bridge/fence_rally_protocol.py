"""The mission protocol for mission_type FENCE and RALLY (ArduPilot's ``MissionItemProtocol_Fence``
and ``MissionItemProtocol_Rally``), next to ``mission.MissionManager`` for type MISSION.

Shell module (pymavlink). The same messages as a mission (MISSION_COUNT, MISSION_REQUEST_INT /
MISSION_REQUEST, MISSION_ITEM_INT / MISSION_ITEM, MISSION_ACK, MISSION_REQUEST_LIST,
MISSION_CLEAR_ALL) with the message's ``mission_type``; differences from a mission: there is no home
item (seq 0 is the first fence / rally item), MISSION_WRITE_PARTIAL_LIST and MISSION_SET_CURRENT do
not apply. Items are validated here (fence commands 5000-5004 in a FENCE upload, NAV_RALLY_POINT
5100 in a RALLY one; finite params, valid latitude / longitude / altitude, a GLOBAL or
GLOBAL_RELATIVE_ALT frame), then the whole list goes to ``Vehicle.fence_changed`` /
``Vehicle.rally_changed`` (which may refuse it: an incomplete polygon), atomically at the end as
for missions. Request retries and the upload timeout are the mission's. MISSION_CLEAR_ALL with
mission_type ALL also clears fence and rally (the mission protocol answers it).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.geofence import FENCE_COMMANDS, MAX_FENCE_ITEMS, MAX_RALLY_POINTS, RALLY_COMMANDS
from autopilot_bridge.mission import (
    LAT_E7_MAX,
    LOCATION_ALT_MAX_M,
    LOCATION_FRAMES,
    LON_E7_MAX,
    MissionOutbox,
    MissionResult,
    MissionType,
    item_float_message,
    item_int_message,
)
from autopilot_bridge.telemetry import deg_e7
from autopilot_bridge.vehicle_interface import MavSeverity, MissionItem, Outcome, Vehicle

logger = logging.getLogger(__name__)

HANDLED = frozenset({"MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_LIST",
                     "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_CLEAR_ALL", "MISSION_ACK"})


def decode_typed_item(msg: mavlink2.MAVLink_message, is_int: bool, commands: frozenset[int]
                      ) -> tuple[MissionItem | None, MissionResult]:
    """A fence or rally MISSION_ITEM(_INT) -> MissionItem, or the MISSION_ACK error."""
    command = int(msg.command)
    params = (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4))
    for i, value in enumerate(params):
        if not math.isfinite(value):
            return None, MissionResult(MissionResult.INVALID_PARAM1 + i)
    if command not in commands:
        return None, MissionResult.UNSUPPORTED
    if is_int:
        x_e7, y_e7 = int(msg.x), int(msg.y)
    else:
        if not abs(msg.x) <= 90.0:
            return None, MissionResult.INVALID_PARAM5_X
        if not abs(msg.y) <= 180.0:
            return None, MissionResult.INVALID_PARAM6_Y
        x_e7, y_e7 = deg_e7(msg.x), deg_e7(msg.y)
    if abs(x_e7) > LAT_E7_MAX:
        return None, MissionResult.INVALID_PARAM5_X
    if abs(y_e7) > LON_E7_MAX:
        return None, MissionResult.INVALID_PARAM6_Y
    z = float(msg.z)
    if not abs(z) < LOCATION_ALT_MAX_M:
        return None, MissionResult.INVALID_PARAM7
    if int(msg.frame) not in LOCATION_FRAMES:
        return None, MissionResult.UNSUPPORTED_FRAME
    return MissionItem(seq=int(msg.seq), command=command, frame=int(msg.frame), param1=params[0],
                       param2=params[1], param3=params[2], param4=params[3], lat_e7=x_e7,
                       lon_e7=y_e7, alt_m=z, autocontinue=bool(msg.autocontinue)), MissionResult.ACCEPTED


@dataclass
class _Upload:
    link: object
    sender: tuple[int, int]
    count: int
    last_rx_s: float
    last_request_s: float
    use_int: bool = True
    items: list[MissionItem] = field(default_factory=list)


class ItemListProtocol:
    """Upload / download / clear of one mission_type's item list (FENCE or RALLY)."""

    def __init__(self, mission_type: MissionType, commands: frozenset[int], max_items: int,
                 commit: Callable[[tuple[MissionItem, ...]], Outcome], outbox: MissionOutbox,
                 upload_timeout_s: float, request_retry_s: float, name: str) -> None:
        self.mission_type = mission_type
        self._commands = commands
        self.max_items = max_items
        self._commit_fn = commit
        self._out = outbox
        self._timeout_s = upload_timeout_s
        self._retry_s = request_retry_s
        self._name = name
        self.items: tuple[MissionItem, ...] = ()
        self._upload: _Upload | None = None

    def handle(self, msg: mavlink2.MAVLink_message, link: object, now_s: float) -> None:
        kind = msg.get_type()
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "MISSION_COUNT":
            self._on_count(int(msg.count), link, sender, now_s)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            self._on_item(msg, link, sender, now_s, kind == "MISSION_ITEM_INT")
        elif kind == "MISSION_REQUEST_LIST":
            self._send(link, mavlink2.MAVLink_mission_count_message(
                sender[0], sender[1], len(self.items), self.mission_type))
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            seq = int(msg.seq)
            if seq >= len(self.items):
                self._send(link, mavlink2.MAVLink_mission_count_message(
                    sender[0], sender[1], len(self.items), self.mission_type))
                self._ack(link, sender, MissionResult.ERROR)
                return
            build = item_int_message if kind == "MISSION_REQUEST_INT" else item_float_message
            self._send(link, build(self.items[seq], sender, False, self.mission_type))
        elif kind == "MISSION_CLEAR_ALL":
            self._ack(link, sender, self.clear())
        # MISSION_ACK from the GCS ends a download: nothing to do

    def clear(self) -> MissionResult:
        if self._upload is not None:
            return MissionResult.ERROR
        outcome = self._commit_fn(())
        if not outcome.ok:
            return MissionResult.ERROR
        self.items = ()
        return MissionResult.ACCEPTED

    def update(self, now_s: float) -> None:
        up = self._upload
        if up is None:
            return
        if now_s - up.last_rx_s >= self._timeout_s:
            self._upload = None
            self._ack(up.link, up.sender, MissionResult.OPERATION_CANCELLED)
            self._out.statustext(MavSeverity.WARNING, f"{self._name} upload timeout")
        elif now_s - up.last_request_s >= self._retry_s:
            self._request_next(up, now_s)

    def link_closed(self, link: object) -> None:
        if self._upload is not None and self._upload.link is link:
            self._upload = None

    def _on_count(self, count: int, link: object, sender: tuple[int, int], now_s: float) -> None:
        if self._upload is not None and self._upload.sender != sender:
            self._ack(link, sender, MissionResult.DENIED)
            return
        self._upload = None
        if count > self.max_items:
            self._ack(link, sender, MissionResult.NO_SPACE)
            return
        if count == 0:
            self._commit((), link, sender)
            return
        self._upload = _Upload(link, sender, count, now_s, now_s)
        self._request_next(self._upload, now_s)

    def _on_item(self, msg: mavlink2.MAVLink_message, link: object, sender: tuple[int, int],
                 now_s: float, is_int: bool) -> None:
        up = self._upload
        if up is None:
            self._ack(link, sender, MissionResult.ERROR)
            return
        if sender != up.sender:
            self._ack(link, sender, MissionResult.DENIED)
            return
        seq = int(msg.seq)
        if seq < len(up.items):
            return                                  # a repeat
        if seq > len(up.items):
            self._ack(link, sender, MissionResult.INVALID_SEQUENCE)
            return
        if not is_int:
            up.use_int = False
        item, result = decode_typed_item(msg, is_int, self._commands)
        if item is None:
            self._upload = None
            self._ack(link, sender, result)
            return
        up.items.append(item)
        up.last_rx_s = now_s
        if len(up.items) == up.count:
            self._upload = None
            self._commit(tuple(up.items), link, sender)
            return
        self._request_next(up, now_s)

    def _request_next(self, up: _Upload, now_s: float) -> None:
        up.last_request_s = now_s
        cls = (mavlink2.MAVLink_mission_request_int_message if up.use_int
               else mavlink2.MAVLink_mission_request_message)
        self._send(up.link, cls(up.sender[0], up.sender[1], len(up.items), self.mission_type))

    def _commit(self, items: tuple[MissionItem, ...], link: object, sender: tuple[int, int]) -> None:
        outcome = self._commit_fn(items)
        if not outcome.ok:
            self._ack(link, sender, MissionResult.ERROR)
            self._out.statustext(MavSeverity.WARNING, outcome.reason or f"{self._name} refused")
            return
        self.items = items
        logger.info("%s stored: %d items", self._name, len(items))
        self._ack(link, sender, MissionResult.ACCEPTED)

    def _send(self, link: object, msg: mavlink2.MAVLink_message) -> None:
        self._out.send(link, msg)

    def _ack(self, link: object, sender: tuple[int, int], result: MissionResult) -> None:
        self._send(link, mavlink2.MAVLink_mission_ack_message(
            sender[0], sender[1], int(result), int(self.mission_type)))


class FenceRallyProtocols:
    """The FENCE and RALLY protocols of a server; ``handle`` takes the messages of those types."""

    def __init__(self, vehicle: Vehicle, outbox: MissionOutbox, upload_timeout_s: float,
                 request_retry_s: float) -> None:
        self.fence = ItemListProtocol(MissionType.FENCE, FENCE_COMMANDS, MAX_FENCE_ITEMS,
                                      vehicle.fence_changed, outbox, upload_timeout_s,
                                      request_retry_s, "Fence")
        self.rally = ItemListProtocol(MissionType.RALLY, RALLY_COMMANDS, MAX_RALLY_POINTS,
                                      vehicle.rally_changed, outbox, upload_timeout_s,
                                      request_retry_s, "Rally")

    def handle(self, msg: mavlink2.MAVLink_message, link: object, now_s: float) -> bool:
        """True when ``msg`` was a FENCE / RALLY message (answered here). A CLEAR_ALL of type ALL
        clears both and returns False: the mission protocol answers it."""
        kind = msg.get_type()
        if kind not in HANDLED:
            return False
        mtype = int(getattr(msg, "mission_type", MissionType.MISSION))
        if kind == "MISSION_CLEAR_ALL" and mtype == MissionType.ALL:
            self.fence.clear()
            self.rally.clear()
            return False
        protocol = {MissionType.FENCE: self.fence, MissionType.RALLY: self.rally}.get(
            MissionType(mtype) if mtype in (1, 2) else MissionType.MISSION)
        if protocol is None:
            return False
        protocol.handle(msg, link, now_s)
        return True

    def update(self, now_s: float) -> None:
        self.fence.update(now_s)
        self.rally.update(now_s)

    def link_closed(self, link: object) -> None:
        self.fence.link_closed(link)
        self.rally.link_closed(link)
