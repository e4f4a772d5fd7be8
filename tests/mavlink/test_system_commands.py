"""System commands over real MAVLink bytes (pymavlink client, FakeVehicle): RUN_PREARM_CHECKS,
DO_SET_HOME, PREFLIGHT_STORAGE, answered as ArduCopter (autopilot_bridge.system_commands)."""

from __future__ import annotations

import json

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import FakeVehicle, command_ack, gcs_connection, running_server, wait_for

from autopilot_bridge.commands import MavResult
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.vehicle_interface import AltFrame, HomeLocation

M = mavlink2


def _long(conn, command, *params):
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(1, 1, command, 0, *p)
    ack = command_ack(conn, command)
    assert ack is not None, command
    return ack.result


def _statustext(conn, prefix):
    return wait_for(conn, "STATUSTEXT", 5.0, lambda m: m.text.startswith(prefix))


def test_run_prearm_checks_reports_failures_and_is_rejected_when_armed():
    with running_server(FakeVehicle(prearm_failure="PreArm: Need 3D Fix")) as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        assert _long(conn, M.MAV_CMD_RUN_PREARM_CHECKS) == MavResult.ACCEPTED
        msg = _statustext(conn, "PreArm: Need 3D Fix")
        assert msg is not None and msg.severity == M.MAV_SEVERITY_CRITICAL
        vehicle.prearm_failure = None
        assert _long(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == MavResult.ACCEPTED
        assert _long(conn, M.MAV_CMD_RUN_PREARM_CHECKS) == MavResult.TEMPORARILY_REJECTED
        conn.close()


def test_do_set_home_current_location_and_given_location():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        assert _long(conn, M.MAV_CMD_DO_SET_HOME, 1) == MavResult.ACCEPTED
        assert wait_for(conn, "HOME_POSITION", 5.0) is not None
        assert _long(conn, M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 47.1, 8.2, 420.0) == MavResult.ACCEPTED
        conn.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                  M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 0, 0,
                                  471_000_000, 82_000_000, 5.0)
        assert command_ack(conn, M.MAV_CMD_DO_SET_HOME).result == MavResult.ACCEPTED
        assert _long(conn, M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 95.0, 8.2, 420.0) == MavResult.DENIED
        assert _long(conn, M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 47.1, 8.2, float("nan")) == MavResult.DENIED
        homes = [args[0] for name, args in vehicle.calls if name == "set_home"]
        assert homes[0] is None and len(homes) == 3, homes   # float32 params: compare approximately
        for home, (alt, frame) in zip(homes[1:], [(420.0, AltFrame.AMSL), (5.0, AltFrame.RELATIVE_HOME)], strict=True):
            assert isinstance(home, HomeLocation) and home.alt_frame == frame
            assert (home.lat_deg, home.lon_deg, home.alt_m) == pytest.approx((47.1, 8.2, alt), abs=1e-5)
        conn.close()


def test_preflight_storage_erase_drops_the_kept_parameters(tmp_path):
    store = tmp_path / "params.json"
    params = ParameterStore(PARAM_SPECS, persist_path=store)
    params.set("RTL_ALT", 3000)
    assert json.loads(store.read_text()) == {"RTL_ALT": 3000}
    with running_server(params=params) as (server, _):
        conn = gcs_connection(server.tcp_port)
        assert _long(conn, M.MAV_CMD_PREFLIGHT_STORAGE, 1) == MavResult.ACCEPTED
        assert json.loads(store.read_text()) == {"RTL_ALT": 3000}
        assert _long(conn, M.MAV_CMD_PREFLIGHT_STORAGE, 7) == MavResult.DENIED
        assert _long(conn, M.MAV_CMD_PREFLIGHT_STORAGE, 2) == MavResult.ACCEPTED
        assert _statustext(conn, "All parameters reset, reboot board") is not None
        conn.close()
    assert json.loads(store.read_text()) == {}
    assert ParameterStore(PARAM_SPECS, persist_path=store).get("RTL_ALT") == 1500


def test_set_ekf_source_set_selects_1_to_3():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        assert _long(conn, M.MAV_CMD_SET_EKF_SOURCE_SET, 2) == MavResult.ACCEPTED
        assert _long(conn, M.MAV_CMD_SET_EKF_SOURCE_SET, 4) == MavResult.DENIED
        assert _long(conn, M.MAV_CMD_SET_EKF_SOURCE_SET, 1.5) == MavResult.DENIED
        assert [a for n, a in vehicle.calls if n == "set_ekf_source_set"] == [(2,)]
        conn.close()


