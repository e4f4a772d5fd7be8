"""MAVLink transport (part of ``MavlinkServer``): the TCP server socket and its clients, the UDP socket
with its target and peers, one ``Link`` each (own sequence numbers, telemetry scheduler and frame
parser); non-blocking reads, buffered TCP writes, sends to one link or all.
"""

from __future__ import annotations

import enum
import errno
import logging
import select
import socket
import struct
from collections import deque

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.mavlink_framing import FrameParser
from autopilot_bridge.telemetry import (
    TelemetryScheduler,
)
from scenenav.core.errors import UserError

logger = logging.getLogger(__name__)


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


def close_socket(sock: socket.socket) -> None:
    try:
        sock.close()
    except OSError:
        pass


class LinkTransportMixin:
    """Part of ``MavlinkServer`` (``autopilot_bridge.mavlink_server``); works on its state."""

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
                close_socket(sock)
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
            close_socket(link.sock)
        if link in self._links:
            self._links.remove(link)
        if link.addr is not None and self._udp_peers.get(link.addr) is link:
            del self._udp_peers[link.addr]
        self.missions.link_closed(link)
        self.fence_rally.link_closed(link)
        self.ftp.forget(lambda key: key[0] is link)

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
