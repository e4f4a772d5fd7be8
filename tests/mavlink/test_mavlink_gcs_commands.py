"""Issue 15, items 3 and 5-7 over real MAVLink bytes against the FakeVehicle: missions with every
command AP_Mission stores (DO_JUMP, loiters, conditions, camera and gimbal items, terrain frames)
uploaded and downloaded unchanged, the "change altitude" item, CONDITION_YAW, DO_SET_ROI_LOCATION /
DO_SET_ROI_NONE, DO_PAUSE_CONTINUE, DO_LAND_START and mode AUTO_RTL, NAV_TAKEOFF's param3, RC_CHANNELS_OVERRIDE and MANUAL_CONTROL
only from SYSID_MYGCS, and the RC_CHANNELS / SERVO_OUTPUT_RAW stream."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import HOME, command_ack, gcs_connection, running_server, wait_for
from test_mavlink_mission import download, item_int, upload

from autopilot_bridge.commands import MavResult
from autopilot_bridge.mission import MissionResult
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import AltFrame, VehicleTelemetry

M = mavlink2


def long_cmd(conn, command, *params):
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(1, 1, command, 0, *p)
    ack = command_ack(conn, command)
    assert ack is not None, f"no COMMAND_ACK for {command}"
    return ack.result


def test_missions_store_every_ap_mission_command_and_terrain_frames():
    items = [item_int(0, frame=M.MAV_FRAME_GLOBAL, alt=HOME[2]),
             item_int(1, command=M.MAV_CMD_NAV_TAKEOFF, lat=0, lon=0, alt=10),
             item_int(2, command=M.MAV_CMD_NAV_SPLINE_WAYPOINT),
             item_int(3, command=M.MAV_CMD_DO_JUMP, frame=M.MAV_FRAME_MISSION, lat=0, lon=0,
                      params=(2, -1, 0, 0)),
             item_int(4, command=M.MAV_CMD_NAV_LOITER_TURNS, params=(2, 0, -15, 0)),
             item_int(5, command=M.MAV_CMD_CONDITION_DISTANCE, frame=M.MAV_FRAME_MISSION,
                      lat=0, lon=0, params=(5, 0, 0, 0)),
             item_int(6, command=M.MAV_CMD_IMAGE_START_CAPTURE, frame=M.MAV_FRAME_MISSION,
                      lat=0, lon=0, params=(0, 2, 0, 0)),
             item_int(7, command=M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, frame=M.MAV_FRAME_MISSION,
                      lat=0, lon=0, params=(-45, 0, math.nan, math.nan)),
             item_int(8, frame=M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, alt=30.0),
             item_int(9, command=M.MAV_CMD_DO_LAND_START),
             item_int(10, command=M.MAV_CMD_NAV_LAND)]
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            ack = upload(conn, items)
            # the gimbal item's NaN params are refused as AP_Mission refuses NaN there
            assert ack is not None and ack.type == MissionResult.INVALID_PARAM3
            items[7] = item_int(7, command=M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
                                frame=M.MAV_FRAME_MISSION, lat=0, lon=0, params=(-45, 0, 0, 0))
            ack = upload(conn, items)
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            assert [i.command for i in vehicle.mission] == [m.command for m in items[1:]]
            back = download(conn)
            for sent, got in zip(items[1:], back[1:], strict=True):
                assert (got.command, got.frame, got.param1, got.param2, got.param3, got.x, got.y) \
                    == (sent.command, sent.frame, sent.param1, sent.param2, sent.param3, sent.x,
                        sent.y)
            # MAVProxy's `changealt`: MISSION_ITEM current=3, accepted and without effect (ArduCopter)
            calls = len(vehicle.moving_calls())
            conn.mav.mission_item_send(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                                       M.MAV_CMD_NAV_WAYPOINT, 3, 1, 0, 0, 0, 0, 0, 0, 30.0)
            ack = wait_for(conn, "MISSION_ACK")
            assert ack is not None and ack.type == MissionResult.ACCEPTED
            assert len(vehicle.moving_calls()) == calls and len(vehicle.mission) == 10
        finally:
            conn.close()


def test_condition_yaw_roi_pause_and_takeoff_param3():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            assert long_cmd(conn, M.MAV_CMD_CONDITION_YAW, 400, 10, 1, 0) == MavResult.FAILED
            assert long_cmd(conn, M.MAV_CMD_CONDITION_YAW, 90, 10, 1, 2) == MavResult.FAILED
            assert long_cmd(conn, M.MAV_CMD_CONDITION_YAW, 90, 10, -1, 1) == MavResult.ACCEPTED
            assert vehicle.calls[-1] == ("condition_yaw", (90.0, 10.0, -1, True))
            lat, lon = int(HOME[0] * 1e7) + 1000, int(HOME[1] * 1e7)
            conn.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                      M.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, 0, 0,
                                      lat, lon, 5.0)
            ack = command_ack(conn, M.MAV_CMD_DO_SET_ROI_LOCATION)
            assert ack is not None and ack.result == MavResult.ACCEPTED
            name, args = vehicle.calls[-1]
            assert name == "set_roi" and args[2:] == (5.0, AltFrame.RELATIVE_HOME)
            assert math.isclose(args[0], lat * 1e-7)
            assert long_cmd(conn, M.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, 95.0, 0, 0) == \
                MavResult.FAILED
            assert long_cmd(conn, M.MAV_CMD_DO_SET_ROI_NONE) == MavResult.ACCEPTED
            assert vehicle.calls[-1] == ("set_roi", (0.0, 0.0, 0.0, AltFrame.RELATIVE_HOME))
            # DO_PAUSE_CONTINUE: refused outside AUTO / GUIDED with ArduCopter's text
            assert long_cmd(conn, M.MAV_CMD_DO_PAUSE_CONTINUE, 0) == MavResult.FAILED
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "pause" in m.text)
            assert text is not None and text.text == "Failed to pause"
            assert long_cmd(conn, M.MAV_CMD_DO_PAUSE_CONTINUE, 2) == MavResult.DENIED
            vehicle.mode = CopterMode.GUIDED
            assert long_cmd(conn, M.MAV_CMD_DO_PAUSE_CONTINUE, 0) == MavResult.ACCEPTED
            assert vehicle.calls[-1] == ("pause_continue", (True,))
            assert long_cmd(conn, M.MAV_CMD_DO_PAUSE_CONTINUE, 1) == MavResult.ACCEPTED
            assert vehicle.calls[-1] == ("pause_continue", (False,))
            vehicle.armed = True
            long_cmd(conn, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 1, 0, 0, 0, 12.0)
            assert [c for c in vehicle.calls if c[0] == "takeoff"][-1][1] == (12.0, False)
        finally:
            conn.close()


def test_do_land_start_and_mode_27_report_auto_rtl_and_fail_without_a_landing_sequence():
    from autopilot_bridge.vehicle_interface import MissionCommand, MissionItem
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            assert long_cmd(conn, M.MAV_CMD_DO_LAND_START) == MavResult.FAILED
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "AUTO RTL" in m.text)
            full = "Mode change to AUTO RTL failed: No landing sequence found"
            assert text is not None and full.startswith(text.text) and len(text.text) >= 45
            vehicle.mission = (MissionItem(1, int(MissionCommand.NAV_TAKEOFF), 3, alt_m=10.0),
                               MissionItem(2, int(MissionCommand.DO_LAND_START), 3),
                               MissionItem(3, int(MissionCommand.NAV_LAND), 3))
            assert long_cmd(conn, M.MAV_CMD_DO_LAND_START) == MavResult.ACCEPTED
            assert vehicle.calls[-1] == ("jump_to_landing_sequence", ())
            hb = wait_for(conn, "HEARTBEAT", condition=lambda m: m.custom_mode == CopterMode.AUTO_RTL)
            assert hb is not None                          # QGC shows "Auto RTL"
            vehicle.mode = CopterMode.AUTO
            conn.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0,
                                       M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, CopterMode.AUTO_RTL, 0, 0, 0, 0, 0)
            ack = command_ack(conn, M.MAV_CMD_DO_SET_MODE)
            assert ack is not None and ack.result == MavResult.ACCEPTED
            assert vehicle.calls[-1] == ("set_mode", (CopterMode.AUTO_RTL,))
        finally:
            conn.close()


def test_rc_overrides_only_from_my_gcs_and_rc_telemetry():
    tel = VehicleTelemetry(rc_channels_pwm=(1500, 1500, 1300, 1500) + (0,) * 14,
                           servo_pwm=(1400, 1410, 1420, 1430))
    with running_server() as (server, vehicle):
        vehicle.telemetry = lambda: tel          # what the flight core reports
        other = gcs_connection(server.tcp_port, source_system=200)
        conn = gcs_connection(server.tcp_port)
        try:
            chans = [1500, 1500, 1300, 1500] + [65535] * 4 + [0] * 10
            other.mav.rc_channels_override_send(1, 1, *chans)
            other.mav.manual_control_send(1, 0, 0, 500, 0, 0)
            long_cmd(other, M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES)    # processed in order
            conn.mav.rc_channels_override_send(1, 1, *chans)
            conn.mav.manual_control_send(1, 100, -200, 500, 0, 0)
            conn.mav.manual_control_send(7, 100, -200, 500, 0, 0)     # not for us
            long_cmd(conn, M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES)
            rc = [c for c in vehicle.calls if c[0] in ("rc_channels_override", "manual_control")]
            assert rc == [("rc_channels_override", (tuple(chans),)),
                          ("manual_control", (100.0, -200.0, 500.0, 0.0))]
            assert server.stats["rc_not_my_gcs"] == 2
            conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_RC_CHANNELS, 5, 1)
            got = wait_for(conn, "RC_CHANNELS")
            assert got is not None and got.chancount == 4 and got.chan3_raw == 1300
            servo = wait_for(conn, "SERVO_OUTPUT_RAW")
            assert servo is not None and (servo.servo1_raw, servo.servo4_raw) == (1400, 1430)
        finally:
            conn.close()
            other.close()
