"""``scenenav run --live``: a Foxglove WebSocket client (the protocol spoken by hand with the
``websockets`` package) connects during a short autopilot flight, subscribes to the camera and the
estimate channels and decodes what arrives; the channels it was offered are the ones bus.mcap
recorded (same topics, schema names and schemas), so one layout opens both."""

from __future__ import annotations

import asyncio
import base64
import json
import math
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
import websockets

#: The protocol's own name only, as Lichtblick and ``@foxglove/ws-protocol`` clients offer it (the
#: live view also accepts foxglove-sdk's newer ``foxglove.sdk.v1``: tests/unit/app/test_ws_subprotocol.py).
SUBPROTOCOLS = ["foxglove.websocket.v1"]
WANTED = ("viz/camera", "viz/estimate/pose")
_OP_MESSAGE_DATA = 0x01
_MESSAGE_HEADER = struct.Struct("<BIQ")      # opcode, subscription id, log time (ns)


async def _watch(url: str, n_each: int, timeout_s: float, on_enough) -> tuple[str, dict, dict, str]:
    """Connect, subscribe to WANTED as they are advertised, call ``on_enough()`` once every wanted
    topic has ``n_each`` messages, and stay connected until the server ends the connection (the
    run's end) or ``timeout_s``; the negotiated subprotocol, every advertised channel by topic, the
    decoded messages per wanted topic (the first ``n_each``), and how the connection ended ("close
    frame": the server's closing handshake)."""
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        channels: dict[str, dict] = {}
        subs: dict[int, str] = {}
        got: dict[str, list] = {t: [] for t in WANTED}
        deadline = time.monotonic() + timeout_s
        ended = f"still open after {timeout_s} s"
        while time.monotonic() < deadline:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=max(0.1, deadline - time.monotonic()))
            except asyncio.TimeoutError:
                break
            except websockets.ConnectionClosed as exc:
                ended = "close frame" if exc.rcvd is not None else f"{type(exc).__name__}: {exc}"
                break
            if isinstance(raw, str):
                op = json.loads(raw)
                if op["op"] == "advertise":
                    for ch in op["channels"]:
                        channels[ch["topic"]] = ch
                        if ch["topic"] in WANTED:
                            sid = len(subs) + 1
                            subs[sid] = ch["topic"]
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                                {"id": sid, "channelId": ch["id"]}]}))
            elif raw[0] == _OP_MESSAGE_DATA:
                _op, sid, log_ns = _MESSAGE_HEADER.unpack_from(raw)
                if len(got[subs[sid]]) < n_each:
                    got[subs[sid]].append((log_ns, json.loads(raw[_MESSAGE_HEADER.size:])))
                    if all(len(m) == n_each for m in got.values()):
                        on_enough()
        return ws.subprotocol, channels, got, ended


def _mcap_channels(path: Path) -> dict[str, tuple[str, bytes, str]]:
    from mcap.reader import make_reader
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    return {c.topic: (summary.schemas[c.schema_id].name, summary.schemas[c.schema_id].data,
                      c.message_encoding) for c in summary.channels.values()}


def test_live_view_streams_camera_and_estimate_during_a_flight(tmp_path):
    run = tmp_path / "live"
    # paced (2x): the client connects while the vehicle flies (a lockstep flight may end first); no
    # perception node (the simulator publishes the camera frames all the same). The run is stopped
    # with Ctrl-C once the client has its messages (with 12 and once, at load 8-10, with 30 s of
    # flight the run of a loaded machine ended before the client had them): 120 s is a bound only
    launcher = subprocess.Popen(
        [sys.executable, "-m", "scenenav.app.cli", "run", "--out", str(run), "--set", "duration_s=120",
         "--set", "flight.mode=autopilot", "--set", "perception.enabled=false", "--set", "clock.mode=realtime", "--set", "clock.speed_factor=2",
         "--set", "autopilot.mavlink_tcp_port=0", "--set", "autopilot.mavlink_udp_out=none",
         "--live", "--live-port", "0", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while not (run / "live.json").is_file():
            assert launcher.poll() is None, launcher.communicate()[1][-3000:]
            assert time.monotonic() - t0 < 120, "the live view never wrote live.json"
            time.sleep(0.1)
        url = json.loads((run / "live.json").read_text())["url"]
        # the client stays until the run ends: the live view then ends every viewer's session with
        # a close frame (it once cut them: "no close frame received or sent")
        protocol, channels, got, ended = asyncio.run(_watch(
            url, n_each=3, timeout_s=240, on_enough=lambda: launcher.send_signal(signal.SIGINT)))
        out, err = launcher.communicate(timeout=300)
        assert launcher.returncode == 130, err[-3000:]      # stopped by the Ctrl-C, cleanly
    finally:
        if launcher.poll() is None:
            launcher.send_signal(signal.SIGINT)
            launcher.wait(60)
    assert protocol == "foxglove.websocket.v1"
    assert ended == "close frame", ended          # the run's end (a Ctrl-C), said to the viewer
    assert f"live view: {url}" in err
    for topic in WANTED:
        assert len(got[topic]) >= 3, f"{topic}: {len(got[topic])} messages"
    _t, img = got["viz/camera"][-1]
    pixels = base64.b64decode(img["data"])
    assert len(pixels) == img["height"] * img["step"] == img["height"] * img["width"] * 3
    for log_ns, pose in got["viz/estimate/pose"]:
        assert pose["frame_id"] == "world"
        p, q = pose["pose"]["position"], pose["pose"]["orientation"]
        assert all(math.isfinite(p[k]) for k in "xyz")
        assert abs(math.hypot(q["w"], q["x"], q["y"], q["z"]) - 1.0) < 1e-6
        assert log_ns == (pose["timestamp"]["sec"] * 10**9 + pose["timestamp"]["nsec"])
    # the live channels are the recorded ones: topic, schema name, schema, encoding
    recorded = _mcap_channels(run / "bus.mcap")
    shared = [t for t in channels if t in recorded]
    assert set(WANTED) | {"viz/map/reference", "viz/truth/pose", "viz/events"} <= set(shared)
    for topic in shared:
        ch = channels[topic]
        assert (ch["schemaName"], ch["schema"].encode(), ch["encoding"]) == recorded[topic], topic
    stats = json.loads((run / "live_stats.json").read_text())
    assert stats["messages_sent"] > 0 and stats["dropped"] == 0
    assert stats["viewer_connections"] == stats["viewers_on_the_old_subprotocol_name"] == 1


@pytest.mark.parametrize("command", ["run", "sitl"])
@pytest.mark.parametrize("value", ["-1", "x", "70000"])
def test_a_bad_live_port_is_a_one_line_usage_error(capsys, command, value):
    from scenenav.app.cli import build_parser
    args = [command, "--out", "r", "--live", "--live-port", value]
    with pytest.raises(SystemExit) as exc:
        build_parser(domain_commands=False).parse_args(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--live-port" in err and "expected a port number 0 to 65535" in err
