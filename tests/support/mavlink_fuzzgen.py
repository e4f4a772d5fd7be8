"""Fuzz inputs for the MAVLink server (shared by test_mavlink_fuzz.py and
test_autopilot_fuzz_flight.py).

Four kinds, ``n_per_kind`` of each, shuffled: random bytes (half of them starting with a MAVLink
magic byte), valid frames with 1-3 flipped bits, truncated valid frames, and valid frames (correct
CRC) of every known message type with random field values including NaN/inf and extremes.
Messages that a ground station sends on purpose to change the flight are kept out of the
valid-frame generator: the ``excluded_types`` and COMMAND_LONG/INT whose command is in
``STATE_CHANGING_COMMANDS`` (re-rolled).
"""

from __future__ import annotations

import math
import struct

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

M = mavlink2

STATE_CHANGING_COMMANDS = frozenset({
    M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND,
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_DO_SET_MODE,
    M.MAV_CMD_MISSION_START, M.MAV_CMD_DO_SET_MISSION_CURRENT, M.MAV_CMD_DO_REPOSITION,
    M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_CMD_CONDITION_YAW, M.MAV_CMD_DO_SET_ROI_LOCATION,
    M.MAV_CMD_DO_SET_ROI, M.MAV_CMD_DO_SET_ROI_NONE, M.MAV_CMD_DO_PAUSE_CONTINUE,
    M.MAV_CMD_DO_SET_HOME, M.MAV_CMD_SET_EKF_SOURCE_SET, M.MAV_CMD_PREFLIGHT_STORAGE,
})
# what the server-only fuzz leaves out (the fake vehicle records mission changes separately);
# RC overrides and MANUAL_CONTROL are the pilot's sticks: deliberate input that flies the vehicle;
# SETUP_SIGNING installs its (random) key: a deliberate change of the link, like a mode change
EXCLUDED_TYPES = frozenset({"SET_MODE", "MISSION_SET_CURRENT", "RC_CHANNELS_OVERRIDE",
                            "MANUAL_CONTROL", "SETUP_SIGNING"})
# in flight, mission uploads and clears are deliberate ground-station actions too
FLIGHT_EXCLUDED_TYPES = EXCLUDED_TYPES | frozenset({
    "MISSION_COUNT", "MISSION_CLEAR_ALL", "MISSION_WRITE_PARTIAL_LIST"})

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


def random_message(rng: np.random.Generator, classes: list) -> mavlink2.MAVLink_message:
    """One message of a random class in ``classes`` with random field values."""
    cls = classes[int(rng.integers(len(classes)))]
    values = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=False):
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


def build_inputs(rng: np.random.Generator, n_per_kind: int,
                 excluded_types: frozenset[str] = EXCLUDED_TYPES,
                 source_system: int = 255, source_component: int = 190) -> list[bytes]:
    """``4 * n_per_kind`` fuzz inputs in random order (see the module docstring)."""
    classes = [c for c in M.mavlink_map.values() if c.msgname not in excluded_types]
    mav = M.MAVLink(None, source_system, source_component)

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
    for _ in range(n_per_kind):
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
