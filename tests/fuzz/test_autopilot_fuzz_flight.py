"""Fuzz the real autopilot while it flies a mission (``scenenav sitl --lockstep``, GPS).

A pymavlink ground station (system 255 = SYSID_MYGCS, heartbeats at 4 Hz, FS_GCS_ENABLE 1 so a
lost heartbeat would show as an RTL) uploads take-off to 10 m, three 30 m legs and NAV_LAND, arms
in GUIDED and starts the mission. While the vehicle flies, a second TCP client throws 10,400 fuzz
inputs (``mavlink_fuzzgen``: random bytes, bit-flipped, truncated and valid-CRC frames of random
types with random/NaN/extreme fields; deliberate flight changes such as SET_MODE, arming and mode
commands, mission uploads and clears are left out) as fast as the autopilot reads them, after
absurd mission uploads from that client (65535 items; items with latitude, longitude or altitude
out of range or NaN), each of which must get its MISSION_ACK error and leave the mission alone.

Checked: the fuzz was all sent before the mission ended; the mission completes (MISSION_ITEM_REACHED
of the last item, disarmed); the ground-truth track (``truth.csv``) stays on the planned path with no
jumps and lands at the last waypoint; the autopilot process is alive and answers PARAM_REQUEST_READ
afterwards; its counters (``autopilot_stats.json``) show the garbage dropped and no handler errors.
"""

from __future__ import annotations

import json
import math
import socket
import threading
import time

import numpy as np
import pytest
from support.mavlink_fuzzgen import FLIGHT_EXCLUDED_TYPES, M, build_inputs
from support.sitl_session import Gcs, SitlSession, enu_to_latlon, final_position, wait_until, world_origin, write_params

from scenenav.core.geometry import distance_to_polyline_m

#: real-time SITL flights: `make test` runs them after the parallel part, apart from it
pytestmark = pytest.mark.realtime

SEED = 20240917
N_PER_KIND = 2600                       # four kinds -> 10,400 inputs
ALT_M = 10.0
LEGS_ENU = [(30.0, 0.0), (30.0, 30.0), (0.0, 30.0)]
COPTER_GUIDED = 4
COPTER_AUTO = 3
MAV_MODE_FLAG_SAFETY_ARMED = 128
PATH_TOLERANCE_M = 3.0
MAX_TRUTH_SPEED_M_S = 15.0


