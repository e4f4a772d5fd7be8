"""The Foxglove WebSocket protocol under both of its subprotocol names, in front of foxglove-sdk.

The protocol (github.com/foxglove/ws-protocol, ``docs/spec.md``) is negotiated as the WebSocket
subprotocol ``foxglove.websocket.v1``. foxglove-sdk (0.30) names it ``foxglove.sdk.v1`` and answers
a client that offers only the old name with HTTP 400, so Lichtblick and every client built on
``@foxglove/ws-protocol`` could not connect. This bridge listens on the public port and forwards
each connection byte for byte to the SDK's server; only the upgrade handshake is touched: where a
client offers ``foxglove.websocket.v1`` and not ``foxglove.sdk.v1``, the request also offers the new
name and the server's answer names the old one again. After the handshake the frames pass unchanged
(the names carry the same messages).

Used by :mod:`scenenav.app.live`; pure sockets and threads, no bus.
"""

from __future__ import annotations

import logging
import socket
import threading

log = logging.getLogger(__name__)

OLD_NAME = b"foxglove.websocket.v1"
NEW_NAME = b"foxglove.sdk.v1"
#: An upgrade request or answer longer than this is not a WebSocket handshake: the connection is closed.
MAX_HEAD_BYTES = 64 * 1024
_HEADER = b"sec-websocket-protocol"
_END = b"\r\n\r\n"
_CHUNK = 65536


def _split_head(head: bytes) -> list[bytes]:
    return head[:-len(_END)].split(b"\r\n") if head.endswith(_END) else head.split(b"\r\n")


def _is_protocol_line(line: bytes) -> bool:
    name, sep, _ = line.partition(b":")
    return bool(sep) and name.strip().lower() == _HEADER


def offered(head: bytes) -> list[bytes]:
    """The subprotocols an upgrade request offers, in order (every Sec-WebSocket-Protocol line)."""
    out: list[bytes] = []
    for line in _split_head(head)[1:]:
        if _is_protocol_line(line):
            out += [t.strip() for t in line.partition(b":")[2].split(b",") if t.strip()]
    return out


def rename_offer(head: bytes) -> tuple[bytes, bool]:
    """``head`` (a request line, headers and the blank line) offering ``foxglove.sdk.v1`` right
    after ``foxglove.websocket.v1`` where only the old name was offered; and whether it did so."""
    tokens = offered(head)
    if OLD_NAME not in tokens or NEW_NAME in tokens:
        return head, False
    at = tokens.index(OLD_NAME)
    tokens.insert(at + 1, NEW_NAME)
    lines = [ln for ln in _split_head(head) if not _is_protocol_line(ln)]
    lines.insert(1, b"Sec-WebSocket-Protocol: " + b", ".join(tokens))
    return b"\r\n".join(lines) + _END, True


def rename_answer(head: bytes) -> bytes:
    """The server's handshake answer naming ``foxglove.websocket.v1`` where it chose the new name."""
    lines = _split_head(head)
    for i, line in enumerate(lines):
        if _is_protocol_line(line) and line.partition(b":")[2].strip() == NEW_NAME:
            lines[i] = b"Sec-WebSocket-Protocol: " + OLD_NAME
    return b"\r\n".join(lines) + _END


def _read_head(sock: socket.socket) -> tuple[bytes, bytes] | None:
    """Read up to the end of an HTTP head: (head, bytes that came after it); None if the peer
    closed or sent more than MAX_HEAD_BYTES without one."""
    buf = b""
    while _END not in buf:
        if len(buf) > MAX_HEAD_BYTES:
            return None
        chunk = sock.recv(_CHUNK)
        if not chunk:
            return None
        buf += chunk
    end = buf.index(_END) + len(_END)
    return buf[:end], buf[end:]


def _pump(src: socket.socket, dst: socket.socket) -> None:
    try:
        while chunk := src.recv(_CHUNK):
            dst.sendall(chunk)
    except OSError:
        pass
    finally:
        for s in (src, dst):        # one side gone: the connection is over both ways
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


class SubprotocolBridge:
    """Listen on ``host:port`` (0: any free port; :attr:`port` is the bound one) and forward every
    connection to ``upstream_host:upstream_port``, renaming the subprotocol in the handshake as the
    module says. Raises OSError when the port cannot be bound."""

    def __init__(self, host: str, port: int, upstream_port: int, upstream_host: str = "127.0.0.1") -> None:
        self.host = host
        self.upstream_host = upstream_host
        self.upstream_port = upstream_port
        self._listener = socket.create_server((host, port))
        self.port = self._listener.getsockname()[1]
        self._closing = threading.Event()
        self._lock = threading.Lock()
        self._ended = threading.Condition(self._lock)        # a forwarded connection ended
        self._open: set[socket.socket] = set()
        self.connections = 0
        self.renamed = 0
        self._thread = threading.Thread(target=self._accept, name="ws-bridge", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._closing.is_set():
            try:
                client, _addr = self._listener.accept()
            except OSError:
                return          # closed
            threading.Thread(target=self._serve, args=(client,), name="ws-bridge-conn",
                             daemon=True).start()

    def _track(self, *socks: socket.socket) -> None:
        with self._lock:
            self._open.update(socks)

    def _serve(self, client: socket.socket) -> None:
        upstream = None
        try:
            self._track(client)
            request = _read_head(client)
            if request is None:
                return
            head, rest = request
            head, renamed = rename_offer(head)
            upstream = socket.create_connection((self.upstream_host, self.upstream_port), timeout=10)
            upstream.settimeout(None)
            self._track(upstream)
            upstream.sendall(head + rest)
            answer = _read_head(upstream)
            if answer is None:
                return
            head, rest = answer
            client.sendall((rename_answer(head) if renamed else head) + rest)
            with self._lock:
                self.connections += 1
                self.renamed += renamed
            back = threading.Thread(target=_pump, args=(upstream, client), daemon=True)
            back.start()
            _pump(client, upstream)
            back.join()
        except OSError as exc:
            if not self._closing.is_set():
                log.warning("live view: a viewer connection failed: %s", exc)
        finally:
            for s in (client, upstream):
                if s is not None:
                    s.close()
                    with self._lock:
                        self._open.discard(s)
                        self._ended.notify_all()

    def stop_accepting(self) -> None:
        """Stop listening (a new viewer is refused); the forwarded connections go on."""
        self._closing.set()
        try:
            self._listener.shutdown(socket.SHUT_RDWR)     # wakes the blocked accept() (close alone does not)
        except OSError:
            pass
        self._listener.close()

    def close(self, drain_s: float = 0.0) -> None:
        """Stop listening and end every forwarded connection: those still open after ``drain_s``
        seconds are cut. Cutting one ends its WebSocket without a close frame; so a caller that
        stopped the upstream server first (which sends each client its close frame, and closes
        the connection once the client answered) gives the connections ``drain_s`` to end so."""
        self.stop_accepting()
        with self._lock:
            self._ended.wait_for(lambda: not self._open, timeout=drain_s)
            socks = list(self._open)
        for s in socks:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=5)
