"""Zenoh session helpers: peer mode on loopback, multicast scouting off, explicit endpoints, no shared memory.

Topology of a run: the simulator listens on the run's hub endpoint ``tcp/127.0.0.1:<port>``; every
other node connects to it and listens on an ephemeral loopback port; gossip scouting (over those
links only) then meshes the peers. No multicast, and each run has its own port and key namespace, so
parallel runs never cross-talk. By default nothing leaves 127.0.0.1; with ``listen_host`` (the
scenario's ``external.listen_host``) every node of the run listens on that address instead (an
interface's, or 0.0.0.0 for all), so a node on another machine can connect to the hub and the
gossip mesh can link it with every node (peers do not forward for each other).

``Bus`` wraps one session: typed publishers (reliable, congestion control BLOCK so nothing is lost),
typed subscribers that decode, count and drop malformed payloads without ever raising into Zenoh,
and liveliness tokens/subscribers.
"""

from __future__ import annotations

import json
import logging
import socket
import threading
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable

import zenoh

from scenenav.core.contracts import DecodeError, decode, encode

log = logging.getLogger(__name__)

#: Zenoh transmit queue of the data priority, in batches of up to 64 kB per link (Zenoh's maximum, 16;
#: its default, 2, is less than two camera frames).
DATA_QUEUE_BATCHES = 16


@dataclass(frozen=True)
class BusConfig:
    """How a node joins the bus of one run."""

    namespace: str
    hub_port: int                      # the simulator's listening port
    listen_hub: bool = False           # True for the node that owns the hub endpoint (the simulator)
    host: str = "127.0.0.1"            # the hub's address, as this node connects to it
    listen_host: str = ""              # the address this node listens on ("": ``host``)

    def zenoh_config(self) -> zenoh.Config:
        listen = self.listen_host or self.host
        conf: dict[str, Any] = {
            "mode": "peer",
            "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
            "listen": {"endpoints": [f"tcp/{listen}:{self.hub_port if self.listen_hub else 0}"]},
            "connect": {"endpoints": [] if self.listen_hub else [f"tcp/{self.host}:{self.hub_port}"]},
        }
        cfg = zenoh.Config()
        for key, value in conf.items():
            cfg.insert_json5(key, json.dumps(value))
        # No shared memory: zenoh 1.x moves every payload over 3 kB (camera frames) through a 16 MB
        # pool per publisher that each subscriber maps, plus small segments per peer link. Our
        # payloads are bytes built per message, so it saves no copy; but a node kept the segments of
        # peers long gone and its resident memory grew with the pool pages it touched (``bench soak``:
        # recorder +4 to +10 % in 30 minutes, +2 fds over 14 perception swaps).
        cfg.insert_json5("transport/shared_memory/enabled", "false")
        # Room for a burst on every link: Zenoh's default is 2 batches (2 x 64 kB) per priority, so
        # a camera frame (120 kB, two fragments) found them still taken by the tick's sensors
        # whenever the link's transmit thread had not run for 50 ms (2 loaded cores): published
        # with congestion control DROP (tried on 2026-12-04) it was lost and the run's fixes
        # changed; with BLOCK the publisher waits. 16 batches (allocated only when used) hold
        # several frames, so the simulator rarely waits, and a frozen subscriber's link takes
        # longer to fill (docs/faults.md).
        cfg.insert_json5("transport/link/tx/queue/size/data", str(DATA_QUEUE_BATCHES))
        if not self.listen_hub:
            # Keep retrying the hub until it is up (nodes may start before the simulator).
            cfg.insert_json5("connect/timeout_ms", "-1")
        return cfg


class HubPortTaken(RuntimeError):
    """The hub endpoint could not be bound: another process listens on that port."""

    def __init__(self, port: int) -> None:
        super().__init__(f"cannot listen on the run's Zenoh hub port {port}: address already in use")
        self.port = port


#: Exit code of the simulator node when its hub port was taken (``EX_TEMPFAIL``): the launcher
#: then starts the run again on another port.
EXIT_HUB_PORT_TAKEN = 75


def free_port(host: str = "127.0.0.1") -> int:
    """An unused TCP port on loopback (for tests and the launcher)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _direct(handler: Callable) -> zenoh.handlers.Callback:
    """Run ``handler`` in Zenoh's receive thread: in-order delivery across subscriptions."""
    return zenoh.handlers.Callback(handler, indirect=False)


class Inbox:
    """Raw samples waiting for their consumer (``Bus.subscribe_inbox``)."""

    def __init__(self, subscriber: Any) -> None:
        self._sub = subscriber

    def take(self) -> tuple[bytes, str] | None:
        """The oldest waiting sample as (payload, key), or None when none is waiting (also once
        the session is closed and the FIFO empty)."""
        try:
            sample = self._sub.try_recv()
        except zenoh.ZError:            # closed and empty
            return None
        if sample is None:
            return None
        return sample.payload.to_bytes(), str(sample.key_expr)


