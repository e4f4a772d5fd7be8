"""Fuzz the server over TCP: it must keep answering and garbage must never reach the vehicle.

10,000+ inputs from ``mavlink_fuzzgen`` (shared with test_autopilot_fuzz_flight.py): random
bytes, bit flips in valid frames, truncated frames, and valid frames (correct CRC) of every known
message type with random field values including NaN/inf and extremes. Messages that may
legitimately move the vehicle are kept out of the valid-frame generator (SET_MODE, and
COMMAND_LONG/INT with a state-changing command id are re-rolled), so any vehicle call afterwards
would be a bug.
"""

from __future__ import annotations

import time

import numpy as np
from support.fake_vehicle import gcs_connection, running_server, wait_for
from support.mavlink_fuzzgen import build_inputs

from autopilot_bridge.modes import CopterMode

SEED = 20240601
N_PER_KIND = 2600  # four kinds -> 10,400 inputs


def test_fuzzed_input_never_breaks_the_server_or_moves_the_vehicle():
    rng = np.random.default_rng(SEED)
    inputs = build_inputs(rng, N_PER_KIND)
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
            # The reply may stem from a fuzzed PARAM_REQUEST_LIST still being answered: wait until
            # the server has read the whole stream before looking at its counters.
            deadline = time.monotonic() + 60.0
            while server.stats["rx_bytes"] < len(stream) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert server.stats["rx_bytes"] >= len(stream), server.stats
            time.sleep(0.5)                      # the poll that read the last bytes parses them
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
