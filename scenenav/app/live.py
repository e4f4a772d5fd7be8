"""Live view node: a Foxglove WebSocket server (``foxglove-sdk``) streaming the run while it flies.

Started by ``scenenav run --live`` and ``scenenav sitl --live`` beside the recorder; never a
lockstep member, so a slow or absent viewer never holds the clock.

Inputs: everything under ``scenenav/<ns>/**`` (like the recorder) and the run folder
(``scenario.yaml`` for the world and the assistant map, the guidance node's ``route*.json``).
Outputs: a WebSocket server speaking ``foxglove.websocket.v1`` on ``127.0.0.1:<port>`` (on the
run's ``external.listen_host`` instead when that is not loopback, for a viewer on another machine;
under
that name and foxglove-sdk's ``foxglove.sdk.v1``: :mod:`scenenav.app.ws_subprotocol`)
(``live.json`` in the run folder names the bound port and URL), with the channels
``bus.mcap`` records (``scenenav.app.viz``): every bus message on its key (JSON, schema
``scenenav.<Type>``; camera frames only as ``viz/camera``) and the view channels ``viz/...``. The
maps are sent again every :data:`MAP_REPEAT_S` wall seconds so a viewer that connects late gets them.
"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path

import foxglove

from scenenav.app.viz import VizMessage, VizState, bus_schema
from scenenav.app.ws_subprotocol import SubprotocolBridge
from scenenav.core.bus import Bus, BusConfig
from scenenav.core.contracts import CameraFrame, DecodeError, decode, message_type
from scenenav.core.formats.atomic_file import write_atomic
from scenenav.core.keys import Keys, type_for_key
from scenenav.core.presence import announce_node

log = logging.getLogger(__name__)

NODE_ID = "live"
LIVE_FILE = "live.json"
MAP_REPEAT_S = 5.0
ROUTE_POLL_S = 1.0
HOST = "127.0.0.1"
#: Wall seconds the viewers get, once the run is over, to answer the server's close frame before
#: their connections are cut.
CLOSE_GRACE_S = 2.0


class LiveNode:
    def __init__(self, run_dir: Path, bus_cfg: BusConfig, port: int, camera_every_n: int = 1,
                 maps: tuple[VizMessage, ...] = ()) -> None:
        self.run_dir = Path(run_dir)
        self.keys = Keys(bus_cfg.namespace)
        self.viz = VizState(camera_every_n)
        self.maps = maps
        self._lock = threading.Lock()
        self._channels: dict[str, foxglove.Channel] = {}
        self._sim_time_us = 0
        self.sent = 0
        self.dropped = 0
        # the SDK's server on a private port; the public one is the bridge that also accepts the
        # protocol's old subprotocol name (Lichtblick, @foxglove/ws-protocol clients)
        self.server = foxglove.start_server(name=f"scenenav {bus_cfg.namespace}", host=HOST, port=0)
        host = bus_cfg.listen_host or HOST      # the run's external.listen_host: a remote viewer
        try:
            self.bridge = SubprotocolBridge(host, port, self.server.port, upstream_host=HOST)
        except OSError as exc:
            self.server.stop()
            raise RuntimeError(str(exc)) from exc
        self.port = self.bridge.port
        local = HOST if host in (HOST, "0.0.0.0") else host     # where a viewer here connects
        write_atomic(self.run_dir / LIVE_FILE,
                     json.dumps({"host": host, "port": self.port, "url": f"ws://{local}:{self.port}",
                                 "protocol": "foxglove.websocket.v1"}, indent=2))
        log.info("live view: ws://%s:%d", host, self.port)
        self.bus = Bus(bus_cfg)
        self.bus.subscribe_raw(self.keys.everything, self._on_sample)
        self.presence = announce_node(self.bus, self.keys, "live", NODE_ID)

    def _channel(self, topic: str, schema_name: str, schema: bytes) -> foxglove.Channel:
        ch = self._channels.get(topic)
        if ch is None:
            with self._lock:
                ch = self._channels.get(topic)
                if ch is None:
                    ch = foxglove.Channel(topic, message_encoding="json", schema=foxglove.Schema(
                        name=schema_name, encoding="jsonschema", data=schema))
                    self._channels[topic] = ch
        return ch

    def send(self, messages) -> None:
        for v in messages:
            self._channel(v.topic, v.schema_name, v.schema).log(v.payload, log_time=v.log_time_ns)
            self.sent += 1

    def _on_sample(self, payload: bytes, key: str) -> None:
        type_name = type_for_key(self.keys, key)
        if type_name is None:
            return
        try:
            msg = decode(message_type(type_name), payload)
        except DecodeError:
            self.dropped += 1
            return
        self._sim_time_us = max(self._sim_time_us, int(msg.timestamp_us))
        if not isinstance(msg, CameraFrame):
            self._channel(key, *bus_schema(type_name)).log(bytes(payload),
                                                            log_time=int(msg.timestamp_us) * 1000)
        with self._lock:          # VizState keeps the paths: one caller at a time
            out = self.viz.on_message(msg)
        self.send(out)

    def run(self, stop: threading.Event) -> None:
        """Until ``stop``: send the maps and routes every MAP_REPEAT_S, new route files within
        ROUTE_POLL_S."""
        next_maps = 0.0
        waited = 0.0
        routes: list[VizMessage] = []
        while not stop.is_set():
            if waited >= next_maps:                     # again, for viewers that joined since
                self.send(self.maps)
                self.send(routes)
                next_maps = waited + MAP_REPEAT_S
            with self._lock:
                new = self.viz.route_messages(self.run_dir, self._sim_time_us)
            self.send(new)
            routes.extend(new)
            stop.wait(ROUTE_POLL_S)
            waited += ROUTE_POLL_S

    def close(self) -> dict:
        self.presence.close()
        self.bus.close()
        stop_serving(self.server, self.bridge)
        return {"port": self.port, "messages_sent": self.sent, "dropped": self.dropped,
                "viewer_connections": self.bridge.connections,
                "viewers_on_the_old_subprotocol_name": self.bridge.renamed}


def stop_serving(server, bridge: SubprotocolBridge, grace_s: float = CLOSE_GRACE_S) -> None:
    """End every viewer's session with a WebSocket close frame: no new viewer, then the SDK's server
    stops (it sends each one a close frame, through the bridge), then the bridge, after up to
    ``grace_s`` for the closing handshakes. The bridge closed first (as once) cut the connections
    under the server: a viewer saw the run's end as "closed without a close frame"."""
    bridge.stop_accepting()
    server.stop()
    bridge.close(drain_s=grace_s)
