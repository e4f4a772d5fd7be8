"""Decoding of MAVLink setpoints and external navigation into the Vehicle's typed targets:
SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT (type mask, frame, sanity limits as ArduCopter's
``sane_vel_or_acc_vector``) and ODOMETRY. Values that are no place on Earth or not finite are
rejected (None).
"""

from __future__ import annotations

import logging
import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.vehicle_interface import (
    ACCEL_IGNORE,
    POSITION_IGNORE,
    VELOCITY_IGNORE,
    AltFrame,
    GlobalPositionTarget,
    LocalPositionTarget,
    MavFrame,
    Odometry,
    PositionTargetTypeMask,
    setpoint_kind,
)
from scenenav.core.numeric import all_finite

logger = logging.getLogger(__name__)


MAX_SETPOINT_VEL_ACC = 1000.0      # ArduCopter sane_vel_or_acc_vector limit (m/s, m/s^2)


LOCATION_ALT_MAX_M = 83000.0


# A local (NED, metres) position target beyond this is no place on Earth (half its circumference);
# rejected like an out-of-range latitude in a global target.
MAX_LOCAL_TARGET_XY_M = 2.0e7


def _sane3(a: float, b: float, c: float) -> bool:
    return all_finite(a, b, c) and max(abs(a), abs(b), abs(c)) <= MAX_SETPOINT_VEL_ACC


_NAN3 = (math.nan, math.nan, math.nan)


LOCAL_SETPOINT_FRAMES = frozenset({MavFrame.LOCAL_NED, MavFrame.LOCAL_OFFSET_NED,
                                   MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED})


GLOBAL_SETPOINT_FRAMES = {MavFrame.GLOBAL: AltFrame.AMSL, MavFrame.GLOBAL_INT: AltFrame.AMSL,
                          MavFrame.GLOBAL_RELATIVE_ALT: AltFrame.RELATIVE_HOME,
                          MavFrame.GLOBAL_RELATIVE_ALT_INT: AltFrame.RELATIVE_HOME}


def _vel_acc_yaw(msg: mavlink2.MAVLink_message
                 ) -> tuple[tuple[float, float, float], tuple[float, float, float],
                            float | None, float | None] | None:
    mask = int(msg.type_mask)
    vel, acc = _NAN3, _NAN3
    if not mask & VELOCITY_IGNORE:
        if not _sane3(msg.vx, msg.vy, msg.vz):
            return None
        vel = (msg.vx, msg.vy, msg.vz)
    if not mask & ACCEL_IGNORE:
        if not _sane3(msg.afx, msg.afy, msg.afz):
            return None
        acc = (msg.afx, msg.afy, msg.afz)
    yaw = yaw_rate = None
    if not mask & PositionTargetTypeMask.YAW_IGNORE:
        if not math.isfinite(msg.yaw):
            return None
        yaw = msg.yaw
    if not mask & PositionTargetTypeMask.YAW_RATE_IGNORE:
        if not math.isfinite(msg.yaw_rate):
            return None
        yaw_rate = msg.yaw_rate
    return vel, acc, yaw, yaw_rate


def local_position_target(msg: mavlink2.MAVLink_message) -> LocalPositionTarget | None:
    """Validated SET_POSITION_TARGET_LOCAL_NED, or None when ArduCopter would reject it."""
    try:
        frame = MavFrame(msg.coordinate_frame)
    except ValueError:
        return None
    kind = setpoint_kind(int(msg.type_mask))
    if frame not in LOCAL_SETPOINT_FRAMES or kind is None:
        return None
    pos = _NAN3
    if not int(msg.type_mask) & POSITION_IGNORE:
        if not (all_finite(msg.x, msg.y, msg.z) and abs(msg.x) <= MAX_LOCAL_TARGET_XY_M
                and abs(msg.y) <= MAX_LOCAL_TARGET_XY_M and abs(msg.z) < LOCATION_ALT_MAX_M):
            return None
        pos = (msg.x, msg.y, msg.z)
    rest = _vel_acc_yaw(msg)
    if rest is None:
        return None
    vel, acc, yaw, yaw_rate = rest
    return LocalPositionTarget(int(msg.time_boot_ms), frame, int(msg.type_mask), kind, pos, vel,
                               acc, yaw, yaw_rate)


def global_position_target(msg: mavlink2.MAVLink_message) -> GlobalPositionTarget | None:
    """Validated SET_POSITION_TARGET_GLOBAL_INT, or None when it must be rejected."""
    try:
        frame = MavFrame(msg.coordinate_frame)
    except ValueError:
        return None
    kind = setpoint_kind(int(msg.type_mask))
    alt_frame = GLOBAL_SETPOINT_FRAMES.get(frame)
    if alt_frame is None or kind is None:
        return None
    lat = lon = alt = math.nan
    if not int(msg.type_mask) & POSITION_IGNORE:
        if not (abs(msg.lat_int) <= 900_000_000 and abs(msg.lon_int) <= 1_800_000_000
                and math.isfinite(msg.alt) and abs(msg.alt) < LOCATION_ALT_MAX_M):
            return None
        lat, lon, alt = msg.lat_int * 1e-7, msg.lon_int * 1e-7, float(msg.alt)
    rest = _vel_acc_yaw(msg)
    if rest is None:
        return None
    vel, acc, yaw, yaw_rate = rest
    return GlobalPositionTarget(int(msg.time_boot_ms), frame, int(msg.type_mask), kind, lat, lon,
                                alt, alt_frame, vel, acc, yaw, yaw_rate)


def odometry_from_message(msg: mavlink2.MAVLink_message) -> Odometry | None:
    """Validated ODOMETRY (finite position, unit quaternion), or None."""
    q = tuple(float(v) for v in msg.q)
    if not all_finite(msg.x, msg.y, msg.z) or not all(math.isfinite(v) for v in q):
        return None
    if abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-2:
        return None
    return Odometry(
        time_usec=int(msg.time_usec), frame_id=int(msg.frame_id),
        child_frame_id=int(msg.child_frame_id), position_m=(msg.x, msg.y, msg.z),
        q_wxyz=(q[0], q[1], q[2], q[3]), velocity_m_s=(msg.vx, msg.vy, msg.vz),
        body_rates_rad_s=(msg.rollspeed, msg.pitchspeed, msg.yawspeed),
        pose_covariance=tuple(float(v) for v in msg.pose_covariance),
        velocity_covariance=tuple(float(v) for v in msg.velocity_covariance),
        reset_counter=int(msg.reset_counter), estimator_type=int(msg.estimator_type),
        quality_pct=int(msg.quality))
