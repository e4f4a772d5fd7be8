"""RAW_IMU, SCALED_IMU, VIBRATION and POSITION_TARGET_* encoders and the vibration monitor."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.telemetry import STREAM_GROUPS, DataStream, EncodeContext, encode
from autopilot_bridge.vehicle_interface import VehicleTelemetry
from autopilot_bridge.vibration import VibrationMonitor

M = mavlink2
CTX = EncodeContext(mission_item_count=0, battery_monitor=4, unix_time_us=0)


def test_imu_messages_in_milli_g_and_mrad():
    tel = VehicleTelemetry(time_boot_ms=1234, imu_accel_frd_m_s2=(0.0, 0.980665, -9.80665),
                           imu_gyro_frd_rad_s=(0.01, -0.02, 0.5))
    raw = encode(M.MAVLINK_MSG_ID_RAW_IMU, tel, CTX)
    assert (raw.time_usec, raw.xacc, raw.yacc, raw.zacc) == (1_234_000, 0, 100, -1000)
    assert (raw.xgyro, raw.ygyro, raw.zgyro) == (10, -20, 500)
    scaled = encode(M.MAVLINK_MSG_ID_SCALED_IMU, tel, CTX)
    assert (scaled.time_boot_ms, scaled.zacc, scaled.zgyro) == (1234, -1000, 500)
    assert encode(M.MAVLINK_MSG_ID_RAW_IMU, VehicleTelemetry(), CTX).xacc == 0   # unknown -> 0
    assert M.MAVLINK_MSG_ID_RAW_IMU in STREAM_GROUPS[DataStream.RAW_SENSORS]
    assert M.MAVLINK_MSG_ID_VIBRATION in STREAM_GROUPS[DataStream.EXTRA3]


def test_position_targets_only_with_a_target():
    assert encode(M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, VehicleTelemetry(), CTX) is None
    assert encode(M.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT, VehicleTelemetry(), CTX) is None
    tel = VehicleTelemetry(target_position_ned_m=(10.0, -5.0, -20.0),
                           target_velocity_ned_m_s=(1.0, 0.0, 0.0), target_yaw_rad=0.5,
                           target_lat_deg=47.1, target_lon_deg=8.2, target_alt_amsl_m=520.0)
    local = encode(M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, tel, CTX)
    assert (local.x, local.y, local.z, local.vx, local.yaw) == pytest.approx((10, -5, -20, 1, 0.5))
    assert local.type_mask & M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
    assert not local.type_mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    glob = encode(M.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT, tel, CTX)
    assert (glob.lat_int, glob.lon_int, glob.alt) == (471_000_000, 82_000_000, 520.0)
    assert glob.coordinate_frame == M.MAV_FRAME_GLOBAL_INT


def test_vibration_is_the_rms_of_the_high_passed_accelerometer():
    mon, dt = VibrationMonitor(), 0.0025
    rng = np.random.default_rng(1)
    for _ in range(4000):     # 10 s: white noise of std 2 m/s/s on x, nothing on y, gravity on z
        mon.add((rng.normal(0.0, 2.0), 0.0, -9.8), dt)
    vx, vy, vz = mon.levels
    assert 1.5 < vx < 2.6 and vy == 0.0 and vz == pytest.approx(0.0, abs=1e-6)
    assert mon.clip_counts == [0, 0, 0]
    mon.add((200.0, 0.0, -9.8), dt)
    assert mon.clip_counts == [1, 0, 0]
    mon.add((math.nan, 0.0, 0.0), dt)          # ignored
    assert math.isfinite(mon.levels[0])


def test_wind_says_where_the_wind_comes_from():
    # 5 m/s blowing towards the east (NED y) comes from the west: -90 degrees (ArduPilot's atan2
    # range, -180 .. 180)
    wind = encode(M.MAVLINK_MSG_ID_WIND, VehicleTelemetry(wind_ned_m_s=(0.0, 5.0, 0.0)), CTX)
    assert (wind.direction, wind.speed, wind.speed_z) == pytest.approx((-90.0, 5.0, 0.0))
    north = encode(M.MAVLINK_MSG_ID_WIND, VehicleTelemetry(wind_ned_m_s=(-3.0, 0.0, 0.0)), CTX)
    assert (north.direction, north.speed) == pytest.approx((0.0, 3.0))     # blowing south: from the north
    calm = encode(M.MAVLINK_MSG_ID_WIND, VehicleTelemetry(wind_ned_m_s=(math.nan, 0.0, 0.0)), CTX)
    assert (calm.direction, calm.speed) == (0.0, 0.0)
    assert M.MAVLINK_MSG_ID_WIND in STREAM_GROUPS[DataStream.EXTRA3]
