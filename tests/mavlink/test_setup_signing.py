"""SETUP_SIGNING as ArduPilot handles it (MAVProxy's `signing setup`, QGC): the key is installed on
every link, kept in the key file for the next start, all zeros disable signing, refused when armed;
unsigned traffic is then dropped except what ArduPilot accepts unsigned."""

from __future__ import annotations

import json
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import command_ack, gcs_connection, running_server, wait_for

from autopilot_bridge.signing import signing_timestamp

M = mavlink2
KEY = bytes(range(1, 33))
ZERO = bytes(32)


def _signed_frame(msg) -> bool:
    """MAVLink 2 incompat flag SIGNED on the received frame (a client without the key does not
    verify, so pymavlink's get_signed() stays False)."""
    return bool(msg.get_msgbuf()[2] & M.MAVLINK_IFLAG_SIGNED)


def _setup(conn, key):
    conn.mav.setup_signing_send(1, 1, list(key), signing_timestamp(time.time()))  # as MAVProxy


def _ping(conn):
    conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 0, 0, 0, 0, 0, 0, 0, 0)
    return command_ack(conn, M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1.5)


def test_setup_signing_installs_persists_and_zero_key_disables(tmp_path):
    key_file = tmp_path / "instance0.json.signing.json"
    with running_server(signing_key_path=str(key_file)) as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        assert _ping(conn) is not None                  # no signing yet
        _setup(conn, KEY)                               # sent unsigned: accepted while signing is off
        assert wait_for(conn, "HEARTBEAT", 3.0, _signed_frame) is not None
        assert _ping(conn) is None                      # unsigned command now dropped
        assert server.stats["dropped_unsigned"] >= 1
        conn.setup_signing(KEY, sign_outgoing=True)
        assert _ping(conn) is not None
        assert json.loads(key_file.read_text())["secret_key_hex"] == KEY.hex()
        conn.close()
    with running_server(signing_key_path=str(key_file)) as (server, vehicle):   # the next start
        plain = gcs_connection(server.tcp_port)
        assert _ping(plain) is None
        plain.close()
        signed = gcs_connection(server.tcp_port)
        signed.setup_signing(KEY, sign_outgoing=True)
        assert _ping(signed) is not None
        _setup(signed, ZERO)                            # all zeros: signing off
        time.sleep(0.3)                                 # let it arrive
        signed.close()
        plain = gcs_connection(server.tcp_port)
        assert _ping(plain) is not None
        hb = wait_for(plain, "HEARTBEAT", 3.0)
        assert hb is not None and not _signed_frame(hb)
        plain.close()


def test_setup_signing_refused_when_armed(tmp_path):
    key_file = tmp_path / "key.json"
    with running_server(signing_key_path=str(key_file)) as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        vehicle.armed = True
        _setup(conn, KEY)
        text = wait_for(conn, "STATUSTEXT", 3.0, lambda m: "signing" in m.text)
        assert text is not None and text.text == "ERROR: Won't setup signing when armed"
        assert _ping(conn) is not None and not key_file.exists()
        conn.close()
