"""A small MAVLink ground-station client (pymavlink) for the guidance node and tools.

Connects to the autopilot like any GCS or companion computer, uploads a mission with the
MISSION_COUNT / MISSION_REQUEST_INT / MISSION_ITEM_INT / MISSION_ACK exchange, changes mode,
arms, and reads back progress. Shell module: the only pymavlink user in ``guidance/``.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from guidance.config import RouteEnd  # noqa: E402
from guidance.fence import FenceItem  # noqa: E402

log = logging.getLogger(__name__)

COPTER_MODES = {"STABILIZE": 0, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9}


class MavlinkClientError(RuntimeError):
    """The autopilot refused or did not answer a request."""


@dataclass(frozen=True)
class MissionWaypoint:
    lat_deg: float
    lon_deg: float
    alt_rel_m: float
    command: int = mavutil.mavlink.MAV_CMD_NAV_WAYPOINT


class AutopilotLink:
    def __init__(self, url: str, source_system: int = 255, source_component: int = 190,
                 timeout_s: float = 30.0):
        self.url = url
        self.timeout_s = timeout_s
        self._link_lost = False     # said once: the autopilot's link refused a reconnect
        self.conn = mavutil.mavlink_connection(url, source_system=source_system,
                                               source_component=source_component, autoreconnect=True)
        self._last_hb_sent = 0.0

    def wait_heartbeat(self) -> None:
        msg = self.conn.wait_heartbeat(timeout=self.timeout_s)
        if msg is None:
            raise MavlinkClientError(f"no heartbeat from the autopilot at {self.url} "
                                     f"within {self.timeout_s:.0f} s")

    def heartbeat(self) -> None:
        """Send our GCS heartbeat (at most 1 Hz)."""
        now = time.monotonic()
        if now - self._last_hb_sent >= 1.0:
            self.conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS,
                                         mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self._last_hb_sent = now

    def _recv(self, types, timeout_s: float):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.heartbeat()
            msg = self.conn.recv_match(type=types, blocking=True, timeout=0.2)
            if msg is not None:
                return msg
        return None

    def command(self, command: int, *params: float, timeout_s: float = 10.0) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(self.conn.target_system, self.conn.target_component,
                                        command, 0, *p)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            ack = self._recv("COMMAND_ACK", deadline - time.monotonic())
            if ack is not None and ack.command == command:
                return ack.result
        raise MavlinkClientError(f"no COMMAND_ACK for command {command}")

    def set_mode(self, name: str) -> None:
        mode = COPTER_MODES[name]
        result = self.command(mavutil.mavlink.MAV_CMD_DO_SET_MODE,
                              mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)
        if result != mavutil.mavlink.MAV_RESULT_ACCEPTED:
            raise MavlinkClientError(f"mode {name} refused (MAV_RESULT {result})")

    def arm(self, retry_s: float = 60.0) -> None:
        """Arm, retrying for ``retry_s`` wall seconds while pre-arm checks fail (0: one try)."""
        deadline = time.monotonic() + retry_s
        while True:
            result = self.command(mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            if result == mavutil.mavlink.MAV_RESULT_ACCEPTED:
                return
            if time.monotonic() >= deadline:
                raise MavlinkClientError(f"arming refused (MAV_RESULT {result})")
            time.sleep(0.5)

    def upload_mission(self, items: list[MissionWaypoint], takeoff_alt_m: float | None = None,
                       end: RouteEnd = RouteEnd.LAND) -> int:
        """Upload home placeholder + [takeoff] + waypoints + [land or RTL]; returns the item count."""
        m = mavutil.mavlink
        rows: list[tuple[int, int, float, float, float, float]] = []  # (cmd, frame, p1, lat, lon, alt)
        first = items[0]
        rows.append((m.MAV_CMD_NAV_WAYPOINT, m.MAV_FRAME_GLOBAL, 0, first.lat_deg, first.lon_deg, 0.0))
        if takeoff_alt_m is not None:
            rows.append((m.MAV_CMD_NAV_TAKEOFF, m.MAV_FRAME_GLOBAL_RELATIVE_ALT, 0,
                         first.lat_deg, first.lon_deg, takeoff_alt_m))
        for it in items:
            rows.append((it.command, m.MAV_FRAME_GLOBAL_RELATIVE_ALT, 0, it.lat_deg, it.lon_deg, it.alt_rel_m))
        last = items[-1]
        if end is RouteEnd.LAND:
            rows.append((m.MAV_CMD_NAV_LAND, m.MAV_FRAME_GLOBAL_RELATIVE_ALT, 0, last.lat_deg, last.lon_deg, 0.0))
        elif end is RouteEnd.RTL:
            rows.append((m.MAV_CMD_NAV_RETURN_TO_LAUNCH, m.MAV_FRAME_GLOBAL_RELATIVE_ALT, 0, 0.0, 0.0, 0.0))
        ts, tc = self.conn.target_system, self.conn.target_component
        self.conn.mav.mission_count_send(ts, tc, len(rows), m.MAV_MISSION_TYPE_MISSION)
        sent = set()
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            msg = self._recv(["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"],
                             deadline - time.monotonic())
            if msg is None:
                break
            if msg.get_type() == "MISSION_ACK":
                if msg.type != m.MAV_MISSION_ACCEPTED:
                    raise MavlinkClientError(f"mission refused (MAV_MISSION_RESULT {msg.type})")
                if len(sent) == len(rows):
                    return len(rows)
                continue
            seq = msg.seq
            if not 0 <= seq < len(rows):
                continue
            cmd, frame, p1, lat, lon, alt = rows[seq]
            self.conn.mav.mission_item_int_send(ts, tc, seq, frame, cmd, 1 if seq == 0 else 0, 1,
                                                p1, 0, 0, float("nan"), int(round(lat * 1e7)),
                                                int(round(lon * 1e7)), alt, m.MAV_MISSION_TYPE_MISSION)
            sent.add(seq)
        raise MavlinkClientError("mission upload timed out")

    def download_fence(self) -> list[FenceItem]:
        """The autopilot's fence (MISSION_REQUEST_LIST / MISSION_COUNT / MISSION_REQUEST_INT /
        MISSION_ITEM_INT / MISSION_ACK with mission_type FENCE), in item order."""
        m = mavutil.mavlink
        fence = m.MAV_MISSION_TYPE_FENCE
        ts, tc = self.conn.target_system, self.conn.target_component
        count = None
        for _ in range(3):
            self.conn.mav.mission_request_list_send(ts, tc, fence)
            msg = self._recv_fence("MISSION_COUNT", 3.0)
            if msg is not None:
                count = int(msg.count)
                break
        if count is None:
            raise MavlinkClientError("no MISSION_COUNT for the fence")
        items: list[FenceItem] = []
        for seq in range(count):
            for _ in range(3):
                self.conn.mav.mission_request_int_send(ts, tc, seq, fence)
                msg = self._recv_fence("MISSION_ITEM_INT", 3.0, seq)
                if msg is not None:
                    items.append(FenceItem(int(msg.command), float(msg.param1), msg.x * 1e-7, msg.y * 1e-7))
                    break
            else:
                raise MavlinkClientError(f"no fence item {seq}")
        self.conn.mav.mission_ack_send(ts, tc, m.MAV_MISSION_ACCEPTED, fence)
        return items

    def _recv_fence(self, kind: str, timeout_s: float, seq: int | None = None):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self._recv(kind, deadline - time.monotonic())
            if msg is not None and getattr(msg, "mission_type", 0) == mavutil.mavlink.MAV_MISSION_TYPE_FENCE \
                    and (seq is None or msg.seq == seq):
                return msg
        return None

    def read_params(self, names: tuple[str, ...], timeout_s: float = 2.0) -> dict[str, float]:
        """PARAM_REQUEST_READ by name (all at once, one retry for the missing); the values that
        came back (a name the autopilot does not have gets no answer, as ArduPilot)."""
        values: dict[str, float] = {}
        ts, tc = self.conn.target_system, self.conn.target_component
        for _ in range(2):
            missing = [n for n in names if n not in values]
            if not missing:
                break
            for name in missing:
                self.conn.mav.param_request_read_send(ts, tc, name.encode("ascii"), -1)
            deadline = time.monotonic() + timeout_s / 2
            while time.monotonic() < deadline and any(n not in values for n in names):
                msg = self._recv("PARAM_VALUE", deadline - time.monotonic())
                if msg is not None and msg.param_id in names:
                    values[msg.param_id] = float(msg.param_value)
        return values

    def start_mission(self) -> None:
        result = self.command(mavutil.mavlink.MAV_CMD_MISSION_START, 0, 0)
        if result != mavutil.mavlink.MAV_RESULT_ACCEPTED:
            raise MavlinkClientError(f"MISSION_START refused (MAV_RESULT {result})")

    def set_current(self, seq: int) -> None:
        self.command(mavutil.mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, seq)

    def poll(self, types=None):
        """Non-blocking read of one message (and keep our heartbeat going)."""
        try:
            self.heartbeat()
            return self.conn.recv_match(type=types, blocking=False)
        except OSError as exc:      # the autopilot is gone: pymavlink's reconnect is refused
            if not self._link_lost:
                log.warning("MAVLink link to the autopilot lost (%s); still trying", exc)
                self._link_lost = True
            return None

    def close(self) -> None:
        """Close the link; a link the autopilot already dropped (pymavlink's TCP connection then
        has no socket left: ``port`` None) is closed already."""
        if getattr(self.conn, "port", True) is None:
            return
        try:
            self.conn.close()
        except OSError as exc:
            log.info("MAVLink link close: %s", exc)
