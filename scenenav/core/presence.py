"""Node presence on the bus: a node's liveliness token, and which other nodes it has a link to.

A node announces itself with the token ``nodes/<role>/<id>`` (``Keys.node_alive``), declared once its
subscribers are in place. Zenoh peers do not forward for each other: a peer receives another peer's
declarations (its tokens, its subscriptions) only over a direct link, which gossip makes after both
have joined the hub. So a node that sees another node's token has a link to it, and from then on
receives what that node publishes.

``announce_node`` also *echoes* that: for every other node whose token it sees, it declares
``mesh/<own role>/<own id>/<role>/<id>`` (``Keys.node_sees``) and undeclares it when that node
goes. The simulator starts the clock of a run with external nodes only once every node of the run
has echoed every external node (``scenenav.app.nodes.wait_external_nodes``), so nothing an external
node publishes from the first frame on is lost to the recorder or the autopilot. A node of your own
may echo too (docs/interfaces.md, "Presence"); nothing requires it.
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import Any

from scenenav.core.bus import Bus
from scenenav.core.keys import Keys

log = logging.getLogger(__name__)

__all__ = ["NodePresence", "announce_node", "parse_node_key", "parse_sees_key"]


def parse_node_key(keys: Keys, key: str) -> tuple[str, str] | None:
    """``<root>/nodes/<role>/<id>`` -> (role, id); None for any other key."""
    prefix = f"{keys.root}/nodes/"
    if not key.startswith(prefix):
        return None
    parts = key[len(prefix):].split("/")
    return (parts[0], parts[1]) if len(parts) == 2 and all(parts) else None


def parse_sees_key(keys: Keys, key: str) -> tuple[tuple[str, str], tuple[str, str]] | None:
    """``<root>/mesh/<role>/<id>/<seen role>/<seen id>`` -> ((role, id), (seen role, seen id))."""
    prefix = f"{keys.root}/mesh/"
    if not key.startswith(prefix):
        return None
    parts = key[len(prefix):].split("/")
    if len(parts) != 4 or not all(parts):
        return None
    return (parts[0], parts[1]), (parts[2], parts[3])


class NodePresence:
    """The tokens of one node (see the module docstring); made by ``announce_node``."""

    def __init__(self, bus: Bus, keys: Keys, role: str, node_id: str) -> None:
        self.bus, self.keys, self.role, self.node_id = bus, keys, role, node_id
        self._echoes: dict[tuple[str, str], Any] = {}
        # Zenoh's liveliness callbacks only queue; tokens are declared on this thread, never from
        # inside a Zenoh callback
        self._changes: queue.SimpleQueue[tuple[tuple[str, str], bool] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._echo_loop, name=f"presence-{node_id}", daemon=True)
        self._thread.start()
        bus.watch_liveliness(keys.node_alive_all, self._on_node)
        bus.declare_token(keys.node_alive(role, node_id))

    def _on_node(self, key: str, alive: bool) -> None:
        seen = parse_node_key(self.keys, key)
        if seen is not None and seen != (self.role, self.node_id):
            self._changes.put((seen, alive))

    def _echo_loop(self) -> None:
        while True:
            change = self._changes.get()
            if change is None:
                return
            seen, alive = change
            try:
                if alive and seen not in self._echoes:
                    self._echoes[seen] = self.bus.declare_token(
                        self.keys.node_sees(self.role, self.node_id, *seen))
                elif not alive and seen in self._echoes:
                    self.bus.undeclare_token(self._echoes.pop(seen))
            except Exception as exc:  # a closing session: the echo no longer matters
                log.debug("presence echo of %s/%s: %s", *seen, exc)

    def sees(self) -> set[tuple[str, str]]:
        """The (role, id) of the nodes this node has echoed (a copy)."""
        return set(self._echoes)

    def close(self) -> None:
        """Stop echoing (the bus's close undeclares the tokens)."""
        self._changes.put(None)
        self._thread.join(timeout=2.0)


def announce_node(bus: Bus, keys: Keys, role: str, node_id: str) -> NodePresence:
    """Declare ``nodes/<role>/<node_id>`` and echo every other node seen (module docstring). Call it
    once the node's subscribers are declared."""
    return NodePresence(bus, keys, role, node_id)
