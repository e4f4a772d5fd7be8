"""Commands, modes, telemetry rates, setpoints, external navigation, events, UDP, signing."""

from __future__ import annotations

import math
import socket
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import (
    FakeVehicle,
    command_ack,
    drain,
    gcs_connection,
    running_server,
    server_config,
    wait_for,
)

from autopilot_bridge import telemetry
from autopilot_bridge.commands import MavResult
from autopilot_bridge.mavlink_server import MavlinkServer
from autopilot_bridge.modes import SUPPORTED_MODES, CopterMode, mode_from_name
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.signing import SigningConfig, signing_key
from autopilot_bridge.vehicle_interface import (
    LandedState,
    MavSeverity,
    MissionItemReachedEvent,
    MissionState,
    PositionTargetTypeMask,
    SensorFlag,
    SetpointKind,
    SpeedType,
    StatusTextEvent,
    SystemStatus,
    Vehicle,
    VehicleTelemetry,
)
from scenenav.core.contracts import GpsFixType

M = mavlink2
CUSTOM = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def long_cmd(conn, command, *params):
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(1, 1, command, 0, *p)
    ack = command_ack(conn, command)
    assert ack is not None, f"no COMMAND_ACK for {command}"
    return ack.result


# ----------------------------------------------------------------------------- enums


def test_enums_match_mavlink():
    for mode in CopterMode:
        assert M.enums["COPTER_MODE"][int(mode)].name == f"COPTER_MODE_{mode.name}", mode
    for pairs, prefix in ((MavSeverity, "MAV_SEVERITY_"), (LandedState, "MAV_LANDED_STATE_"),
                          (SystemStatus, "MAV_STATE_"), (MissionState, "MISSION_STATE_"),
                          (MavResult, "MAV_RESULT_")):
        for member in pairs:
            assert member == getattr(M, prefix + member.name), member
    for fix in GpsFixType:
        name = {"FIX_2D": "2D_FIX", "FIX_3D": "3D_FIX"}.get(fix.name, fix.name)
        assert fix == getattr(M, "GPS_FIX_TYPE_" + name), fix
    for speed in SpeedType:
        assert speed == getattr(M, "SPEED_TYPE_" + speed.name), speed
    for flag in PositionTargetTypeMask:
        assert flag == getattr(M, "POSITION_TARGET_TYPEMASK_" + flag.name), flag
    for flag in SensorFlag:
        name = {"GYRO_3D": "3D_GYRO", "ACCEL_3D": "3D_ACCEL", "MAG_3D": "3D_MAG"}.get(
            flag.name, flag.name)
        value = getattr(M, "MAV_SYS_STATUS_SENSOR_" + name, None) or getattr(
            M, "MAV_SYS_STATUS_" + name)
        assert flag == value, flag
    assert isinstance(FakeVehicle(), Vehicle)   # the fake implements the whole protocol
    assert mode_from_name("guided") == CopterMode.GUIDED
    assert {m.name for m in SUPPORTED_MODES} == {"STABILIZE", "ALT_HOLD", "GUIDED", "AUTO",
                                                 "LOITER", "RTL", "LAND", "POSHOLD", "BRAKE",
                                                 "CIRCLE", "SMART_RTL", "AUTO_RTL"}


# ----------------------------------------------------------------------------- arming & modes


