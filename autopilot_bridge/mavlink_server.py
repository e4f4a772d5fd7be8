"""MAVLink 2 server making a :class:`~autopilot_bridge.vehicle_interface.Vehicle` look like
an ArduCopter quadrotor to MAVProxy, QGroundControl and MAVSDK.

Shell module (pymavlink, sockets). Inputs: MAVLink from ground stations on a TCP server
socket (default 127.0.0.1:5760, several clients at once, as ArduPilot SITL) and on a UDP
socket that sends to 127.0.0.1:14550 (where ground stations listen) and answers every peer
that writes to it. Outputs: telemetry streams, protocol replies and vehicle events to every
link; calls into the Vehicle (see ``vehicle_interface``) and the ParameterStore.

Non-blocking: the owner calls :meth:`MavlinkServer.poll` from its loop with its own clock
(``now_s``, seconds, monotonic; simulated time is fine). Each poll does ``select`` with a zero
timeout, reads what is there, handles every complete frame, runs the mission protocol timers,
sends due telemetry and flushes. Telemetry timestamps are the vehicle's ``time_boot_ms``.
HEARTBEAT alone is scheduled on the wall clock (``monotonic_s``, injectable), so ground stations
keep their link while the simulated clock stands still (``telemetry.WALL_CLOCK_MSG_IDS``).

Modules: this one has the server (configuration, poll loop, dispatch of decoded messages to their
handlers, telemetry streams); ``mavlink_links`` the sockets and links, ``mavlink_framing`` the
framing, ``mavlink_params`` the parameter protocol, ``setpoints`` the decoding of setpoints and
external navigation, ``mission`` the mission protocol, ``commands`` COMMAND_LONG / COMMAND_INT.

Robustness: garbage, bad CRCs, truncated frames, unknown ids, unsigned frames while signing is
on and NaN fields are counted in :attr:`MavlinkServer.stats` and ignored; a frame is only
acted on if its CRC (and signature, when enabled) is good, it is addressed to us (target
system 0 or ours, target component 0, 1 or 190), and its fields pass the handler's checks.
``poll`` never raises: an unexpected error in a handler is logged and counted
(``handler_errors``); this is the one deliberate catch-all, at the network boundary.
"""

from __future__ import annotations

import logging
import math
import socket
import struct
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Iterable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.commands import CommandHandler, CommandRequest, MavResult
from autopilot_bridge.fence_rally_protocol import FenceRallyProtocols
from autopilot_bridge.mavlink_framing import frame_is_signed, frame_msg_id
from autopilot_bridge.mavlink_ftp import PAYLOAD_LEN, FtpServer
from autopilot_bridge.mavlink_links import Link, LinkKind, LinkTransportMixin, close_socket
from autopilot_bridge.mavlink_params import BANNER, ParamProtocolMixin
from autopilot_bridge.mission import MissionManager
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.param_pack import PackedParam, pack_params, parse_query
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.setpoints import global_position_target, local_position_target, odometry_from_message
from autopilot_bridge.signing import Signer, SigningConfig
from autopilot_bridge.system_commands import SystemCommands
from autopilot_bridge.telemetry import (
    ARDUPILOT_UNSENT_MSG_IDS,
    STREAMABLE_MSG_IDS,
    EncodeContext,
    encode,
    statustext_messages,
)
from autopilot_bridge.tlog import TlogWriter
from autopilot_bridge.vehicle_interface import (
    HomeChangedEvent,
    MavSeverity,
    MissionItemReachedEvent,
    ModeChangedEvent,
    StatusTextEvent,
    Vehicle,
    VehicleTelemetry,
)
from scenenav.core.config import check

logger = logging.getLogger(__name__)

MAV_COMP_ID_AUTOPILOT1 = 1
MAV_COMP_ID_MISSIONPLANNER = 190
# The tlog's buffer is written out at most this often (wall clock; closing writes the rest): a
# write per poll cost a system call per control tick.
TLOG_FLUSH_PERIOD_S = 0.5
PARAM_FILE = "@PARAM/param.pck"     # ArduPilot's packed parameter file (autopilot_bridge.param_pack)