class FuzzClient:
    """A second TCP client that writes the fuzz stream in random chunks and drains its replies."""

    def __init__(self, port: int, stream: bytes, rng: np.random.Generator) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=30.0)
        self.stream = stream
        self.chunks = [int(c) for c in rng.integers(1, 4096, len(stream) // 512 + 8)]
        self.sent_bytes = 0
        self.received_bytes = 0
        self.mission_acks: list[int] = []
        self.param_values: list[str] = []
        self._parser = M.MAVLink(None)
        self._parser.robust_parsing = True
        self.error: BaseException | None = None
        self.done = threading.Event()             # the whole stream is written
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fuzz", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _drain(self) -> None:
        self.sock.setblocking(False)
        try:
            while True:
                data = self.sock.recv(65536)
                if not data:
                    raise ConnectionError("the autopilot closed the fuzz link")
                self.received_bytes += len(data)
                for msg in self._parser.parse_buffer(data) or ():
                    if msg.get_type() == "MISSION_ACK":
                        self.mission_acks.append(int(msg.type))
                    elif msg.get_type() == "PARAM_VALUE":
                        self.param_values.append(msg.param_id)
        except BlockingIOError:
            pass
        finally:
            self.sock.settimeout(30.0)

    def _run(self) -> None:
        try:
            pos, i = 0, 0
            while pos < len(self.stream):
                size = self.chunks[i % len(self.chunks)]
                i += 1
                self.sock.sendall(self.stream[pos:pos + size])
                pos += size
                self.sent_bytes = min(pos, len(self.stream))
                self._drain()
            self.done.set()
            while not self._stop.wait(0.05):          # keep reading the replies, like a GCS
                self._drain()
        except (OSError, ConnectionError) as exc:
            self.error = exc
        finally:
            self.done.set()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)
        self.sock.close()


def absurd_uploads(home) -> tuple[bytes, list[int]]:
    """Mission uploads a ground station must never get through, and the MISSION_ACK each gets."""
    mav = M.MAVLink(None, 255, 190)
    rel = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    frames, expected = [], []

    def send(msg) -> None:
        frames.append(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256

    send(M.MAVLink_mission_count_message(1, 1, 65535, 0))
    expected.append(M.MAV_MISSION_NO_SPACE)
    for lat_e7, lon_e7, alt, result in ((2_000_000_000, 0, 10.0, M.MAV_MISSION_INVALID_PARAM5_X),
                                        (0, -2_000_000_000, 10.0, M.MAV_MISSION_INVALID_PARAM6_Y),
                                        (0, 0, math.nan, M.MAV_MISSION_INVALID_PARAM7),
                                        (0, 0, 1.0e9, M.MAV_MISSION_INVALID_PARAM7)):
        send(M.MAVLink_mission_count_message(1, 1, 3, 0))
        send(home)
        send(M.MAVLink_mission_item_int_message(1, 1, 1, rel, M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0,
                                                0, lat_e7, lon_e7, alt, 0))
        expected.append(result)
    return b"".join(frames), expected


def tail_requests() -> bytes:
    """PARAM_REQUEST_READs after the fuzz: their answer on the fuzz link means every byte before
    them was handled (one TCP stream, parsed in order)."""
    mav = M.MAVLink(None, 255, 190)
    out = b""
    for _ in range(3):
        out += M.MAVLink_param_request_read_message(1, 1, b"WPNAV_SPEED", -1).pack(mav)
        mav.seq += 1
    return out


def mission_items(m) -> list:
    lat0, lon0 = world_origin()
    rel = m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT

    def item(seq, command, lat=0.0, lon=0.0, alt=0.0, frame=rel):
        return m.MAVLink_mission_item_int_message(
            1, 1, seq, frame, command, 0, 1, 0.0, 0.0, 0.0, 0.0,
            int(round(lat * 1e7)), int(round(lon * 1e7)), alt, 0)

    items = [item(0, m.MAV_CMD_NAV_WAYPOINT, lat0, lon0, 0.0, m.MAV_FRAME_GLOBAL_INT),
             item(1, m.MAV_CMD_NAV_TAKEOFF, alt=ALT_M)]
    for x, y in LEGS_ENU:
        lat, lon = enu_to_latlon(x, y)
        items.append(item(len(items), m.MAV_CMD_NAV_WAYPOINT, lat, lon, ALT_M))
    items.append(item(len(items), m.MAV_CMD_NAV_LAND))          # lat/lon 0: land where it is
    return items


def upload(gcs: Gcs, items: list) -> int | None:
    """Client side of the mission upload; the MISSION_ACK type, or None."""
    gcs.send("mission_count_send", 1, 1, len(items), 0)
    while True:
        msg = gcs.wait(["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], timeout_s=15)
        if msg is None or msg.get_type() == "MISSION_ACK":
            return None if msg is None else msg.type
        gcs.send("send", items[msg.seq])


def distance_to_path_m(x: np.ndarray, y: np.ndarray, path: list[tuple[float, float]]) -> np.ndarray:
    """Horizontal distance of each point to the polyline ``path``."""
    return distance_to_polyline_m(np.stack([x, y], axis=1), path)


def test_fuzz_while_flying_a_mission(tmp_path):
    t_start = time.monotonic()
    params = write_params(tmp_path, FS_GCS_ENABLE=1, FS_GCS_TIMEOUT=5, WPNAV_SPEED_UP=500,
                          WPNAV_SPEED_DN=300, LAND_SPEED=200, DISARM_DELAY=30)
    rng = np.random.default_rng(SEED)
    inputs = build_inputs(rng, N_PER_KIND, FLIGHT_EXCLUDED_TYPES)
    assert len(inputs) >= 10_000
    fuzz_stream = b"".join(inputs)
    sitl = SitlSession(tmp_path, "--lockstep", "--perception", "off",
                       "--set", f"autopilot.params_file={params}")
    gcs = fuzz = None
    try:
        sitl.wait_ready()
        gcs = Gcs(sitl.port)
        m = gcs.m
        items = mission_items(m)
        absurd, expected_acks = absurd_uploads(items[0])
        stream = absurd + fuzz_stream + tail_requests()
        assert upload(gcs, items) == m.MAV_MISSION_ACCEPTED
        assert wait_until_accepted(gcs, m.MAV_CMD_DO_SET_MODE, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                   COPTER_GUIDED), "GUIDED refused"
        assert wait_until_accepted(gcs, m.MAV_CMD_COMPONENT_ARM_DISARM, 1), "could not arm"
        assert gcs.command(m.MAV_CMD_MISSION_START, 0, 0) == m.MAV_RESULT_ACCEPTED
        assert gcs.wait("HEARTBEAT", lambda h: h.custom_mode == COPTER_AUTO
                        and h.base_mode & MAV_MODE_FLAG_SAFETY_ARMED, 30, fresh=True) is not None

        fuzz = FuzzClient(sitl.port, stream, rng)
        fuzz.start()
        assert fuzz.done.wait(60), "the fuzz stream was not taken within 60 s"
        assert fuzz.error is None, f"fuzz link failed: {fuzz.error!r}"
        assert wait_until(lambda: "WPNAV_SPEED" in fuzz.param_values, 60), \
            "the autopilot never got through the fuzz stream"
        # the vehicle was still flying the mission when the autopilot had handled all of it
        hb = gcs.wait("HEARTBEAT", timeout_s=10, fresh=True)
        assert hb is not None and hb.custom_mode == COPTER_AUTO
        assert hb.base_mode & MAV_MODE_FLAG_SAFETY_ARMED, "mission over before the fuzz was sent"

        last = len(items) - 1
        assert gcs.wait("MISSION_ITEM_REACHED", lambda r: r.seq == last, 90) is not None, \
            "the mission never reached its last item"
        assert gcs.wait("HEARTBEAT", lambda h: not h.base_mode & MAV_MODE_FLAG_SAFETY_ARMED,
                        60) is not None, "never disarmed after landing"
        # the autopilot is alive and answering
        pid = sitl.child_pid("autopilot")
        assert pid is not None and _alive(pid)
        reply = None
        for _ in range(20):
            gcs.send("param_request_read_send", 1, 1, b"WPNAV_SPEED", -1)
            reply = gcs.wait("PARAM_VALUE", lambda p: p.param_id == "WPNAV_SPEED", 0.5)
            if reply is not None:
                break
        assert reply is not None and reply.param_value == 1000.0
    finally:
        if fuzz is not None:
            fuzz.close()
        if gcs is not None:
            gcs.close()
        sitl.stop()
    wall_s = time.monotonic() - t_start

    stats = json.loads((sitl.run_dir / "autopilot_stats.json").read_text())
    mav, node = stats["mavlink"], stats["node"]
    print(f"fuzz flight: {len(inputs)} inputs, {len(fuzz_stream)} bytes, {wall_s:.1f} s wall; "
          f"fuzz link: {fuzz.received_bytes} bytes back, mission acks {fuzz.mission_acks}; "
          f"mavlink {mav}; node {node}")
    assert fuzz.sent_bytes == len(stream)
    assert fuzz.mission_acks[:len(expected_acks)] == expected_acks, fuzz.mission_acks
    assert mav["handler_errors"] == 0 and mav["encode_errors"] == 0, mav
    assert node.get("worker_errors", 0) == 0, node
    assert mav["bad_crc"] > 1000 and mav["garbage_bytes"] > 10_000, mav
    assert mav["unknown"] > 0 and mav["parse_errors"] + mav["truncated"] > 0, mav
    assert mav["rx_msgs"] > N_PER_KIND and mav["ignored"] > 100, mav
    assert stats["mission_state"] == "COMPLETE" and not stats["armed"], stats

    events = sitl.events()
    assert "Mission complete" in events
    assert [f"Reached command #{i}" in events for i in range(1, len(LEGS_ENU) + 3)] == \
        [True] * (len(LEGS_ENU) + 2)                # the uploaded mission, every item
    assert not any(e.startswith("GCS Failsafe") for e in events), events
    assert any(e.startswith("disarmed") for e in events)
    # ground truth: on the planned path, no jumps, landed at the last waypoint
    truth = sitl.truth()
    t, x, y, z = truth["t_s"], truth["x_m"], truth["y_m"], truth["z_m"]
    path = [(0.0, 0.0), *LEGS_ENU]
    off = distance_to_path_m(x, y, path)
    assert off.max() < PATH_TOLERANCE_M, f"left the planned path by {off.max():.1f} m"
    assert z.max() < ALT_M + 1.5
    dt = np.diff(t)
    step = np.sqrt(np.diff(x) ** 2 + np.diff(y) ** 2 + np.diff(z) ** 2)
    ok = dt > 0
    assert np.all(step[ok] / dt[ok] < MAX_TRUTH_SPEED_M_S), "jump in the truth track"
    assert np.min(np.hypot(x - 30.0, y - 30.0)) < 2.0          # the far corner was flown
    end = final_position(truth)
    assert np.hypot(end[0] - LEGS_ENU[-1][0], end[1] - LEGS_ENU[-1][1]) < 2.0, end
    assert end[2] < 0.5


def wait_until_accepted(gcs: Gcs, command: int, *params: float) -> bool:
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        if gcs.command(command, *params) == gcs.m.MAV_RESULT_ACCEPTED:
            return True
        time.sleep(0.5)
    return False


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False
