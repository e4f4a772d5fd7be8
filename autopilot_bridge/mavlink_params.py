"""MAVLink parameter protocol (part of ``MavlinkServer``): PARAM_REQUEST_LIST (sent in batches of
``params_per_poll``), PARAM_REQUEST_READ, PARAM_SET (refused values answered with the unchanged
value and a STATUSTEXT), and a PARAM_VALUE for every change, whoever made it.
"""

from __future__ import annotations

import logging
from collections import deque

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.mavlink_links import Link
from autopilot_bridge.telemetry import (
    statustext_messages,
)
from autopilot_bridge.vehicle_interface import (
    MavSeverity,
)

logger = logging.getLogger(__name__)

# What ArduPilot sends as STATUSTEXT when a ground station asks for the parameter list.
BANNER = ("ArduCopter V4.5.7 (scenenav emulator)", "Frame: QUAD/X")


def _param_name(raw: object) -> str:
    if isinstance(raw, (bytes, bytearray)):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).split("\0", 1)[0]


class ParamProtocolMixin:
    """Part of ``MavlinkServer`` (``autopilot_bridge.mavlink_server``); works on its state."""

    def _param_value(self, index: int) -> mavlink2.MAVLink_message:
        spec, value = self.params.by_index(index)
        return mavlink2.MAVLink_param_value_message(
            spec.name.encode("ascii"), float(value), int(spec.ptype), self.params.count, index)

    def _on_param_request_list(self, msg: mavlink2.MAVLink_message, link: Link,
                               now_s: float) -> None:
        for text in BANNER:
            for m in statustext_messages(int(MavSeverity.INFO), text, 0):
                self.send(link, m)
        link.param_queue = deque(range(self.params.count))

    def _send_param_batches(self) -> None:
        for link in list(self._links):
            for _ in range(min(self.cfg.params_per_poll, len(link.param_queue))):
                self.send(link, self._param_value(link.param_queue.popleft()))

    def _on_param_request_read(self, msg: mavlink2.MAVLink_message, link: Link,
                               now_s: float) -> None:
        if msg.param_index >= 0:
            index: int | None = msg.param_index if msg.param_index < self.params.count else None
        else:
            index = self.params.index_of(_param_name(msg.param_id))
        if index is None:
            logger.debug("PARAM_REQUEST_READ %r/%d: no such parameter", msg.param_id,
                         msg.param_index)
            return
        self.send(link, self._param_value(index))

    def _on_param_set(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        name = _param_name(msg.param_id)
        index = self.params.index_of(name)
        if index is None:
            logger.info("PARAM_SET %r: no such parameter", name)
            return
        before = self.params.get(name)
        result = self.params.set(name, msg.param_value)
        if not result.ok:
            self.stats["param_set_refused"] += 1
            self.send(link, self._param_value(index))
            self.statustext(MavSeverity.WARNING, result.reason)
            return
        if result.reason:                       # stored, clamped to a safe limit: say so
            self.stats["param_set_clamped"] += 1
            self.statustext(MavSeverity.WARNING, result.reason)
        if result.value == before:
            self.broadcast(self._param_value(index))
        else:
            self._flush_param_changes()  # echo the change right away

    def _on_param_changed(self, name: str, value: float) -> None:
        """ParameterStore observer. Queued, so a change made from another thread is sent and
        passed to the vehicle by the poll thread."""
        self._param_changes.append((name, value))

    def _flush_param_changes(self) -> None:
        while self._param_changes:
            name, value = self._param_changes.popleft()
            index = self.params.index_of(name)
            if index is not None:
                self.broadcast(self._param_value(index))
            self.vehicle.param_changed(name, value)