STAT_KEYS = (
    "rx_bytes", "rx_msgs", "tx_msgs", "tx_bytes", "tx_dropped", "garbage_bytes", "bad_crc",
    "parse_errors", "unknown", "truncated", "dropped_unsigned", "bad_signature", "not_for_us",
    "own_echo", "ignored", "handler_errors", "setpoints_ignored", "setpoints_rejected",
    "rc_not_my_gcs", "origin_rejected",
    "vision_ignored", "vision_rejected", "param_set_refused", "param_set_clamped", "signing_setups", "tcp_clients", "tcp_refused",
    "udp_peers", "udp_refused", "socket_errors", "encode_errors",
)


@dataclass(frozen=True)
class MavlinkServerConfig:
    """Endpoints and protocol settings. Ports 0 mean "any free port" (see the server's
    ``tcp_port`` / ``udp_port``). ``tlog_path`` empty = no log."""

    tcp_enabled: bool = True
    tcp_host: str = "127.0.0.1"
    tcp_port: int = 5760
    tcp_max_clients: int = 8
    udp_enabled: bool = True
    udp_bind_host: str = "127.0.0.1"
    udp_bind_port: int = 0
    udp_target_host: str = "127.0.0.1"
    udp_target_port: int = 14550
    udp_max_peers: int = 16
    udp_peer_timeout_s: float = 30.0
    component_id: int = MAV_COMP_ID_AUTOPILOT1
    signing: SigningConfig = field(default_factory=SigningConfig)
    tlog_path: str = ""
    signing_key_path: str = ""      # SETUP_SIGNING's key is kept there ("" = not kept)
    params_per_poll: int = 25
    partial_frame_timeout_s: float = 1.0
    mission_upload_timeout_s: float = 8.0
    mission_request_retry_s: float = 1.0
    tcp_send_buffer_max_bytes: int = 1 << 20

    def __post_init__(self) -> None:
        for key in ("tcp_port", "udp_bind_port", "udp_target_port"):
            value = getattr(self, key)
            check(0 <= value <= 65535, f"mavlink.{key}", value, "a port number 0..65535")
        check(1 <= self.tcp_max_clients <= 64, "mavlink.tcp_max_clients", self.tcp_max_clients,
              "1..64")
        check(1 <= self.udp_max_peers <= 64, "mavlink.udp_max_peers", self.udp_max_peers, "1..64")
        check(self.udp_peer_timeout_s > 0, "mavlink.udp_peer_timeout_s",
              self.udp_peer_timeout_s, "a positive number of seconds")
        check(1 <= self.component_id <= 255, "mavlink.component_id", self.component_id, "1..255")
        check(self.params_per_poll >= 1, "mavlink.params_per_poll", self.params_per_poll, ">= 1")
        for key in ("partial_frame_timeout_s", "mission_upload_timeout_s",
                    "mission_request_retry_s"):
            value = getattr(self, key)
            check(value > 0, f"mavlink.{key}", value, "a positive number of seconds")
        check(self.tcp_send_buffer_max_bytes >= 4096, "mavlink.tcp_send_buffer_max_bytes",
              self.tcp_send_buffer_max_bytes, ">= 4096")


def command_handler(vehicle: Vehicle, services: MavlinkServer) -> CommandHandler:
    """Every command the server answers: ``commands`` plus the modules registered into it."""
    handler = CommandHandler(vehicle, services)
    handler.register(SystemCommands(vehicle, services).handlers())
    return handler


