"""Mission protocol: upload/download/clear/set-current over real TCP, validation, timeouts."""

from __future__ import annotations

import math
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import (
    HOME,
    FakeVehicle,
    gcs_connection,
    running_server,
    server_config,
    wait_for,
)

from autopilot_bridge.mavlink_server import MavlinkServer
from autopilot_bridge.mission import MissionResult, MissionType, decode_item
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.vehicle_interface import AltFrame, MavFrame, MissionCommand

M = mavlink2
REL = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def item_int(seq, command=M.MAV_CMD_NAV_WAYPOINT, frame=REL, lat=HOME[0], lon=HOME[1], alt=20.0,
             params=(0.0, 0.0, 0.0, 0.0), current=0, mission_type=0):
    return M.MAVLink_mission_item_int_message(
        1, 1, seq, frame, command, current, 1, *params, int(round(lat * 1e7)),
        int(round(lon * 1e7)), alt, mission_type)


def four_waypoints():
    home = item_int(0, frame=M.MAV_FRAME_GLOBAL, alt=HOME[2])
    wps = [item_int(i, lat=HOME[0] + 0.0005 * i, lon=HOME[1] - 0.0003 * i, alt=10.0 + i,
                    params=(float(i), 0.0, 0.0, math.nan))
           for i in range(1, 5)]
    return [home] + wps