def test_arm_refused_with_statustext_reason_then_forced():
    vehicle = FakeVehicle(prearm_failure="PreArm: EKF not healthy")
    with running_server(vehicle) as (server, _):
        conn = gcs_connection(server.tcp_port)
        try:
            assert long_cmd(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == MavResult.FAILED
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "PreArm" in m.text)
            assert text is not None and text.text == "PreArm: EKF not healthy"
            assert text.severity == M.MAV_SEVERITY_CRITICAL
            assert not vehicle.armed
            assert long_cmd(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196) == MavResult.ACCEPTED
            assert vehicle.armed
            hb = wait_for(conn, "HEARTBEAT",
                          condition=lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
            assert hb is not None
        finally:
            conn.close()


def test_arm_mode_takeoff_land_rtl():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            assert long_cmd(conn, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10) == MavResult.FAILED
            assert long_cmd(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == MavResult.ACCEPTED
            assert long_cmd(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, math.nan) == MavResult.DENIED
            assert long_cmd(conn, M.MAV_CMD_DO_SET_MODE, CUSTOM, CopterMode.GUIDED) == 0
            hb = wait_for(conn, "HEARTBEAT", condition=lambda m: m.custom_mode == 4)
            assert hb is not None and hb.base_mode & M.MAV_MODE_FLAG_GUIDED_ENABLED
            assert hb.base_mode & CUSTOM and hb.type == M.MAV_TYPE_QUADROTOR
            assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA
            assert long_cmd(conn, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, math.nan) == \
                MavResult.DENIED
            assert long_cmd(conn, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 12.5) == \
                MavResult.ACCEPTED
            assert vehicle.relative_alt_m == 12.5
            # COMMAND_INT takeoff must use a relative-altitude frame (ArduCopter)
            conn.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL, M.MAV_CMD_NAV_TAKEOFF, 0, 0,
                                      0, 0, 0, 0, 0, 0, 20.0)
            ack = command_ack(conn, M.MAV_CMD_NAV_TAKEOFF)
            assert ack is not None and ack.result == MavResult.DENIED
            gpi = wait_for(conn, "GLOBAL_POSITION_INT", condition=lambda m: m.relative_alt > 0)
            assert gpi is not None and gpi.relative_alt == 12500
            # disarm in flight is refused without force
            assert long_cmd(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == MavResult.FAILED
            assert long_cmd(conn, M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == MavResult.ACCEPTED
            assert vehicle.mode == CopterMode.RTL
            assert long_cmd(conn, M.MAV_CMD_NAV_LAND) == MavResult.ACCEPTED
            assert vehicle.mode == CopterMode.LAND
            assert long_cmd(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == MavResult.ACCEPTED
            assert not vehicle.armed
            assert long_cmd(conn, M.MAV_CMD_MISSION_START) == MavResult.FAILED  # no mission
            assert long_cmd(conn, 31999) == MavResult.UNSUPPORTED
        finally:
            conn.close()


def test_mode_changes_by_command_and_set_mode_message():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            conn.mav.set_mode_send(1, CUSTOM, CopterMode.LOITER)
            ack = command_ack(conn, M.MAV_CMD_DO_SET_MODE)
            assert ack is not None and ack.result == MavResult.ACCEPTED
            assert vehicle.mode == CopterMode.LOITER
            assert long_cmd(conn, M.MAV_CMD_DO_SET_MODE, CUSTOM, CopterMode.ACRO) == \
                MavResult.FAILED
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "ACRO" in m.text)
            assert text is not None
            assert long_cmd(conn, M.MAV_CMD_DO_SET_MODE, CUSTOM, 8) == MavResult.FAILED
            assert long_cmd(conn, M.MAV_CMD_DO_SET_MODE, 0, CopterMode.RTL) == MavResult.DENIED
            assert long_cmd(conn, M.MAV_CMD_DO_SET_MODE, CUSTOM, math.inf) == MavResult.DENIED
            # the vehicle refuses AUTO without a mission: FAILED + its reason
            assert long_cmd(conn, M.MAV_CMD_DO_SET_MODE, CUSTOM, CopterMode.AUTO) == \
                MavResult.FAILED
            assert wait_for(conn, "STATUSTEXT", condition=lambda m: "no mission" in m.text)
            assert long_cmd(conn, M.MAV_CMD_NAV_LOITER_UNLIM) == MavResult.ACCEPTED
            assert vehicle.mode == CopterMode.LOITER
        finally:
            conn.close()


def test_reposition_change_speed_and_messages():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            lat, lon = int(47.3985 * 1e7), int(8.5461 * 1e7)
            conn.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                      M.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, math.nan,
                                      lat, lon, 25.0)
            ack = command_ack(conn, M.MAV_CMD_DO_REPOSITION)
            assert ack is not None and ack.result == MavResult.DENIED  # not GUIDED, no flag
            conn.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                      M.MAV_CMD_DO_REPOSITION, 0, 0, 5.0, 1, 0, math.nan,
                                      lat, lon, 25.0)
            ack = command_ack(conn, M.MAV_CMD_DO_REPOSITION)
            assert ack is not None and ack.result == MavResult.ACCEPTED
            assert vehicle.mode == CopterMode.GUIDED
            name, args = vehicle.calls[-1]
            assert name == "reposition" and args[0] == pytest.approx(47.3985)
            assert args[2] == 25.0 and args[4] is None and args[5] is None  # speed 5 ignored
            assert long_cmd(conn, M.MAV_CMD_DO_REPOSITION, -1, 1, 0, 0, 47.0, 8.0, 10) == \
                MavResult.COMMAND_INT_ONLY
            assert long_cmd(conn, M.MAV_CMD_DO_CHANGE_SPEED, 1, 0) == MavResult.DENIED
            assert long_cmd(conn, M.MAV_CMD_DO_CHANGE_SPEED, 7, 5) == MavResult.DENIED
            assert long_cmd(conn, M.MAV_CMD_DO_CHANGE_SPEED, 1, 7.5) == MavResult.ACCEPTED
            assert vehicle.calls[-1] == ("change_speed", (SpeedType.GROUNDSPEED, 7.5))

            assert long_cmd(conn, M.MAV_CMD_REQUEST_MESSAGE,
                            M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == MavResult.ACCEPTED
            ver = wait_for(conn, "AUTOPILOT_VERSION")
            assert ver is not None
            for cap in ("MISSION_INT", "COMMAND_INT", "MAVLINK2", "PARAM_FLOAT", "FTP",
                        "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT"):
                assert ver.capabilities & getattr(M, "MAV_PROTOCOL_CAPABILITY_" + cap), cap
            assert ver.capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
            assert ver.capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
            assert ver.flight_sw_version >> 24 == 4
            assert long_cmd(conn, M.MAV_CMD_REQUEST_MESSAGE, 60000) == MavResult.DENIED
            assert long_cmd(conn, M.MAV_CMD_GET_HOME_POSITION) == MavResult.ACCEPTED
            home = wait_for(conn, "HOME_POSITION")
            assert home is not None and home.latitude == int(round(47.397742 * 1e7))
            assert long_cmd(conn, M.MAV_CMD_GET_MESSAGE_INTERVAL,
                            M.MAVLINK_MSG_ID_ATTITUDE) == MavResult.ACCEPTED
            interval = wait_for(conn, "MESSAGE_INTERVAL")
            assert interval is not None and interval.interval_us == 250000
            assert long_cmd(conn, M.MAV_CMD_SET_MESSAGE_INTERVAL, 99999, 1000) == MavResult.DENIED
            conn.mav.timesync_send(0, 123456)
            ts = wait_for(conn, "TIMESYNC", condition=lambda m: m.ts1 == 123456)
            assert ts is not None and ts.tc1 > 0
        finally:
            conn.close()


# ----------------------------------------------------------------------------- rates (fake clock)


class ClockedServer:
    """Server polled by the test on a fake clock; the vehicle's time_boot_ms follows it."""

    def __init__(self, vehicle: FakeVehicle | None = None, t0: float = 50.0) -> None:
        self.vehicle = vehicle or FakeVehicle()
        self.server = MavlinkServer(self.vehicle, ParameterStore(), server_config())
        self.t0 = self.t = t0

    def run_until(self, t_end: float, step_s: float = 0.01) -> None:
        k = 0
        start = self.t
        while (t := start + k * step_s) < t_end - 1e-9:
            self.poll_at(t)
            k += 1
        self.t = t_end

    def poll_at(self, t: float) -> None:
        self.vehicle.time_boot_ms = int(round((t - self.t0) * 1000))
        self.server.poll(t)

    def settle(self, conn, kind: str, command: int | None = None):
        """Poll at the current fake time until the client got a reply (real-time wait)."""
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            self.poll_at(self.t)
            msg = wait_for(conn, kind, timeout_s=0.02,
                           condition=None if command is None else lambda m: m.command == command)
            if msg is not None:
                return msg
        raise AssertionError(f"no {kind}")


def count_in(msgs, start_ms, end_ms):
    return sum(1 for m in msgs if start_ms <= m.time_boot_ms < end_ms)


def test_set_message_interval_changes_the_rate_on_the_callers_clock():
    cs = ClockedServer()
    conn = gcs_connection(cs.server.tcp_port)
    try:
        cs.run_until(cs.t0 + 5.0)                       # default ATTITUDE rate: 4 Hz
        conn.mav.command_long_send(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                   M.MAVLINK_MSG_ID_ATTITUDE, 100_000, 0, 0, 0, 0, 0)
        ack = cs.settle(conn, "COMMAND_ACK", M.MAV_CMD_SET_MESSAGE_INTERVAL)
        assert ack.result == MavResult.ACCEPTED
        cs.run_until(cs.t0 + 10.0)                      # now 10 Hz
        conn.mav.command_long_send(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                   M.MAVLINK_MSG_ID_ATTITUDE, -1, 0, 0, 0, 0, 0)
        cs.settle(conn, "COMMAND_ACK", M.MAV_CMD_SET_MESSAGE_INTERVAL)
        cs.run_until(cs.t0 + 13.0)                      # disabled
        attitude = drain(conn, "ATTITUDE")
        assert abs(count_in(attitude, 1000, 5000) - 16) <= 1
        assert abs(count_in(attitude, 6000, 10000) - 40) <= 1
        assert count_in(attitude, 10500, 13000) == 0
    finally:
        conn.close()
        cs.server.close()


def test_request_data_stream_legacy_rates():
    cs = ClockedServer()
    conn = gcs_connection(cs.server.tcp_port)
    try:
        cs.run_until(cs.t0 + 1.0)
        conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_POSITION, 2, 1)
        conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_EXTRA1, 10, 0)
        conn.mav.command_long_send(1, 1, M.MAV_CMD_GET_HOME_POSITION, 0, 0, 0, 0, 0, 0, 0, 0)
        cs.settle(conn, "COMMAND_ACK", M.MAV_CMD_GET_HOME_POSITION)
        start = cs.t
        cs.run_until(start + 6.0)
        t_ms = int(round((start - cs.t0) * 1000))
        gpi = drain(conn, "GLOBAL_POSITION_INT")
        assert abs(count_in(gpi, t_ms + 1000, t_ms + 5000) - 8) <= 1
        assert count_in(drain(conn, "ATTITUDE"), t_ms + 1, t_ms + 6000) == 0  # EXTRA1 stopped
    finally:
        conn.close()
        cs.server.close()