def test_preflight_reboot_as_arducopter_then_the_vehicle_gets_its_mission_again():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        assert _long(conn, M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 2) == MavResult.UNSUPPORTED
        assert _long(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == MavResult.ACCEPTED
        assert _long(conn, M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == MavResult.FAILED   # armed
        assert _long(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == MavResult.ACCEPTED
        assert not any(name == "reboot" for name, _ in vehicle.calls)
        assert _long(conn, M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == MavResult.ACCEPTED
        assert _statustext(conn, "ArduCopter V4.5.7") is not None            # the boot banner
        names = [name for name, _ in vehicle.calls]
        reboot = names.index("reboot")
        assert {"mission_changed", "fence_changed", "rally_changed"} <= set(names[reboot:])
        assert _long(conn, M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 3) == MavResult.ACCEPTED  # bootloader: restart
        conn.close()


def test_do_motor_test_parameters_as_arducopter_casts_them():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        assert _long(conn, M.MAV_CMD_DO_MOTOR_TEST, 2, 0, 15, 2.5, 0) == MavResult.ACCEPTED
        conn.mav.command_int_send(1, 1, 0, M.MAV_CMD_DO_MOTOR_TEST, 0, 0, 3, 1, 1200, 1.0, 4, 0, 0)
        assert command_ack(conn, M.MAV_CMD_DO_MOTOR_TEST).result == MavResult.ACCEPTED
        assert _long(conn, M.MAV_CMD_DO_MOTOR_TEST, 1, 0, float("nan"), 2.0) == MavResult.DENIED
        assert _long(conn, M.MAV_CMD_DO_MOTOR_TEST, 1, 0, 10, -1.0) == MavResult.DENIED
        requests = [args[0] for name, args in vehicle.calls if name == "motor_test"]
        assert [(r.motor_seq, r.throttle_type, r.throttle_value, r.motor_count) for r in requests] == [
            (2, 0, 15, 0), (3, 1, 1200, 4)]
        assert requests[0].timeout_s == pytest.approx(2.5)
        assert _long(conn, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == MavResult.ACCEPTED
        assert _long(conn, M.MAV_CMD_DO_MOTOR_TEST, 1, 0, 10, 2.0) == MavResult.FAILED    # vehicle refuses
        conn.close()


def test_set_gps_global_origin_is_handed_over_and_answered_with_gps_global_origin():
    from support.fake_vehicle import HOME
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        conn.mav.set_gps_global_origin_send(1, 471_000_000, 82_000_000, 420_500, 0)
        origin = wait_for(conn, "GPS_GLOBAL_ORIGIN", 5.0)
        assert origin is not None and (origin.latitude, origin.longitude) == (
            round(HOME[0] * 1e7), round(HOME[1] * 1e7))                  # the vehicle's origin
        conn.mav.set_gps_global_origin_send(1, 950_000_000, 82_000_000, 0, 0)   # bad lat: dropped
        conn.mav.set_gps_global_origin_send(7, 471_000_000, 82_000_000, 0, 0)   # another system
        assert _long(conn, M.MAV_CMD_RUN_PREARM_CHECKS) == MavResult.ACCEPTED   # the three were read
        calls = [args for name, args in vehicle.calls if name == "set_gps_global_origin"]
        assert calls == [pytest.approx((47.1, 8.2, 420.5))]
        assert server.stats["origin_rejected"] == 1
        conn.close()


def test_motor_test_and_reboot_on_scenenav_sitl(tmp_path):
    """The real autopilot node (``scenenav sitl --lockstep``): DO_MOTOR_TEST spins motor 1 (test
    order: front right, servo1) at 1200 us on the ground, then "finished motor test"; a reboot sends
    the banner, the EKF aligns again ("EKF3 IMU0 origin set") with the parameters kept, and the
    vehicle arms afterwards."""
    from support.sitl_session import Gcs, SitlSession, statustext, wait_until

    sitl = SitlSession(tmp_path, "--lockstep", "--perception", "off")
    gcs = None
    try:
        sitl.wait_ready()
        gcs = Gcs(sitl.port)
        assert gcs.wait("EKF_STATUS_REPORT", lambda m: m.flags & M.EKF_POS_HORIZ_ABS, 60) is not None
        gcs.send("request_data_stream_send", 1, 1, M.MAV_DATA_STREAM_RC_CHANNELS, 10, 1)
        assert gcs.command(M.MAV_CMD_DO_MOTOR_TEST, 1, 1, 1200, 1.5, 1) == MavResult.ACCEPTED
        servo = gcs.wait("SERVO_OUTPUT_RAW", lambda m: m.servo1_raw == 1200, 30, fresh=True)
        assert servo is not None and servo.servo2_raw == servo.servo3_raw == servo.servo4_raw == 1000
        assert statustext(gcs, "finished motor test", 30) is not None
        gcs.send("param_set_send", 1, 1, b"RTL_ALT", 2500.0, M.MAV_PARAM_TYPE_INT32)
        assert gcs.wait("PARAM_VALUE", lambda m: m.param_id == "RTL_ALT", 10) is not None
        assert gcs.command(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == MavResult.ACCEPTED
        assert statustext(gcs, "ArduCopter V4.5.7", 30) is not None
        assert statustext(gcs, "EKF3 IMU0 origin set", 60) is not None
        gcs.send("param_request_read_send", 1, 1, b"RTL_ALT", -1)
        value = gcs.wait("PARAM_VALUE", lambda m: m.param_id == "RTL_ALT", 10, fresh=True)
        assert value is not None and value.param_value == 2500.0
        assert wait_for(gcs.conn, "HEARTBEAT", 10) is not None
        assert gcs.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4) == MavResult.ACCEPTED
        assert wait_until(lambda: gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == MavResult.ACCEPTED,
                          30, period_s=0.5), "could not arm after the reboot"
    finally:
        if gcs is not None:
            gcs.close()
        sitl.stop()