def upload(conn, items, timeout_s=10.0, float_items=False):
    """Client side of the upload; returns the MISSION_ACK."""
    conn.mav.mission_count_send(1, 1, len(items), 0)
    while True:
        msg = wait_for(conn, ["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], timeout_s)
        if msg is None or msg.get_type() == "MISSION_ACK":
            return msg
        item = items[msg.seq]
        if float_items:
            conn.mav.send(M.MAVLink_mission_item_message(
                1, 1, item.seq, item.frame, item.command, item.current, item.autocontinue,
                item.param1, item.param2, item.param3, item.param4, item.x * 1e-7,
                item.y * 1e-7, item.z, item.mission_type))
        else:
            conn.mav.send(item)


def download(conn, use_int=True, mission_type=0):
    conn.mav.mission_request_list_send(1, 1, mission_type)
    count = wait_for(conn, "MISSION_COUNT")
    assert count is not None
    items = []
    for seq in range(count.count):
        if use_int:
            conn.mav.mission_request_int_send(1, 1, seq, mission_type)
            msg = wait_for(conn, "MISSION_ITEM_INT", condition=lambda m, s=seq: m.seq == s)
        else:
            conn.mav.mission_request_send(1, 1, seq, mission_type)
            msg = wait_for(conn, "MISSION_ITEM", condition=lambda m, s=seq: m.seq == s)
        assert msg is not None, seq
        items.append(msg)
    conn.mav.mission_ack_send(1, 1, 0, mission_type)
    return items


def test_upload_download_clear_over_tcp():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            sent = four_waypoints()
            ack = upload(conn, sent)
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            assert len(vehicle.mission) == 4
            assert [i.seq for i in vehicle.mission] == [1, 2, 3, 4]
            assert vehicle.mission[1].lat_deg == pytest.approx(HOME[0] + 0.001, abs=1e-7)
            assert vehicle.mission[1].alt_frame == AltFrame.RELATIVE_HOME

            got = download(conn)
            assert len(got) == 5
            home = got[0]
            assert home.x == int(round(HOME[0] * 1e7)) and home.frame == M.MAV_FRAME_GLOBAL
            for a, b in zip(sent[1:], got[1:], strict=False):
                assert (a.seq, a.frame, a.command, a.x, a.y) == \
                    (b.seq, b.frame, b.command, b.x, b.y)
                assert a.z == pytest.approx(b.z)
                assert a.param1 == b.param1 and math.isnan(b.param4)

            floats = download(conn, use_int=False)
            assert floats[2].x == pytest.approx(HOME[0] + 0.001, abs=1e-6)

            conn.mav.mission_clear_all_send(1, 1, 0)
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            assert vehicle.mission == ()
            assert len(download(conn)) == 1  # home only
        finally:
            conn.close()


def test_float_mission_item_upload_is_accepted():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            ack = upload(conn, four_waypoints(), float_items=True)
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            assert vehicle.mission[3].lat_deg == pytest.approx(HOME[0] + 0.002, abs=2e-6)
        finally:
            conn.close()


def test_bad_uploads_get_mission_ack_errors():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            conn.mav.mission_count_send(1, 1, 65535, 0)
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.NO_SPACE

            cases = [
                (item_int(1, lat=91.0), MissionResult.INVALID_PARAM5_X),
                (item_int(1, lon=-181.0), MissionResult.INVALID_PARAM6_Y),
                (item_int(1, alt=math.nan), MissionResult.INVALID_PARAM7),
                (item_int(1, params=(math.nan, 0, 0, 0)), MissionResult.INVALID_PARAM1),
                (item_int(1, params=(0, math.inf, 0, 0)), MissionResult.INVALID_PARAM2),
                # AP_Mission stores no MAV_CMD_USER_1, nor a waypoint in a local frame
                (item_int(1, command=M.MAV_CMD_USER_1), MissionResult.UNSUPPORTED),
                (item_int(1, frame=M.MAV_FRAME_LOCAL_NED), MissionResult.UNSUPPORTED_FRAME),
            ]
            for bad, expected in cases:
                items = four_waypoints()
                items[1] = bad
                ack = upload(conn, items)
                assert ack is not None and ack.type == expected, expected.name
            assert vehicle.mission == ()  # nothing stored by failed uploads

            # NaN latitude in a float MISSION_ITEM
            conn.mav.mission_count_send(1, 1, 2, 0)
            req = wait_for(conn, ["MISSION_REQUEST_INT", "MISSION_REQUEST"])
            assert req is not None and req.seq == 0
            conn.mav.mission_item_send(1, 1, 0, 0, 16, 0, 1, 0, 0, 0, 0, HOME[0], HOME[1], 0, 0)
            req = wait_for(conn, ["MISSION_REQUEST_INT", "MISSION_REQUEST"])
            assert req is not None and req.seq == 1
            conn.mav.mission_item_send(1, 1, 1, 3, 16, 0, 1, 0, 0, 0, 0, math.nan, HOME[1], 10, 0)
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.INVALID_PARAM5_X

            # out of sequence: INVALID_SEQUENCE, the upload goes on
            conn.mav.mission_count_send(1, 1, 2, 0)
            assert wait_for(conn, "MISSION_REQUEST_INT") is not None
            conn.mav.send(item_int(1))
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.INVALID_SEQUENCE
            conn.mav.send(item_int(0))
            conn.mav.send(item_int(1))
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            assert len(vehicle.mission) == 1
        finally:
            conn.close()


def test_fence_and_rally_start_empty_and_are_uploaded_by_type():
    """Their full round trip is in test_fence_rally_protocol.py."""
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            for mtype in (MissionType.FENCE, MissionType.RALLY):
                conn.mav.mission_request_list_send(1, 1, mtype)
                count = wait_for(conn, "MISSION_COUNT")
                assert count is not None and count.count == 0 and count.mission_type == mtype
                conn.mav.mission_count_send(1, 1, 3, mtype)
                req = wait_for(conn, "MISSION_REQUEST_INT")
                assert req is not None and (req.seq, req.mission_type) == (0, mtype)
                conn.mav.mission_count_send(1, 1, 0, mtype)     # restart empty: ends the upload
                ack = wait_for(conn, "MISSION_ACK")
                assert ack is not None and ack.type == MissionResult.ACCEPTED
                conn.mav.mission_clear_all_send(1, 1, mtype)
                ack = wait_for(conn, "MISSION_ACK")
                assert ack is not None and ack.type == MissionResult.ACCEPTED
        finally:
            conn.close()


def test_set_current_and_guided_waypoint():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            assert upload(conn, four_waypoints()).type == MissionResult.ACCEPTED
            conn.mav.mission_set_current_send(1, 1, 3)
            cur = wait_for(conn, "MISSION_CURRENT", condition=lambda m: m.seq == 3)
            assert cur is not None and cur.total == 4
            conn.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MISSION_CURRENT, 0,
                                       2, 0, 0, 0, 0, 0, 0)
            ack = wait_for(conn, "COMMAND_ACK")
            assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
            assert vehicle.mission_seq == 2
            conn.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MISSION_CURRENT, 0,
                                       9, 0, 0, 0, 0, 0, 0)
            ack = wait_for(conn, "COMMAND_ACK")
            assert ack is not None and ack.result == M.MAV_RESULT_DENIED

            # guided waypoint (current=2): refused outside GUIDED, a reposition inside
            conn.mav.send(item_int(0, current=2, alt=30.0))
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.ERROR
            vehicle.mode = CopterMode.GUIDED
            conn.mav.send(item_int(0, current=2, alt=30.0))
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            name, args = vehicle.calls[-1]
            assert name == "reposition" and args[2] == 30.0 and args[3] == AltFrame.RELATIVE_HOME
            assert len(vehicle.mission) == 4  # the stored mission is untouched
        finally:
            conn.close()