def test_scheduler_semantics():
    sched = telemetry.TelemetryScheduler()
    att = M.MAVLINK_MSG_ID_ATTITUDE
    assert sched.interval_us(att) == 250000
    assert sched.set_interval_us(att, 0.0) and sched.interval_us(att) == 250000
    assert not sched.set_interval_us(att, -5)
    assert not sched.set_interval_us(att, math.nan)
    assert sched.set_interval_us(att, 1.0) and sched.interval_s(att) == sched.MIN_INTERVAL_S
    assert sched.set_interval_us(att, -1) and sched.interval_us(att) == -1
    assert not sched.set_stream_rate(99, 1.0)
    assert sched.set_stream_rate(telemetry.DataStream.ALL, 0) and sched.interval_s(
        M.MAVLINK_MSG_ID_SYS_STATUS) is None
    assert sched.interval_s(M.MAVLINK_MSG_ID_HEARTBEAT) == 1.0


def test_encoders_survive_absurd_telemetry():
    weird = VehicleTelemetry(
        time_boot_ms=-5, lat_deg=math.nan, lon_deg=math.inf, alt_amsl_m=-math.inf,
        relative_alt_m=1e30, position_ned_m=(math.nan, math.inf, -1e40),
        velocity_ned_m_s=(1e9, -1e9, math.nan), attitude_rpy_rad=(math.nan,) * 3,
        heading_deg=math.nan, groundspeed_m_s=math.inf, throttle_pct=500, gps_satellites=-3,
        gps_hdop=math.inf, battery_voltage_v=1e9, battery_current_a=math.nan,
        battery_remaining_pct=400, home_set=True, home_lat_deg=100.0, origin_set=True,
        origin_lat_deg=math.nan, origin_lon_deg=1e9, origin_alt_amsl_m=-math.inf, mission_current_seq=-1,
        ekf_flags=1 << 40, sensors_present=-1, cpu_load_pct=math.nan,
        imu_accel_frd_m_s2=(math.inf, -1e9, math.nan), vibration_m_s2=(math.nan, -1.0, 1e40),
        accel_clipping=(-5, 2 ** 40, 0), target_position_ned_m=(math.nan, math.inf, 1e40),
        target_lat_deg=math.nan, target_lon_deg=1e9, target_alt_amsl_m=math.inf,
        flow_fitted=True, flow_time_us=-5, flow_rate_frd_rad_s=(math.nan, math.inf),
        flow_comp_frd_m_s=(1e40, -math.inf), flow_quality=999, rangefinder_distance_m=1e40)
    mav = M.MAVLink(None, 1, 1)
    ctx = telemetry.EncodeContext(mission_item_count=3, battery_monitor=4)
    for msg_id in telemetry.STREAMABLE_MSG_IDS:
        msg = telemetry.encode(msg_id, weird, ctx)
        assert msg is not None
        buf = msg.pack(mav)
        assert mav.decode(bytearray(buf)).get_msgId() == msg_id
    texts = telemetry.statustext_messages(6, "x" * 120, 7)
    assert [len(t.text) for t in texts] == [50, 50, 20] and {t.id for t in texts} == {7}


