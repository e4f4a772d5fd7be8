"""Fence and rally upload / download over real MAVLink bytes (pymavlink's mission protocol with
mission_type FENCE and RALLY), and the capability bits QGC's Plan view looks for."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import command_ack, gcs_connection, running_server, wait_for

from autopilot_bridge.geofence import FenceCommand
from autopilot_bridge.mission import MissionResult, MissionType

M = mavlink2
SQUARE = [(47.0, 8.0), (47.0, 8.001), (47.001, 8.001), (47.001, 8.0)]


def _upload(conn, mtype, items, use_int=True):
    conn.mav.mission_count_send(1, 1, len(items), mtype)
    while True:
        req = wait_for(conn, ["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], 5.0)
        assert req is not None
        if req.get_type() == "MISSION_ACK":
            return req
        assert req.mission_type == mtype
        cmd, p1, lat, lon, alt, frame = items[req.seq]
        if use_int:
            conn.mav.mission_item_int_send(1, 1, req.seq, frame, cmd, 0, 1, p1, 0, 0, 0,
                                           int(lat * 1e7), int(lon * 1e7), alt, mtype)
        else:
            conn.mav.mission_item_send(1, 1, req.seq, frame, cmd, 0, 1, p1, 0, 0, 0,
                                       lat, lon, alt, mtype)


def _download(conn, mtype):
    conn.mav.mission_request_list_send(1, 1, mtype)
    count = wait_for(conn, "MISSION_COUNT", 5.0, lambda m: m.mission_type == mtype)
    items = []
    for seq in range(count.count):
        conn.mav.mission_request_int_send(1, 1, seq, mtype)
        items.append(wait_for(conn, "MISSION_ITEM_INT", 5.0, lambda m, s=seq: m.seq == s))
    conn.mav.mission_ack_send(1, 1, 0, mtype)
    return items


def test_fence_and_rally_round_trip_and_clear():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        fence = [(FenceCommand.POLYGON_VERTEX_INCLUSION, 4, lat, lon, 0.0, M.MAV_FRAME_GLOBAL)
                 for lat, lon in SQUARE]
        fence.append((FenceCommand.CIRCLE_EXCLUSION, 15.0, 47.0005, 8.0005, 0.0, M.MAV_FRAME_GLOBAL))
        ack = _upload(conn, MissionType.FENCE, fence)
        assert (ack.type, ack.mission_type) == (MissionResult.ACCEPTED, MissionType.FENCE)
        rally = [(FenceCommand.RALLY_POINT, 0, 47.0008, 8.0002, 20.0,
                  M.MAV_FRAME_GLOBAL_RELATIVE_ALT)]
        ack = _upload(conn, MissionType.RALLY, rally, use_int=False)
        assert (ack.type, ack.mission_type) == (MissionResult.ACCEPTED, MissionType.RALLY)
        got = _download(conn, MissionType.FENCE)
        assert [m.command for m in got] == [5001] * 4 + [5004]
        assert got[4].param1 == 15.0 and got[1].y == 80010000
        assert [m.command for m in _download(conn, MissionType.RALLY)] == [5100]
        fences = [args[0] for name, args in vehicle.calls if name == "fence_changed"]
        assert len(fences) == 1 and len(fences[0]) == 5
        # a mission command in a fence upload is refused
        bad = _upload(conn, MissionType.FENCE, [(16, 0, 47.0, 8.0, 0.0, M.MAV_FRAME_GLOBAL)])
        assert bad.type == MissionResult.UNSUPPORTED
        conn.mav.mission_clear_all_send(1, 1, MissionType.ALL)
        assert wait_for(conn, "MISSION_ACK", 5.0).type == MissionResult.ACCEPTED
        assert _download(conn, MissionType.FENCE) == [] and _download(conn, MissionType.RALLY) == []
        conn.close()


def test_autopilot_version_claims_fence_and_rally():
    with running_server() as (server, _):
        conn = gcs_connection(server.tcp_port)
        conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                   M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)
        assert command_ack(conn, M.MAV_CMD_REQUEST_MESSAGE).result == 0
        caps = wait_for(conn, "AUTOPILOT_VERSION", 5.0).capabilities
        assert caps & M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
        assert caps & M.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
        conn.close()


def test_do_fence_enable_command_reaches_the_vehicle_and_bad_actions_fail():
    """MAV_CMD_DO_FENCE_ENABLE as QGC's and MAVProxy's `fence enable` send it: param1 the action,
    param2 the FENCE_TYPE mask; a non-integral action is FAILED before the vehicle sees it."""
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        cmd = M.MAV_CMD_DO_FENCE_ENABLE
        results = []
        for p1, p2 in ((1, 0), (2, 0), (0, 4), (7, 0), (0.5, 0)):
            conn.mav.command_long_send(1, 1, cmd, 0, p1, p2, 0, 0, 0, 0, 0)
            results.append(command_ack(conn, cmd).result)
        assert results == [M.MAV_RESULT_ACCEPTED] * 3 + [M.MAV_RESULT_FAILED] * 2
        calls = [args for name, args in vehicle.calls if name == "fence_enable"]
        assert calls == [(1, 0), (2, 0), (0, 4), (7, 0)]
        conn.close()