def _step(server, conn, t, k):
    """poll(t), then a TIMESYNC round trip at the same t: every message read before its echo
    was sent at time t, whatever the real-time delays (TCP keeps the order)."""
    server.poll(t)
    conn.mav.timesync_send(0, k)
    got = []
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        server.poll(t)
        while (msg := conn.recv_match(blocking=True, timeout=0.01)) is not None:
            if msg.get_type() == "TIMESYNC" and msg.ts1 == k:
                return got
            got.append(msg)
    raise AssertionError("no TIMESYNC echo")


def test_upload_retries_then_times_out_on_the_callers_clock():
    vehicle = FakeVehicle()
    server = MavlinkServer(vehicle, ParameterStore(), server_config())
    conn = gcs_connection(server.tcp_port)
    try:
        t = 100.0
        _step(server, conn, t, 1)  # accept the client
        conn.mav.mission_count_send(1, 1, 3, 0)
        seen = []
        for k in range(2, 50):
            seen += [(t, m) for m in _step(server, conn, t, k)
                     if m.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK")]
            t += 0.25
        reqs = [(when, m) for when, m in seen if m.get_type() == "MISSION_REQUEST_INT"]
        acks = [(when, m) for when, m in seen if m.get_type() == "MISSION_ACK"]
        # requested at once, then every second without an answer, until the 8 s timeout
        assert [when for when, _ in reqs] == [100.0 + i for i in range(8)]
        assert all(m.seq == 0 for _, m in reqs)
        assert len(acks) == 1 and acks[0][1].type == MissionResult.OPERATION_CANCELLED
        assert acks[0][0] == 108.0
        assert not server.missions.receiving
    finally:
        conn.close()
        server.close()


def test_decode_item_rules():
    ok, res = decode_item(item_int(1, params=(0, 0, 0, math.nan)), True)
    assert res == MissionResult.ACCEPTED and ok is not None and math.isnan(ok.param4)
    _, res = decode_item(item_int(1, command=M.MAV_CMD_DO_CHANGE_SPEED,
                                  params=(1, 5, -1, math.nan)), True)
    assert res == MissionResult.INVALID_PARAM4   # NaN param4 only for NAV commands
    speed, res = decode_item(item_int(1, command=M.MAV_CMD_DO_CHANGE_SPEED, frame=2, lat=0,
                                      lon=0, alt=math.nan, params=(1, 5, -1, 0)), True)
    assert res == MissionResult.ACCEPTED and speed is not None and speed.alt_m == 0.0
    _, res = decode_item(item_int(1, command=0), True)
    assert res == MissionResult.INVALID


def test_enum_values_match_mavlink():
    for r in MissionResult:
        assert r == getattr(M, f"MAV_MISSION_{r.name}"), r
    for f in MavFrame:
        assert f == getattr(M, f"MAV_FRAME_{f.name}"), f
    for c in MissionCommand:
        assert c == getattr(M, f"MAV_CMD_{c.name}"), c


def test_partial_write_replaces_and_appends_items():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            assert upload(conn, four_waypoints()).type == MissionResult.ACCEPTED
            conn.mav.mission_write_partial_list_send(1, 1, 3, 5, 0)   # replace 3, 4; append 5
            for expected_seq in (3, 4, 5):
                req = wait_for(conn, "MISSION_REQUEST_INT")
                assert req is not None and req.seq == expected_seq
                conn.mav.send(item_int(req.seq, alt=50.0 + req.seq))
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            assert [i.seq for i in vehicle.mission] == [1, 2, 3, 4, 5]
            assert [i.alt_m for i in vehicle.mission] == [11.0, 12.0, 53.0, 54.0, 55.0]
            conn.mav.mission_write_partial_list_send(1, 1, 4, 9, 0)   # beyond the end
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.ERROR
        finally:
            conn.close()