class Bus:
    """One Zenoh session of a node, with typed publish/subscribe and malformed-message counting."""

    def __init__(self, cfg: BusConfig):
        self.cfg = cfg
        try:
            self.session = zenoh.open(cfg.zenoh_config())
        except zenoh.ZError as exc:
            if cfg.listen_hub and "already in use" in str(exc):
                raise HubPortTaken(cfg.hub_port) from None
            raise
        self._publishers: dict[str, Any] = {}
        self._subscribers: list[Any] = []
        self._tokens: list[Any] = []
        self.dropped: Counter[str] = Counter()   # malformed messages per key
        self._lock = threading.Lock()
        self._closing = False                    # set by close(): callbacks racing it stay quiet

    # --------------------------------------------------------------------------- publishing
    def publisher(self, key: str):
        """The publisher of ``key`` (declared on first use). Congestion control BLOCK: a healthy
        subscriber never loses a message (lockstep determinism depends on it), and one that cannot
        keep up slows the publisher down until Zenoh closes its link (a frozen node: see
        docs/faults.md)."""
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE)
            self._publishers[key] = pub
        return pub

    def publish(self, key: str, msg: Any) -> None:
        self.publisher(key).put(encode(msg))

    def put_raw(self, key: str, payload: bytes) -> None:
        self.publisher(key).put(payload)

    # -------------------------------------------------------------------------- subscribing
    def subscribe(self, key: str, cls: type, callback: Callable[[Any, str], None]) -> None:
        """Call ``callback(message, key)`` for each well-formed ``cls`` message on ``key``.

        Malformed payloads are counted in ``self.dropped`` and logged (rate-limited), never raised.
        Exceptions from the callback are logged with their traceback and swallowed so the
        subscriber keeps running. Callbacks run directly in Zenoh's receive thread
        (``indirect=False``), so messages from one publisher session arrive in publication order
        across all of this session's subscriptions (the lockstep protocol relies on it): keep
        them short and hand long work to a thread of your own.
        """
        def handler(sample: zenoh.Sample) -> None:
            k = str(sample.key_expr)
            try:
                msg = decode(cls, sample.payload.to_bytes())
            except DecodeError as exc:
                self._count_drop(k, str(exc))
                return
            try:
                callback(msg, k)
            except Exception:  # a bug in a handler must not kill the Zenoh callback thread
                self._handler_failed("handler for %s failed", k)
        self._subscribers.append(self.session.declare_subscriber(key, _direct(handler)))

    def subscribe_raw(self, key: str, callback: Callable[[bytes, str], None]) -> None:
        def handler(sample: zenoh.Sample) -> None:
            try:
                callback(sample.payload.to_bytes(), str(sample.key_expr))
            except Exception:
                self._handler_failed("raw handler for %s failed", sample.key_expr)
        self._subscribers.append(self.session.declare_subscriber(key, _direct(handler)))

    def subscribe_inbox(self, key: str, capacity: int) -> Inbox:
        """The samples of ``key`` queued in a FIFO of ``capacity`` (``zenoh.handlers.FifoChannel``)
        for a thread of the caller to take in batches (``Inbox.take``): Zenoh's receive thread
        only queues them, without running Python or taking its GIL. Nothing is dropped: when the
        FIFO is full, the receive thread waits (the consumer must keep up)."""
        sub = self.session.declare_subscriber(key, zenoh.handlers.FifoChannel(capacity))
        self._subscribers.append(sub)
        return Inbox(sub)

    def _count_drop(self, key: str, why: str) -> None:
        with self._lock:
            self.dropped[key] += 1
            n = self.dropped[key]
        if n <= 5 or n % 100 == 0:
            log.warning("dropped malformed message #%d on %s: %s", n, key, why)

    # --------------------------------------------------------------------------- liveliness
    def declare_token(self, key: str) -> Any:
        token = self.session.liveliness().declare_token(key)
        self._tokens.append(token)
        return token

    def alive_tokens(self, key: str, timeout_s: float = 2.0) -> set[str]:
        """The liveliness tokens matching ``key`` alive now, as the peers linked to this session
        answer (a liveliness query; a subscriber's history arrives later, this does not)."""
        found: set[str] = set()
        for reply in self.session.liveliness().get(key, timeout=timeout_s):
            sample = reply.ok          # None for an error reply: no token in it
            if sample is not None:
                found.add(str(sample.key_expr))
        return found

    def undeclare_token(self, token: Any) -> None:
        """Withdraw a token of ``declare_token`` before the session closes."""
        if token in self._tokens:
            self._tokens.remove(token)
        try:
            token.undeclare()
        except zenoh.ZError:
            pass

    def watch_liveliness(self, key: str, on_change: Callable[[str, bool], None]) -> None:
        """``on_change(key, alive)`` for tokens matching ``key``, including ones already alive."""
        def handler(sample: zenoh.Sample) -> None:
            try:
                on_change(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
            except Exception:
                self._handler_failed("liveliness handler for %s failed", sample.key_expr)
        self._subscribers.append(
            self.session.liveliness().declare_subscriber(key, handler, history=True))

    def _handler_failed(self, what: str, key: Any) -> None:
        """A callback raised: logged with its traceback, unless the bus is closing. Zenoh may still
        deliver a sample (a member's token withdrawn at the end of a run, say) while ``close`` runs,
        and a callback that publishes then meets the closed session: an expected race, not a bug."""
        if self._closing:
            log.debug(what + " while the bus was closing", key, exc_info=True)
        else:
            log.exception(what, key)

    def close(self) -> None:
        self._closing = True
        for tok in self._tokens:
            try:
                tok.undeclare()
            except zenoh.ZError:
                pass
        self._tokens.clear()
        try:
            self.session.close()
        except zenoh.ZError:
            pass
