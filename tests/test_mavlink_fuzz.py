"""Fuzz the server over TCP: it must keep answering and garbage must never reach the vehicle.

10,000+ inputs: random bytes, bit flips in valid frames, truncated frames, and valid frames
(correct CRC) of every known message type with random field values including NaN/inf and
extremes. Messages that may legitimately move the vehicle are kept out of the valid-frame
generator (SET_MODE, and COMMAND_LONG/INT with a state-changing command id are re-rolled), so
any vehicle call afterwards would be a bug.
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np
from fake_vehicle import gcs_connection, running_server, wait_for
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.modes import CopterMode

M = mavlink2
SEED = 20240601
N_PER_KIND = 2600  # four kinds -> 10,400 inputs

STATE_CHANGING_COMMANDS = frozenset({
    M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_DO_SET_MODE,
    M.MAV_CMD_MISSION_START, M.MAV_CMD_DO_SET_MISSION_CURRENT, M.MAV_CMD_DO_REPOSITION,
    M.MAV_CMD_DO_CHANGE_SPEED,
})
EXCLUDED_TYPES = frozenset({"SET_MODE", "MISSION_SET_CURRENT"})

_INT_RANGES = {
    "uint8_t": (0, 2 ** 8 - 1), "int8_t": (-(2 ** 7), 2 ** 7 - 1),
    "uint16_t": (0, 2 ** 16 - 1), "int16_t": (-(2 ** 15), 2 ** 15 - 1),
    "uint32_t": (0, 2 ** 32 - 1), "int32_t": (-(2 ** 31), 2 ** 31 - 1),
    "uint64_t": (0, 2 ** 64 - 1), "int64_t": (-(2 ** 63), 2 ** 63 - 1),
}
_FLOAT_SPECIALS = (math.nan, math.inf, -math.inf, 0.0, 1.0, -1.0, 3.4e38, -3.4e38)


def _scalar(rng: np.random.Generator, ftype: str, name: str):
    if ftype in ("float", "double"):
        if rng.random() < 0.5:
            return _FLOAT_SPECIALS[int(rng.integers(len(_FLOAT_SPECIALS)))]
        return float(rng.uniform(-1e6, 1e6))
    if name == "target_system":
        return (0, 1, 1, int(rng.integers(256)))[int(rng.integers(4))]
    if name == "target_component":
        return (0, 1, int(rng.integers(256)))[int(rng.integers(3))]
    lo, hi = _INT_RANGES[ftype]
    pick = rng.random()
    if pick < 0.2:
        return lo
    if pick < 0.4:
        return hi
    if pick < 0.6:
        return int(rng.integers(0, 3))
    return int(rng.integers(max(lo, -(2 ** 62)), min(hi, 2 ** 62)))


def random_message(rng: np.random.Generator, classes: list) -> mavlink2.MAVLink_message | None:
    cls = classes[int(rng.integers(len(classes)))]
    values = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
        length = cls.array_lengths[cls.ordered_fieldnames.index(name)]
        if ftype == "char":
            n = int(rng.integers(0, max(length, 1) + 1))
            values.append(bytes(rng.integers(0, 256, n, dtype=np.uint8)))
        elif length:
            values.append([_scalar(rng, ftype, name) for _ in range(length)])
        else:
            values.append(_scalar(rng, ftype, name))
    msg = cls(*values)
    if msg.get_type() in ("COMMAND_LONG", "COMMAND_INT"):
        while msg.command in STATE_CHANGING_COMMANDS:
            msg.command = int(rng.integers(0, 2 ** 16))
    return msg


def build_inputs(rng: np.random.Generator) -> list[bytes]:
    classes = [c for c in M.mavlink_map.values()
               if c.msgname not in EXCLUDED_TYPES]
    mav = M.MAVLink(None, 255, 190)

    def valid_frame() -> bytes:
        while True:
            msg = random_message(rng, classes)
            try:
                buf = msg.pack(mav)
            except (struct.error, ValueError, TypeError, OverflowError):
                continue  # some random values do not fit their field; try another
            mav.seq = (mav.seq + 1) % 256
            return buf

    inputs: list[bytes] = []
    for _ in range(N_PER_KIND):
        # 1. random bytes, sometimes starting with a MAVLink magic byte
        junk = bytearray(rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8))
        if rng.random() < 0.5:
            junk[0] = 0xFD if rng.random() < 0.7 else 0xFE
        inputs.append(bytes(junk))
        # 2. bit flips in a valid frame
        frame = bytearray(valid_frame())
        for _ in range(int(rng.integers(1, 4))):
            bit = int(rng.integers(len(frame) * 8))
            frame[bit // 8] ^= 1 << (bit % 8)
        inputs.append(bytes(frame))
        # 3. truncated valid frame
        frame = valid_frame()
        inputs.append(frame[:int(rng.integers(1, len(frame)))])
        # 4. valid frame (good CRC) with random field values
        inputs.append(valid_frame())
    order = rng.permutation(len(inputs))
    return [inputs[i] for i in order]


def test_fuzzed_input_never_breaks_the_server_or_moves_the_vehicle():
    rng = np.random.default_rng(SEED)
    inputs = build_inputs(rng)
    assert len(inputs) >= 10_000
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            stream = b"".join(inputs)
            pos = 0
            while pos < len(stream):
                size = int(rng.integers(1, 4096))
                conn.write(stream[pos:pos + size])
                pos += size
                while conn.recv_match(blocking=False) is not None:  # keep our side drained
                    pass
            # like a real GCS: repeat the request until answered
            reply = None
            deadline = time.monotonic() + 30.0
            while reply is None and time.monotonic() < deadline:
                conn.mav.param_request_read_send(1, 1, b"WPNAV_SPEED", -1)
                reply = wait_for(conn, "PARAM_VALUE", timeout_s=0.5,
                                 condition=lambda m: m.param_id == "WPNAV_SPEED")
            assert reply is not None, f"server stopped answering: {server.stats}"
            assert reply.param_value == 1000.0
            stats = dict(server.stats)
        finally:
            conn.close()
    assert stats["handler_errors"] == 0, stats
    assert stats["encode_errors"] == 0, stats
    assert stats["bad_crc"] > 1000 and stats["garbage_bytes"] > 0, stats
    assert stats["rx_msgs"] > N_PER_KIND, stats      # the valid frames were decoded
    assert vehicle.moving_calls() == []
    assert not vehicle.armed and vehicle.mode == CopterMode.STABILIZE
    assert vehicle.relative_alt_m == 0.0