# ----------------------------------------------------------------------------- guided / vision


def test_setpoints_only_in_guided_and_only_when_valid():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            vel_only = int(PositionTargetTypeMask.X_IGNORE | PositionTargetTypeMask.Y_IGNORE
                           | PositionTargetTypeMask.Z_IGNORE | PositionTargetTypeMask.AX_IGNORE
                           | PositionTargetTypeMask.AY_IGNORE | PositionTargetTypeMask.AZ_IGNORE
                           | PositionTargetTypeMask.YAW_IGNORE)
            args = (0, 1, 1, M.MAV_FRAME_LOCAL_NED, vel_only, 0, 0, 0, 1.0, -2.0, 0.5,
                    0, 0, 0, 0, 0.1)
            conn.mav.set_position_target_local_ned_send(*args)       # not GUIDED: ignored
            assert long_cmd(conn, M.MAV_CMD_DO_SET_MODE, CUSTOM, CopterMode.GUIDED) == 0
            conn.mav.set_position_target_local_ned_send(*args)       # accepted
            bad = list(args)
            bad[8] = math.nan
            conn.mav.set_position_target_local_ned_send(*bad)        # NaN velocity
            bad = list(args)
            bad[3] = M.MAV_FRAME_GLOBAL
            conn.mav.set_position_target_local_ned_send(*bad)        # wrong frame
            conn.mav.set_position_target_global_int_send(
                0, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b110111111000,
                int(47.4 * 1e7), int(8.55 * 1e7), 30.0, 0, 0, 0, 0, 0, 0, 0, 0)
            conn.mav.set_position_target_global_int_send(
                0, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b110111111000,
                int(95 * 1e7), int(8.55 * 1e7), 30.0, 0, 0, 0, 0, 0, 0, 0, 0)
            assert long_cmd(conn, M.MAV_CMD_GET_HOME_POSITION) == 0  # sync point
            setpoints = [c for c in vehicle.calls if c[0].startswith("set_position_target")]
            assert len(setpoints) == 2
            local = setpoints[0][1][0]
            assert local.kind == SetpointKind.VELOCITY and local.velocity_m_s == (1.0, -2.0, 0.5)
            assert math.isnan(local.position_m[0]) and local.yaw_rad is None
            assert local.yaw_rate_rad_s == pytest.approx(0.1)
            glob = setpoints[1][1][0]
            assert glob.kind == SetpointKind.POSITION and glob.lat_deg == pytest.approx(47.4)
            assert server.stats["setpoints_ignored"] == 1
            assert server.stats["setpoints_rejected"] == 3
        finally:
            conn.close()