class MavlinkServer(LinkTransportMixin, ParamProtocolMixin):
    """ArduCopter-compatible MAVLink endpoint for a Vehicle. See the module docstring."""

    def __init__(self, vehicle: Vehicle, params: ParameterStore,
                 cfg: MavlinkServerConfig | None = None, *,
                 wallclock_s: Callable[[], float] = time.time,
                 monotonic_s: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg if cfg is not None else MavlinkServerConfig()
        self.vehicle = vehicle
        self.params = params
        self.stats: dict[str, int] = {k: 0 for k in STAT_KEYS}
        self.system_id = params.get_int("SYSID_THISMAV")
        self.component_id = self.cfg.component_id
        self.last_gcs_heartbeat_s: float | None = None
        self.last_any_gcs_heartbeat_s: float | None = None
        self._wallclock_s = wallclock_s
        self._monotonic_s = monotonic_s
        self._signer = Signer(self.cfg.signing, wallclock_s, self.cfg.signing_key_path)
        self._links: list[Link] = []
        self._udp_peers: dict[tuple[str, int], Link] = {}
        self._next_link_id = 0
        self._statustext_id = 0
        self._closed = False
        self._reboot_pending = False
        self._param_changes: deque[tuple[str, float]] = deque()
        self._error_counts: dict[str, int] = {}
        self._statustexts: deque[tuple[MavSeverity, str]] = deque()
        self._tcp_listener: socket.socket | None = None
        self._udp: socket.socket | None = None
        self._udp_target: Link | None = None
        self._tlog = TlogWriter(self.cfg.tlog_path, wallclock_s) if self.cfg.tlog_path else None
        self._tlog_flush_due_s = -math.inf
        self.missions = MissionManager(vehicle, self,
                                       upload_timeout_s=self.cfg.mission_upload_timeout_s,
                                       request_retry_s=self.cfg.mission_request_retry_s)
        self.commands = command_handler(vehicle, self)
        self.fence_rally = FenceRallyProtocols(vehicle, self,
                                               upload_timeout_s=self.cfg.mission_upload_timeout_s,
                                               request_retry_s=self.cfg.mission_request_retry_s)
        self.ftp = FtpServer(self._ftp_file)
        self._open_sockets()
        params.add_observer(self._on_param_changed)
        logger.info("MAVLink server sysid %d compid %d: tcp %s, udp %s -> %s:%d",
                    self.system_id, self.component_id,
                    f"{self.cfg.tcp_host}:{self.tcp_port}" if self._tcp_listener else "off",
                    f"{self.cfg.udp_bind_host}:{self.udp_port}" if self._udp else "off",
                    self.cfg.udp_target_host, self.cfg.udp_target_port)

    # ----------------------------------------------------------------- lifecycle


    def close(self) -> None:
        """Close every socket and the tlog. Idempotent."""
        if self._closed:
            return
        self._closed = True
        for link in list(self._links):
            self._flush(link)
            if link.sock is not None:
                close_socket(link.sock)
        self._links.clear()
        self._udp_peers.clear()
        for sock in (self._tcp_listener, self._udp):
            if sock is not None:
                close_socket(sock)
        self._tcp_listener = self._udp = None
        if self._tlog is not None:
            self._tlog.close()
        self.params.remove_observer(self._on_param_changed)

    def __enter__(self) -> MavlinkServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- poll
    def poll(self, now_s: float) -> None:
        """Process input, events, timers and due telemetry. Never raises."""
        if self._closed:
            return
        try:
            self._poll(now_s)
        except Exception:  # noqa: BLE001 - network boundary: log, count, keep serving
            self.stats["handler_errors"] += 1
            logger.exception("MAVLink server poll failed")

    def _poll(self, now_s: float) -> None:
        readable = self._select_readable()
        if self._tcp_listener is not None and self._tcp_listener in readable:
            self._accept()
        if self._udp is not None and self._udp in readable:
            self._read_udp(now_s)
        for link in list(self._links):
            if link.kind == LinkKind.TCP and link.sock in readable:
                self._read_tcp(link)
        for link in list(self._links):
            for frame in link.parser.frames(now_s):
                self._guarded(self._handle_frame, link, frame, now_s)
        self._guarded(self._reboot)
        self._guarded(self._flush_param_changes)
        self._guarded(self._drain_vehicle_events)
        self._guarded(self._flush_statustexts)
        self._guarded(self.missions.update, now_s)
        self._guarded(self.fence_rally.update, now_s)
        self._send_param_batches()
        self._guarded(self._send_streams, now_s)
        self._expire_udp_peers(now_s)
        for link in list(self._links):
            self._signer.refresh_timestamp(link.mav)
            self._flush(link)
        if self._tlog is not None:
            wall_s = self._monotonic_s()
            if wall_s >= self._tlog_flush_due_s:
                self._tlog_flush_due_s = wall_s + TLOG_FLUSH_PERIOD_S
                self._tlog.flush()

    def _guarded(self, fn: Callable[..., object], *args: object) -> None:
        try:
            fn(*args)
        except Exception:  # noqa: BLE001 - see module docstring
            self.stats["handler_errors"] += 1
            name = getattr(fn, "__name__", repr(fn))
            count = self._error_counts.get(name, 0) + 1
            self._error_counts[name] = count
            if count == 1 or count % 1000 == 0:  # a persistent fault must not flood the log
                logger.exception("MAVLink handler %s failed (%d times)", name, count)



    # ----------------------------------------------------------------- output


    def statustext(self, severity: MavSeverity, text: str) -> None:
        """Send a STATUSTEXT to every link (chunked when longer than 50 characters)."""
        self._statustext_id = (self._statustext_id % 0xFFFF) + 1
        logger.info("STATUSTEXT [%d] %s", int(severity), text)
        for msg in statustext_messages(int(severity), text, self._statustext_id):
            self.broadcast(msg)

    def send_statustext(self, severity: MavSeverity, text: str) -> None:
        """Queue a STATUSTEXT for every link; safe from any thread (sent by the next poll).
        The flight core can equally return a ``StatusTextEvent`` from ``drain_events``."""
        self._statustexts.append((severity, text))

    def _flush_statustexts(self) -> None:
        while self._statustexts:
            severity, text = self._statustexts.popleft()
            self.statustext(severity, text)

    def telemetry(self) -> VehicleTelemetry:
        return self.vehicle.telemetry()

    def _encode_context(self) -> EncodeContext:
        return EncodeContext(mission_item_count=len(self.missions.items),
                             battery_monitor=self.params.get_int("BATT_MONITOR"),
                             unix_time_us=int(self._wallclock_s() * 1e6))

    def _send_encoded(self, links: Iterable[Link], msg_id: int,
                      tel: VehicleTelemetry | None = None) -> None:
        tel = tel if tel is not None else self.vehicle.telemetry()
        msg = encode(msg_id, tel, self._encode_context())
        if msg is None:
            return
        for link in links:
            self.send(link, msg)

    def send_mission_current(self, link: object) -> None:
        if isinstance(link, Link):
            self._send_encoded([link], mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT)

    def _send_streams(self, now_s: float) -> None:
        wall_s = self._monotonic_s()
        due = [(link, link.scheduler.due(now_s, wall_s)) for link in self._links]
        if not any(ids for _, ids in due):
            return
        tel = self.vehicle.telemetry()
        ctx = self._encode_context()
        cache: dict[int, mavlink2.MAVLink_message | None] = {}
        for link, ids in due:
            for msg_id in ids:
                if msg_id not in cache:
                    cache[msg_id] = encode(msg_id, tel, ctx)
                msg = cache[msg_id]
                if msg is not None:
                    self.send(link, msg)

    def _drain_vehicle_events(self) -> None:
        for event in self.vehicle.drain_events():
            if isinstance(event, StatusTextEvent):
                self.statustext(event.severity, event.text)
            elif isinstance(event, MissionItemReachedEvent):
                self.broadcast(mavlink2.MAVLink_mission_item_reached_message(
                    max(0, min(int(event.seq), 0xFFFF))))
            elif isinstance(event, ModeChangedEvent):
                self._send_encoded(self._links, mavlink2.MAVLINK_MSG_ID_HEARTBEAT)
            elif isinstance(event, HomeChangedEvent):
                self._send_encoded(self._links, mavlink2.MAVLINK_MSG_ID_HOME_POSITION)
                self._send_encoded(self._links, mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)
            else:
                logger.warning("unknown vehicle event %r", event)

    # ----------------------------------------------------------------- services for commands
    def can_send(self, msg_id: int) -> bool:
        return msg_id in STREAMABLE_MSG_IDS

    def ardupilot_has(self, msg_id: int) -> bool:
        return msg_id in ARDUPILOT_UNSENT_MSG_IDS

    def set_message_interval(self, link: object, msg_id: int, interval_us: float) -> bool:
        return isinstance(link, Link) and link.scheduler.set_interval_us(msg_id, interval_us)

    def message_interval_us(self, link: object, msg_id: int) -> int:
        return link.scheduler.interval_us(msg_id) if isinstance(link, Link) else 0

    def mission_item_count(self) -> int:
        return len(self.missions.items)

    def set_mission_current(self, seq: int) -> bool:
        return self.missions.set_current(seq, None)

    def erase_stored_params(self) -> None:
        self.params.erase_persisted()

    def request_reboot(self) -> None:
        """PREFLIGHT_REBOOT_SHUTDOWN accepted: reboot in this poll, after the ACK went out."""
        self._reboot_pending = True

    def _reboot(self) -> None:
        """The vehicle starts again; it gets the stored mission, fence and rally as ArduPilot reads
        them from its storage at boot, and the ground stations the boot banner."""
        if not self._reboot_pending:
            return
        self._reboot_pending = False
        logger.info("rebooting the vehicle (PREFLIGHT_REBOOT_SHUTDOWN)")
        self.vehicle.reboot()
        self.vehicle.mission_changed(self.missions.items)
        self.vehicle.fence_changed(self.fence_rally.fence.items)
        self.vehicle.rally_changed(self.fence_rally.rally.items)
        for text in BANNER:
            self.statustext(MavSeverity.INFO, text)

    # ----------------------------------------------------------------- input
    def _handle_frame(self, link: Link, frame: bytes, now_s: float) -> None:
        msg_id = frame_msg_id(frame)
        if (self._signer.enabled and not frame_is_signed(frame)
                and not self._signer.accepts_unsigned(msg_id)):
            self.stats["dropped_unsigned"] += 1
            return
        try:
            msg = link.mav.decode(bytearray(frame))
        except mavlink2.MAVError as exc:
            key = "bad_signature" if "signature" in str(exc).lower() else "parse_errors"
            self.stats[key] += 1
            return
        except (struct.error, ValueError, TypeError, IndexError, UnicodeDecodeError):
            self.stats["parse_errors"] += 1
            return
        self.stats["rx_msgs"] += 1
        if self._tlog is not None:
            self._tlog.write(frame)
        link.last_rx_s = now_s
        if msg.get_srcSystem() == self.system_id and msg.get_srcComponent() == self.component_id:
            self.stats["own_echo"] += 1
            return
        if not self._addressed_to_us(msg):
            self.stats["not_for_us"] += 1
            return
        self._dispatch(msg, link, now_s)

    def _addressed_to_us(self, msg: mavlink2.MAVLink_message) -> bool:
        target_system = getattr(msg, "target_system", None)
        if target_system is not None and target_system not in (0, self.system_id):
            return False
        target_component = getattr(msg, "target_component", None)
        return target_component is None or target_component in (
            0, self.component_id, MAV_COMP_ID_MISSIONPLANNER)

    def _dispatch(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        kind = msg.get_type()
        handler = self._HANDLERS.get(kind)
        if handler is not None:
            handler(self, msg, link, now_s)
        elif kind.startswith("MISSION_"):
            if self.fence_rally.handle(msg, link, now_s):
                return
            if not self.missions.handle(msg, link, now_s):
                self.stats["ignored"] += 1
        else:
            self.stats["ignored"] += 1

    def _on_heartbeat(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        if msg.type == mavlink2.MAV_TYPE_GCS:
            self.last_any_gcs_heartbeat_s = now_s
        if msg.get_srcSystem() == self.params.get_int("SYSID_MYGCS"):
            self.last_gcs_heartbeat_s = now_s

    def _on_timesync(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        if msg.tc1 == 0:
            self.send(link, mavlink2.MAVLink_timesync_message(int(now_s * 1e9), msg.ts1))

    def _on_setup_signing(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        """Install the key on every link (``signing``: ArduPilot's handle_setup_signing)."""
        if self.vehicle.telemetry().armed:
            self.statustext(MavSeverity.WARNING, "ERROR: Won't setup signing when armed")
            return
        key = bytes(msg.secret_key)
        self._signer.install(key, int(msg.initial_timestamp))
        for other in self._links:
            self._signer.configure(other.mav, other.mav.signing.link_id)
        logger.info("SETUP_SIGNING from %d: signing %s", msg.get_srcSystem(),
                    "on" if self._signer.enabled else "off")
        self.stats["signing_setups"] += 1

    def _on_file_transfer_protocol(self, msg: mavlink2.MAVLink_message, link: Link,
                                   now_s: float) -> None:
        """MAVLink FTP as ArduPilot answers it (``autopilot_bridge.mavlink_ftp``): serves
        ``@PARAM/param.pck``, NAKs every other path with FileNotFound. Sessions are timed on the
        wall clock (a frozen simulated clock must not keep a session alive)."""
        client = (link, msg.get_srcSystem(), msg.get_srcComponent())
        for payload in self.ftp.handle(client, bytes(msg.payload), self._monotonic_s()):
            self.send(link, mavlink2.MAVLink_file_transfer_protocol_message(
                0, msg.get_srcSystem(), msg.get_srcComponent(), list(payload[:PAYLOAD_LEN])))

    def _ftp_file(self, path: str) -> bytes | None:
        name, _, query = path.partition("?")
        if name != PARAM_FILE:
            return None
        options = parse_query(query)
        if options is None:
            return None
        params = self.params
        return pack_params((PackedParam(spec.name, spec.ptype, value, params.default_at(i))
                            for i, (spec, value) in enumerate(
                                params.by_index(k) for k in range(params.count))), options)

    def _on_request_data_stream(self, msg: mavlink2.MAVLink_message, link: Link,
                                now_s: float) -> None:
        if msg.start_stop not in (0, 1):
            return
        rate = float(msg.req_message_rate) if msg.start_stop == 1 else 0.0
        link.scheduler.set_stream_rate(int(msg.req_stream_id), rate)



    # ----------------------------------------------------------------- commands
    def _on_command(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        req = CommandRequest.from_message(msg)
        result = self.commands.handle(req, link)
        self._ack(link, msg, req.command, result.result)
        if result.reply is not None:
            self.send(link, result.reply)
        for msg_id in result.then_send:
            self._send_encoded([link], msg_id)

    def _on_set_mode(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        result = self.commands.set_mode_common(float(msg.base_mode), float(msg.custom_mode))
        self._ack(link, msg, mavlink2.MAV_CMD_DO_SET_MODE, result)

    def _ack(self, link: Link, msg: mavlink2.MAVLink_message, command: int,
             result: MavResult) -> None:
        self.send(link, mavlink2.MAVLink_command_ack_message(
            command & 0xFFFF, int(result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

    # ----------------------------------------------------------------- pilot input
    def _from_my_gcs(self, msg: mavlink2.MAVLink_message) -> bool:
        """ArduPilot takes RC overrides and MANUAL_CONTROL only from SYSID_MYGCS."""
        if msg.get_srcSystem() == self.params.get_int("SYSID_MYGCS"):
            return True
        self.stats["rc_not_my_gcs"] += 1
        return False

    def _on_rc_channels_override(self, msg: mavlink2.MAVLink_message, link: Link,
                                 now_s: float) -> None:
        if self._from_my_gcs(msg):
            self.vehicle.rc_channels_override(tuple(
                int(getattr(msg, f"chan{i}_raw", 0)) for i in range(1, 19)))

    def _on_manual_control(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        if msg.target in (0, self.system_id) and self._from_my_gcs(msg):
            self.vehicle.manual_control(float(msg.x), float(msg.y), float(msg.z), float(msg.r))

    # ----------------------------------------------------------------- guided / external nav
    def _guided(self) -> bool:
        return self.vehicle.telemetry().mode == CopterMode.GUIDED

    def _on_set_position_target_local_ned(self, msg: mavlink2.MAVLink_message, link: Link,
                                          now_s: float) -> None:
        if not self._guided():
            self.stats["setpoints_ignored"] += 1
            return
        target = local_position_target(msg)
        if target is None:
            self.stats["setpoints_rejected"] += 1
            return
        self.vehicle.set_position_target_local_ned(target)

    def _on_set_position_target_global_int(self, msg: mavlink2.MAVLink_message, link: Link,
                                           now_s: float) -> None:
        if not self._guided():
            self.stats["setpoints_ignored"] += 1
            return
        target = global_position_target(msg)
        if target is None:
            self.stats["setpoints_rejected"] += 1
            return
        self.vehicle.set_position_target_global_int(target)

    def _on_vision_position_estimate(self, msg: mavlink2.MAVLink_message, link: Link,
                                     now_s: float) -> None:
        if self.params.get_int("VISO_TYPE") == 0:
            self.stats["vision_ignored"] += 1
            return
        pose = (msg.x, msg.y, msg.z, msg.roll, msg.pitch, msg.yaw)
        if not all(math.isfinite(v) for v in pose):
            self.stats["vision_rejected"] += 1
            return
        self.vehicle.vision_position_estimate(
            int(msg.usec), msg.x, msg.y, msg.z, msg.roll, msg.pitch, msg.yaw,
            tuple(float(c) for c in msg.covariance), int(msg.reset_counter))

    def _on_odometry(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        if self.params.get_int("VISO_TYPE") == 0:
            self.stats["vision_ignored"] += 1
            return
        odom = odometry_from_message(msg)
        if odom is None:
            self.stats["vision_rejected"] += 1
            return
        self.vehicle.odometry(odom)

    def _on_set_gps_global_origin(self, msg: mavlink2.MAVLink_message, link: Link, now_s: float) -> None:
        """As ``GCS_MAVLINK::handle_set_gps_global_origin``: a bad lat/lon is dropped silently; the
        vehicle takes the origin while it has none (altitude mm). Answered with GPS_GLOBAL_ORIGIN
        once an origin is set (differs: ArduPilot sends it only when the origin changed)."""
        if not (abs(msg.latitude) <= 900_000_000 and abs(msg.longitude) <= 1_800_000_000):
            self.stats["origin_rejected"] += 1
            return
        self.vehicle.set_gps_global_origin(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
        self._send_encoded([link], mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)

    _HANDLERS: dict[str, Callable[[MavlinkServer, mavlink2.MAVLink_message, Link, float], None]] = {
        "HEARTBEAT": _on_heartbeat,
        "PARAM_REQUEST_LIST": ParamProtocolMixin._on_param_request_list,
        "PARAM_REQUEST_READ": ParamProtocolMixin._on_param_request_read,
        "PARAM_SET": ParamProtocolMixin._on_param_set,
        "COMMAND_LONG": _on_command,
        "COMMAND_INT": _on_command,
        "SET_MODE": _on_set_mode,
        "REQUEST_DATA_STREAM": _on_request_data_stream,
        "SET_POSITION_TARGET_LOCAL_NED": _on_set_position_target_local_ned,
        "SET_POSITION_TARGET_GLOBAL_INT": _on_set_position_target_global_int,
        "RC_CHANNELS_OVERRIDE": _on_rc_channels_override,
        "MANUAL_CONTROL": _on_manual_control,
        "VISION_POSITION_ESTIMATE": _on_vision_position_estimate,
        "ODOMETRY": _on_odometry,
        "TIMESYNC": _on_timesync,
        "SETUP_SIGNING": _on_setup_signing,
        "FILE_TRANSFER_PROTOCOL": _on_file_transfer_protocol,
        "SET_GPS_GLOBAL_ORIGIN": _on_set_gps_global_origin,
    }
