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

Robustness: garbage, bad CRCs, truncated frames, unknown ids, unsigned frames while signing is
on and NaN fields are counted in :attr:`MavlinkServer.stats` and ignored; a frame is only
acted on if its CRC (and signature, when enabled) is good, it is addressed to us (target
system 0 or ours, target component 0, 1 or 190), and its fields pass the handler's checks.
``poll`` never raises: an unexpected error in a handler is logged and counted
(``handler_errors``); this is the one deliberate catch-all, at the network boundary.
"""

from __future__ import annotations

import enum
import errno
import logging
import math
import select
import socket
import struct
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Iterable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.commands import CommandHandler, CommandRequest, MavResult
from autopilot_bridge.mission import MissionManager
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.signing import Signer, SigningConfig
from autopilot_bridge.telemetry import (
    STREAMABLE_MSG_IDS,
    EncodeContext,
    TelemetryScheduler,
    encode,
    statustext_messages,
)
from autopilot_bridge.tlog import TlogWriter
from autopilot_bridge.vehicle_interface import (
    ACCEL_IGNORE,
    POSITION_IGNORE,
    VELOCITY_IGNORE,
    AltFrame,
    GlobalPositionTarget,
    HomeChangedEvent,
    LocalPositionTarget,
    MavFrame,
    MavSeverity,
    MissionItemReachedEvent,
    ModeChangedEvent,
    Odometry,
    PositionTargetTypeMask,
    StatusTextEvent,
    Vehicle,
    VehicleTelemetry,
    setpoint_kind,
)
from scenenav.core.config import check
from scenenav.core.errors import UserError

logger = logging.getLogger(__name__)

STX_V1 = 0xFE
STX_V2 = 0xFD
V1_HEADER_LEN = 6
V2_HEADER_LEN = 10
CRC_LEN = 2
SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
MAV_COMP_ID_AUTOPILOT1 = 1
MAV_COMP_ID_MISSIONPLANNER = 190
MAX_SETPOINT_VEL_ACC = 1000.0      # ArduCopter sane_vel_or_acc_vector limit (m/s, m/s^2)
LOCATION_ALT_MAX_M = 83000.0
# A local (NED, metres) position target beyond this is no place on Earth (half its circumference);
# rejected like an out-of-range latitude in a global target.
MAX_LOCAL_TARGET_XY_M = 2.0e7
# MAVLink FTP header: seq u16, session, opcode, size, req_opcode, burst_complete, padding, offset
FTP_HEADER = struct.Struct("<HBBBBBBI")
FTP_ERR_UNKNOWN_COMMAND = 7


class FtpOpcode(enum.IntEnum):
    ACK = 128
    NAK = 129


BANNER = ("ArduCopter V4.5.7 (scenenav emulator)", "Frame: QUAD/X")

STAT_KEYS = (
    "rx_bytes", "rx_msgs", "tx_msgs", "tx_bytes", "tx_dropped", "garbage_bytes", "bad_crc",
    "parse_errors", "unknown", "truncated", "dropped_unsigned", "bad_signature", "not_for_us",
    "own_echo", "ignored", "handler_errors", "setpoints_ignored", "setpoints_rejected",
    "vision_ignored", "vision_rejected", "param_set_refused", "tcp_clients", "tcp_refused",
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


# --------------------------------------------------------------------------- framing


class FrameParser:
    """Splits a byte stream into MAVLink 1/2 frames whose CRC is good.

    A candidate start byte whose frame fails (unknown id, bad CRC, bad flags) costs one byte:
    scanning resumes at the next byte, so a valid frame hidden behind garbage is still found.
    A candidate that stays incomplete for ``partial_timeout_s`` of the caller's clock is
    skipped the same way (``truncated``).
    """

    MAX_BUFFER = 1 << 20

    def __init__(self, stats: dict[str, int], partial_timeout_s: float) -> None:
        self._buf = bytearray()
        self._stats = stats
        self._partial_timeout_s = partial_timeout_s
        self._stall_since_s: float | None = None

    def feed(self, data: bytes) -> None:
        self._buf += data
        excess = len(self._buf) - self.MAX_BUFFER
        if excess > 0:
            del self._buf[:excess]
            self._stats["garbage_bytes"] += excess

    def frames(self, now_s: float) -> list[bytes]:
        out: list[bytes] = []
        while True:
            consumed = self._scan(out)
            if not self._buf:
                self._stall_since_s = None
                return out
            if consumed or self._stall_since_s is None:
                self._stall_since_s = now_s
                return out
            if now_s - self._stall_since_s < self._partial_timeout_s:
                return out
            # a candidate frame never completed: skip its start byte and rescan
            self._stats["truncated"] += 1
            del self._buf[:1]
            self._stall_since_s = now_s

    def _scan(self, out: list[bytes]) -> int:
        buf = self._buf
        n = len(buf)
        i = 0
        stats = self._stats
        while i < n:
            j1 = buf.find(STX_V1, i)
            j2 = buf.find(STX_V2, i)
            if j1 < 0 and j2 < 0:
                stats["garbage_bytes"] += n - i
                i = n
                break
            j = j2 if j1 < 0 else j1 if j2 < 0 else min(j1, j2)
            stats["garbage_bytes"] += j - i
            i = j
            avail = n - i
            if buf[i] == STX_V2:
                if avail < V2_HEADER_LEN:
                    break
                plen, incompat = buf[i + 1], buf[i + 2]
                if incompat & ~IFLAG_SIGNED:
                    stats["parse_errors"] += 1
                    i += 1
                    continue
                hlen = V2_HEADER_LEN
                flen = hlen + plen + CRC_LEN + (SIGNATURE_LEN if incompat & IFLAG_SIGNED else 0)
                msg_id = buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)
            else:
                if avail < V1_HEADER_LEN:
                    break
                plen = buf[i + 1]
                hlen = V1_HEADER_LEN
                flen = hlen + plen + CRC_LEN
                msg_id = buf[i + 5]
            if avail < flen:
                break
            msg_cls = mavlink2.mavlink_map.get(msg_id)
            if msg_cls is None:
                stats["unknown"] += 1
                i += 1
                continue
            crc = mavlink2.x25crc(bytes(buf[i + 1:i + hlen + plen]))
            crc.accumulate(bytes((msg_cls.crc_extra,)))
            wire_crc = buf[i + hlen + plen] | (buf[i + hlen + plen + 1] << 8)
            if crc.crc != wire_crc:
                stats["bad_crc"] += 1
                i += 1
                continue
            out.append(bytes(buf[i:i + flen]))
            i += flen
        del buf[:i]
        return i


def frame_msg_id(frame: bytes) -> int:
    if frame[0] == STX_V2:
        return frame[7] | (frame[8] << 8) | (frame[9] << 16)
    return frame[5]


def frame_is_signed(frame: bytes) -> bool:
    return frame[0] == STX_V2 and bool(frame[2] & IFLAG_SIGNED)


# --------------------------------------------------------------------------- links


class LinkKind(enum.Enum):
    TCP = "tcp"
    UDP_TARGET = "udp-target"
    UDP_PEER = "udp-peer"


class Link:
    """One MAVLink peer: its parser, encoder state (sequence, signing), stream rates and queues."""

    def __init__(self, kind: LinkKind, name: str, mav: mavlink2.MAVLink,
                 scheduler: TelemetryScheduler, parser: FrameParser,
                 sock: socket.socket | None = None,
                 addr: tuple[str, int] | None = None) -> None:
        self.kind = kind
        self.name = name
        self.mav = mav
        self.scheduler = scheduler
        self.parser = parser
        self.sock = sock
        self.addr = addr
        self.out = bytearray()
        self.param_queue: deque[int] = deque()
        self.last_rx_s: float | None = None
        self.closed = False

    def __repr__(self) -> str:
        return f"Link({self.name})"


# --------------------------------------------------------------------------- server


class MavlinkServer:
    """ArduCopter-compatible MAVLink endpoint for a Vehicle. See the module docstring."""

    def __init__(self, vehicle: Vehicle, params: ParameterStore,
                 cfg: MavlinkServerConfig | None = None, *,
                 wallclock_s: Callable[[], float] = time.time) -> None:
        self.cfg = cfg if cfg is not None else MavlinkServerConfig()
        self.vehicle = vehicle
        self.params = params
        self.stats: dict[str, int] = {k: 0 for k in STAT_KEYS}
        self.system_id = params.get_int("SYSID_THISMAV")
        self.component_id = self.cfg.component_id
        self.last_gcs_heartbeat_s: float | None = None
        self.last_any_gcs_heartbeat_s: float | None = None
        self._wallclock_s = wallclock_s
        self._signer = Signer(self.cfg.signing, wallclock_s)
        self._links: list[Link] = []
        self._udp_peers: dict[tuple[str, int], Link] = {}
        self._next_link_id = 0
        self._statustext_id = 0
        self._closed = False
        self._param_changes: deque[tuple[str, float]] = deque()
        self._error_counts: dict[str, int] = {}
        self._statustexts: deque[tuple[MavSeverity, str]] = deque()
        self._tcp_listener: socket.socket | None = None
        self._udp: socket.socket | None = None
        self._udp_target: Link | None = None
        self._tlog = TlogWriter(self.cfg.tlog_path, wallclock_s) if self.cfg.tlog_path else None
        self.missions = MissionManager(vehicle, self,
                                       upload_timeout_s=self.cfg.mission_upload_timeout_s,
                                       request_retry_s=self.cfg.mission_request_retry_s)
        self.commands = CommandHandler(vehicle, self)
        self._open_sockets()
        params.add_observer(self._on_param_changed)
        logger.info("MAVLink server sysid %d compid %d: tcp %s, udp %s -> %s:%d",
                    self.system_id, self.component_id,
                    f"{self.cfg.tcp_host}:{self.tcp_port}" if self._tcp_listener else "off",
                    f"{self.cfg.udp_bind_host}:{self.udp_port}" if self._udp else "off",
                    self.cfg.udp_target_host, self.cfg.udp_target_port)

    # ----------------------------------------------------------------- lifecycle
    def _open_sockets(self) -> None:
        cfg = self.cfg
        try:
            if cfg.tcp_enabled:
                lst = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                lst.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                lst.bind((cfg.tcp_host, cfg.tcp_port))
                lst.listen(cfg.tcp_max_clients)
                lst.setblocking(False)
                self._tcp_listener = lst
            if cfg.udp_enabled:
                udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                udp.bind((cfg.udp_bind_host, cfg.udp_bind_port))
                udp.setblocking(False)
                self._udp = udp
                target = (cfg.udp_target_host, cfg.udp_target_port)
                self._udp_target = self._new_link(LinkKind.UDP_TARGET,
                                                   f"udp:{target[0]}:{target[1]}", addr=target)
                self._udp_peers[target] = self._udp_target
        except OSError as exc:
            self.close()
            raise UserError(f"mavlink: cannot open endpoint (tcp {cfg.tcp_host}:{cfg.tcp_port}, "
                            f"udp {cfg.udp_bind_host}:{cfg.udp_bind_port}): {exc.strerror or exc}"
                            ) from None

    @property
    def tcp_port(self) -> int | None:
        return self._tcp_listener.getsockname()[1] if self._tcp_listener else None

    @property
    def udp_port(self) -> int | None:
        return self._udp.getsockname()[1] if self._udp else None

    @property
    def tcp_client_count(self) -> int:
        return sum(1 for link in self._links if link.kind == LinkKind.TCP)

    @property
    def links(self) -> tuple[Link, ...]:
        return tuple(self._links)

    def close(self) -> None:
        """Close every socket and the tlog. Idempotent."""
        if self._closed:
            return
        self._closed = True
        for link in list(self._links):
            self._flush(link)
            if link.sock is not None:
                _close_socket(link.sock)
        self._links.clear()
        self._udp_peers.clear()
        for sock in (self._tcp_listener, self._udp):
            if sock is not None:
                _close_socket(sock)
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
        self._guarded(self._flush_param_changes)
        self._guarded(self._drain_vehicle_events)
        self._guarded(self._flush_statustexts)
        self._guarded(self.missions.update, now_s)
        self._send_param_batches()
        self._guarded(self._send_streams, now_s)
        self._expire_udp_peers(now_s)
        for link in list(self._links):
            self._signer.refresh_timestamp(link.mav)
            self._flush(link)
        if self._tlog is not None:
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

    # ----------------------------------------------------------------- sockets
    def _select_readable(self) -> set[socket.socket]:
        socks = [s for s in (self._tcp_listener, self._udp) if s is not None]
        socks += [lk.sock for lk in self._links if lk.kind == LinkKind.TCP and lk.sock is not None]
        if not socks:
            return set()
        try:
            readable, _, _ = select.select(socks, [], [], 0)
        except (OSError, ValueError):
            self.stats["socket_errors"] += 1
            return set(socks)  # let the individual reads find the broken one
        return set(readable)

    def _accept(self) -> None:
        assert self._tcp_listener is not None
        for _ in range(self.cfg.tcp_max_clients):
            try:
                sock, addr = self._tcp_listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.stats["socket_errors"] += 1
                return
            if self.tcp_client_count >= self.cfg.tcp_max_clients:
                self.stats["tcp_refused"] += 1
                logger.warning("MAVLink TCP client %s refused: %d clients already", addr,
                               self.cfg.tcp_max_clients)
                _close_socket(sock)
                continue
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._new_link(LinkKind.TCP, f"tcp:{addr[0]}:{addr[1]}", sock=sock)
            self.stats["tcp_clients"] += 1
            logger.info("MAVLink TCP client connected from %s:%d", addr[0], addr[1])

    def _new_link(self, kind: LinkKind, name: str, sock: socket.socket | None = None,
                  addr: tuple[str, int] | None = None) -> Link:
        mav = mavlink2.MAVLink(None, srcSystem=self.system_id, srcComponent=self.component_id)
        self._signer.configure(mav, self._next_link_id)
        self._next_link_id = (self._next_link_id + 1) & 0xFF
        link = Link(kind, name, mav, TelemetryScheduler(),
                    FrameParser(self.stats, self.cfg.partial_frame_timeout_s), sock, addr)
        self._links.append(link)
        return link

    def _close_link(self, link: Link, why: str) -> None:
        if link.closed:
            return
        link.closed = True
        logger.info("MAVLink link %s closed: %s", link.name, why)
        if link.sock is not None:
            _close_socket(link.sock)
        if link in self._links:
            self._links.remove(link)
        if link.addr is not None and self._udp_peers.get(link.addr) is link:
            del self._udp_peers[link.addr]
        self.missions.link_closed(link)

    def _read_tcp(self, link: Link) -> None:
        assert link.sock is not None
        for _ in range(8):
            try:
                data = link.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self._close_link(link, f"recv failed: {exc}")
                return
            if not data:
                self._close_link(link, "peer closed")
                return
            self.stats["rx_bytes"] += len(data)
            link.parser.feed(data)
            if len(data) < 65536:
                return

    def _read_udp(self, now_s: float) -> None:
        assert self._udp is not None
        for _ in range(512):
            try:
                data, addr = self._udp.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                # e.g. ECONNREFUSED reported for an earlier send to a closed port
                if exc.errno not in (errno.ECONNREFUSED, errno.ECONNRESET):
                    self.stats["socket_errors"] += 1
                continue
            self.stats["rx_bytes"] += len(data)
            key = (addr[0], addr[1])
            link = self._udp_peers.get(key)
            if link is None:
                peers = sum(1 for lk in self._links if lk.kind == LinkKind.UDP_PEER)
                if peers >= self.cfg.udp_max_peers:
                    self.stats["udp_refused"] += 1
                    continue
                link = self._new_link(LinkKind.UDP_PEER, f"udp-peer:{key[0]}:{key[1]}", addr=key)
                self._udp_peers[key] = link
                self.stats["udp_peers"] += 1
                logger.info("MAVLink UDP peer %s:%d", key[0], key[1])
            link.last_rx_s = now_s
            link.parser.feed(data)

    def _expire_udp_peers(self, now_s: float) -> None:
        for link in list(self._links):
            if (link.kind == LinkKind.UDP_PEER and link.last_rx_s is not None
                    and now_s - link.last_rx_s > self.cfg.udp_peer_timeout_s):
                self._close_link(link, "UDP peer silent")

    def _flush(self, link: Link) -> None:
        if link.kind != LinkKind.TCP or not link.out or link.sock is None or link.closed:
            return
        while link.out:
            try:
                sent = link.sock.send(link.out[:65536])
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self._close_link(link, f"send failed: {exc}")
                return
            del link.out[:sent]

    # ----------------------------------------------------------------- output
    def send(self, link: object, msg: mavlink2.MAVLink_message) -> None:
        """Send one message on one link (MissionOutbox / internal use)."""
        if not isinstance(link, Link) or link.closed:
            return
        try:
            buf = msg.pack(link.mav)
        except (struct.error, ValueError, TypeError, OverflowError):
            self.stats["encode_errors"] += 1
            logger.exception("cannot encode %s", msg.get_type())
            return
        link.mav.seq = (link.mav.seq + 1) % 256
        if link.kind == LinkKind.TCP:
            if len(link.out) + len(buf) > self.cfg.tcp_send_buffer_max_bytes:
                self.stats["tx_dropped"] += 1
                return
            link.out += buf
        else:
            if self._udp is None or link.addr is None:
                return
            try:
                self._udp.sendto(buf, link.addr)
            except OSError:  # full buffer, unreachable peer ...: UDP may lose packets
                self.stats["tx_dropped"] += 1
                return
        self.stats["tx_msgs"] += 1
        self.stats["tx_bytes"] += len(buf)
        if self._tlog is not None:
            self._tlog.write(buf)

    def broadcast(self, msg: mavlink2.MAVLink_message) -> None:
        for link in list(self._links):
            self.send(link, msg)

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
                             battery_monitor=self.params.get_int("BATT_MONITOR"))

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
        due = [(link, link.scheduler.due(now_s)) for link in self._links]
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
            else:
                logger.warning("unknown vehicle event %r", event)

    # ----------------------------------------------------------------- services for commands
    def can_send(self, msg_id: int) -> bool:
        return msg_id in STREAMABLE_MSG_IDS

    def set_message_interval(self, link: object, msg_id: int, interval_us: float) -> bool:
        return isinstance(link, Link) and link.scheduler.set_interval_us(msg_id, interval_us)

    def message_interval_us(self, link: object, msg_id: int) -> int:
        return link.scheduler.interval_us(msg_id) if isinstance(link, Link) else 0

    def mission_item_count(self) -> int:
        return len(self.missions.items)

    def set_mission_current(self, seq: int) -> bool:
        return self.missions.set_current(seq, None)

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
        logger.warning("SETUP_SIGNING from %d refused: the key comes from the configuration",
                       msg.get_srcSystem())
        self.statustext(MavSeverity.WARNING, "SETUP_SIGNING refused: key is set in config")

    def _on_file_transfer_protocol(self, msg: mavlink2.MAVLink_message, link: Link,
                                   now_s: float) -> None:
        """MAVLink FTP is not implemented: NAK every request with "unknown command" so clients
        (MAVProxy tries FTP for parameters first) fall back at once instead of timing out."""
        payload = bytes(msg.payload)
        if len(payload) < FTP_HEADER.size:
            return
        seq, session, opcode, _size, _req, _burst, _pad, _offset = FTP_HEADER.unpack_from(payload)
        if opcode in (FtpOpcode.ACK, FtpOpcode.NAK):
            return
        reply = FTP_HEADER.pack((seq + 1) & 0xFFFF, session, FtpOpcode.NAK, 1, opcode, 0, 0, 0)
        reply += bytes((FTP_ERR_UNKNOWN_COMMAND,))
        self.send(link, mavlink2.MAVLink_file_transfer_protocol_message(
            msg.target_network, msg.get_srcSystem(), msg.get_srcComponent(),
            list(reply.ljust(251, b"\0"))))

    def _on_request_data_stream(self, msg: mavlink2.MAVLink_message, link: Link,
                                now_s: float) -> None:
        if msg.start_stop not in (0, 1):
            return
        rate = float(msg.req_message_rate) if msg.start_stop == 1 else 0.0
        link.scheduler.set_stream_rate(int(msg.req_stream_id), rate)

    # ----------------------------------------------------------------- params
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
        elif result.value == before:
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

    _HANDLERS: dict[str, Callable[[MavlinkServer, mavlink2.MAVLink_message, Link, float], None]] = {
        "HEARTBEAT": _on_heartbeat,
        "PARAM_REQUEST_LIST": _on_param_request_list,
        "PARAM_REQUEST_READ": _on_param_request_read,
        "PARAM_SET": _on_param_set,
        "COMMAND_LONG": _on_command,
        "COMMAND_INT": _on_command,
        "SET_MODE": _on_set_mode,
        "REQUEST_DATA_STREAM": _on_request_data_stream,
        "SET_POSITION_TARGET_LOCAL_NED": _on_set_position_target_local_ned,
        "SET_POSITION_TARGET_GLOBAL_INT": _on_set_position_target_global_int,
        "VISION_POSITION_ESTIMATE": _on_vision_position_estimate,
        "ODOMETRY": _on_odometry,
        "TIMESYNC": _on_timesync,
        "SETUP_SIGNING": _on_setup_signing,
        "FILE_TRANSFER_PROTOCOL": _on_file_transfer_protocol,
    }


# --------------------------------------------------------------------------- decoding helpers


def _param_name(raw: object) -> str:
    if isinstance(raw, (bytes, bytearray)):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).split("\0", 1)[0]


def _finite3(a: float, b: float, c: float) -> bool:
    return math.isfinite(a) and math.isfinite(b) and math.isfinite(c)


def _sane3(a: float, b: float, c: float) -> bool:
    return _finite3(a, b, c) and max(abs(a), abs(b), abs(c)) <= MAX_SETPOINT_VEL_ACC


_NAN3 = (math.nan, math.nan, math.nan)
LOCAL_SETPOINT_FRAMES = frozenset({MavFrame.LOCAL_NED, MavFrame.LOCAL_OFFSET_NED,
                                   MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED})
GLOBAL_SETPOINT_FRAMES = {MavFrame.GLOBAL: AltFrame.AMSL, MavFrame.GLOBAL_INT: AltFrame.AMSL,
                          MavFrame.GLOBAL_RELATIVE_ALT: AltFrame.RELATIVE_HOME,
                          MavFrame.GLOBAL_RELATIVE_ALT_INT: AltFrame.RELATIVE_HOME}


def _vel_acc_yaw(msg: mavlink2.MAVLink_message
                 ) -> tuple[tuple[float, float, float], tuple[float, float, float],
                            float | None, float | None] | None:
    mask = int(msg.type_mask)
    vel, acc = _NAN3, _NAN3
    if not mask & VELOCITY_IGNORE:
        if not _sane3(msg.vx, msg.vy, msg.vz):
            return None
        vel = (msg.vx, msg.vy, msg.vz)
    if not mask & ACCEL_IGNORE:
        if not _sane3(msg.afx, msg.afy, msg.afz):
            return None
        acc = (msg.afx, msg.afy, msg.afz)
    yaw = yaw_rate = None
    if not mask & PositionTargetTypeMask.YAW_IGNORE:
        if not math.isfinite(msg.yaw):
            return None
        yaw = msg.yaw
    if not mask & PositionTargetTypeMask.YAW_RATE_IGNORE:
        if not math.isfinite(msg.yaw_rate):
            return None
        yaw_rate = msg.yaw_rate
    return vel, acc, yaw, yaw_rate


def local_position_target(msg: mavlink2.MAVLink_message) -> LocalPositionTarget | None:
    """Validated SET_POSITION_TARGET_LOCAL_NED, or None when ArduCopter would reject it."""
    try:
        frame = MavFrame(msg.coordinate_frame)
    except ValueError:
        return None
    kind = setpoint_kind(int(msg.type_mask))
    if frame not in LOCAL_SETPOINT_FRAMES or kind is None:
        return None
    pos = _NAN3
    if not int(msg.type_mask) & POSITION_IGNORE:
        if not (_finite3(msg.x, msg.y, msg.z) and abs(msg.x) <= MAX_LOCAL_TARGET_XY_M
                and abs(msg.y) <= MAX_LOCAL_TARGET_XY_M and abs(msg.z) < LOCATION_ALT_MAX_M):
            return None
        pos = (msg.x, msg.y, msg.z)
    rest = _vel_acc_yaw(msg)
    if rest is None:
        return None
    vel, acc, yaw, yaw_rate = rest
    return LocalPositionTarget(int(msg.time_boot_ms), frame, int(msg.type_mask), kind, pos, vel,
                               acc, yaw, yaw_rate)


def global_position_target(msg: mavlink2.MAVLink_message) -> GlobalPositionTarget | None:
    """Validated SET_POSITION_TARGET_GLOBAL_INT, or None when it must be rejected."""
    try:
        frame = MavFrame(msg.coordinate_frame)
    except ValueError:
        return None
    kind = setpoint_kind(int(msg.type_mask))
    alt_frame = GLOBAL_SETPOINT_FRAMES.get(frame)
    if alt_frame is None or kind is None:
        return None
    lat = lon = alt = math.nan
    if not int(msg.type_mask) & POSITION_IGNORE:
        if not (abs(msg.lat_int) <= 900_000_000 and abs(msg.lon_int) <= 1_800_000_000
                and math.isfinite(msg.alt) and abs(msg.alt) < LOCATION_ALT_MAX_M):
            return None
        lat, lon, alt = msg.lat_int * 1e-7, msg.lon_int * 1e-7, float(msg.alt)
    rest = _vel_acc_yaw(msg)
    if rest is None:
        return None
    vel, acc, yaw, yaw_rate = rest
    return GlobalPositionTarget(int(msg.time_boot_ms), frame, int(msg.type_mask), kind, lat, lon,
                                alt, alt_frame, vel, acc, yaw, yaw_rate)


def odometry_from_message(msg: mavlink2.MAVLink_message) -> Odometry | None:
    """Validated ODOMETRY (finite position, unit quaternion), or None."""
    q = tuple(float(v) for v in msg.q)
    if not _finite3(msg.x, msg.y, msg.z) or not all(math.isfinite(v) for v in q):
        return None
    if abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-2:
        return None
    return Odometry(
        time_usec=int(msg.time_usec), frame_id=int(msg.frame_id),
        child_frame_id=int(msg.child_frame_id), position_m=(msg.x, msg.y, msg.z),
        q_wxyz=(q[0], q[1], q[2], q[3]), velocity_m_s=(msg.vx, msg.vy, msg.vz),
        body_rates_rad_s=(msg.rollspeed, msg.pitchspeed, msg.yawspeed),
        pose_covariance=tuple(float(v) for v in msg.pose_covariance),
        velocity_covariance=tuple(float(v) for v in msg.velocity_covariance),
        reset_counter=int(msg.reset_counter), estimator_type=int(msg.estimator_type),
        quality_pct=int(msg.quality))


def _close_socket(sock: socket.socket) -> None:
    try:
        sock.close()
    except OSError:
        pass