def test_vision_messages_need_viso_type():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            cov = [0.0] * 21
            conn.mav.vision_position_estimate_send(1000, 1.0, 2.0, -3.0, 0.0, 0.0, 0.5, cov, 0)
            assert long_cmd(conn, M.MAV_CMD_GET_HOME_POSITION) == 0
            assert vehicle.vision == [] and server.stats["vision_ignored"] == 1
            conn.mav.param_set_send(1, 1, b"VISO_TYPE", 1, M.MAV_PARAM_TYPE_INT8)
            assert wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "VISO_TYPE")
            conn.mav.vision_position_estimate_send(2000, 1.0, 2.0, -3.0, 0.0, 0.0, 0.5, cov, 0)
            conn.mav.vision_position_estimate_send(3000, math.nan, 2.0, -3.0, 0, 0, 0.5, cov, 0)
            conn.mav.odometry_send(4000, M.MAV_FRAME_LOCAL_FRD, M.MAV_FRAME_BODY_FRD,
                                   1.0, 2.0, -3.0, [1, 0, 0, 0], 0.1, 0, 0, 0, 0, 0,
                                   [math.nan] * 21, [math.nan] * 21, 0, 0, 90)
            assert long_cmd(conn, M.MAV_CMD_GET_HOME_POSITION) == 0
            assert vehicle.vision[0] == (2000, 1.0, 2.0, -3.0, 0.0, 0.0, 0.5)
            assert vehicle.vision[1][0] == "odometry"
            assert vehicle.vision[1][1].position_m == (1.0, 2.0, -3.0)
            assert len(vehicle.vision) == 2 and server.stats["vision_rejected"] == 1
        finally:
            conn.close()


# ----------------------------------------------------------------------------- events, links


def test_vehicle_events_heartbeat_tracking_and_multiple_clients():
    with running_server() as (server, vehicle):
        a = gcs_connection(server.tcp_port)
        b = gcs_connection(server.tcp_port, source_system=245)
        try:
            a.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            b.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            assert wait_for(a, "HEARTBEAT") and wait_for(b, "HEARTBEAT")
            vehicle.push_event(StatusTextEvent(MavSeverity.WARNING, "Battery low " + "z" * 60))
            vehicle.push_event(MissionItemReachedEvent(3))
            for conn in (a, b):
                first = wait_for(conn, "STATUSTEXT", condition=lambda m: "Battery" in m.text)
                assert first is not None and first.id != 0 and first.chunk_seq == 0
                reached = wait_for(conn, "MISSION_ITEM_REACHED")
                assert reached is not None and reached.seq == 3
            deadline = time.monotonic() + 5
            while server.last_gcs_heartbeat_s is None and time.monotonic() < deadline:
                time.sleep(0.01)
            assert server.last_gcs_heartbeat_s is not None       # sysid 255 = SYSID_MYGCS
            assert server.last_any_gcs_heartbeat_s is not None
            assert server.tcp_client_count == 2
        finally:
            a.close()
            b.close()


def test_udp_target_and_udp_peers():
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.2)
    try:
        with running_server(udp_target_port=gcs.getsockname()[1], tcp_enabled=False) as (
                server, vehicle):
            parser = M.MAVLink(None, 255, 190)
            got = _udp_collect(gcs, parser, "HEARTBEAT")
            assert got is not None                               # telemetry to the target
            # a peer that writes to the server's UDP port gets answers
            peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            peer.settimeout(0.2)
            try:
                req = M.MAVLink_param_request_read_message(1, 1, b"RTL_ALT", -1).pack(parser)
                peer.sendto(req, ("127.0.0.1", server.udp_port))
                msg = _udp_collect(peer, M.MAVLink(None, 255, 190), "PARAM_VALUE")
                assert msg is not None and msg.param_id == "RTL_ALT"
                assert server.stats["udp_peers"] == 1
            finally:
                peer.close()
    finally:
        gcs.close()


def _udp_collect(sock, parser, kind, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            data = sock.recv(65536)
        except socket.timeout:
            continue
        for msg in parser.parse_buffer(data) or []:
            if msg.get_type() == kind:
                return msg
    return None


# ----------------------------------------------------------------------------- signing


def test_signing_refuses_unsigned_and_badly_signed_frames():
    cfg = SigningConfig(enabled=True, passphrase="scenenav-test")
    with running_server(signing=cfg) as (server, vehicle):
        good = gcs_connection(server.tcp_port)
        plain = gcs_connection(server.tcp_port, source_system=254)
        wrong = gcs_connection(server.tcp_port, source_system=253)
        try:
            good.setup_signing(signing_key(cfg), sign_outgoing=True)
            wrong.setup_signing(b"\x01" * 32, sign_outgoing=True)
            hb = wait_for(good, "HEARTBEAT")
            assert hb is not None and hb._signed                  # outgoing frames are signed
            good.mav.param_request_read_send(1, 1, b"WPNAV_SPEED", -1)
            assert wait_for(good, "PARAM_VALUE") is not None
            plain.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                        1, 0, 0, 0, 0, 0, 0)
            wrong.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                        1, 0, 0, 0, 0, 0, 0)
            plain.mav.radio_status_send(200, 180, 50, 10, 10, 0, 0)  # accepted unsigned
            good.mav.param_request_read_send(1, 1, b"RTL_ALT", -1)   # sync point
            assert wait_for(good, "PARAM_VALUE", condition=lambda m: m.param_id == "RTL_ALT")
            assert not vehicle.armed and vehicle.moving_calls() == []
            assert server.stats["dropped_unsigned"] >= 1
            assert server.stats["bad_signature"] >= 1
        finally:
            for conn in (good, plain, wrong):
                conn.close()


def test_signing_config_validation():
    from scenenav.core.config import ConfigError
    with pytest.raises(ConfigError):
        SigningConfig(enabled=True)
    with pytest.raises(ConfigError):
        SigningConfig(enabled=True, key_hex="abcd")
    key = SigningConfig(enabled=True, key_hex="11" * 32)
    assert signing_key(key) == b"\x11" * 32


# ----------------------------------------------------------------------------- failure modes


class BrokenVehicle(FakeVehicle):
    """A vehicle whose telemetry raises: the server must log, count and keep going."""

    def telemetry(self) -> VehicleTelemetry:
        raise RuntimeError("flight core bug")


def test_poll_never_raises_when_the_vehicle_does():
    server = MavlinkServer(BrokenVehicle(), ParameterStore(), server_config())
    conn = gcs_connection(server.tcp_port)
    try:
        for k in range(20):
            server.poll(10.0 + 0.1 * k)
        conn.mav.param_request_read_send(1, 1, b"RTL_ALT", -1)
        deadline = time.monotonic() + 10
        reply = None
        while reply is None and time.monotonic() < deadline:
            server.poll(20.0)
            reply = wait_for(conn, "PARAM_VALUE", timeout_s=0.05)
        assert reply is not None and reply.param_id == "RTL_ALT"
        assert server.stats["handler_errors"] > 0
    finally:
        conn.close()
        server.close()


def test_busy_port_is_a_user_error_and_client_limit_holds():
    from scenenav.core.errors import UserError
    with running_server(tcp_max_clients=1) as (server, vehicle):
        with pytest.raises(UserError, match="cannot open endpoint"):
            MavlinkServer(FakeVehicle(), ParameterStore(),
                          server_config(tcp_port=server.tcp_port))
        first = gcs_connection(server.tcp_port)
        try:
            assert wait_for(first, "HEARTBEAT") is not None
            second = socket.create_connection(("127.0.0.1", server.tcp_port), timeout=5)
            try:
                second.settimeout(5)
                assert second.recv(100) == b""          # accepted and closed at once
            finally:
                second.close()
            assert server.stats["tcp_refused"] == 1 and server.tcp_client_count == 1
        finally:
            first.close()
