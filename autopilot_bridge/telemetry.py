"""Telemetry streams: per-link message scheduling and VehicleTelemetry -> MAVLink encoding.

Shell module (uses pymavlink). Two request styles are honoured, per link as in ArduPilot
(each GCS connection has its own rates):

* MAV_CMD_SET_MESSAGE_INTERVAL (interval in us; -1 disables, 0 restores the default), used by
  MAVSDK and QGC;
* REQUEST_DATA_STREAM (legacy stream groups at a rate in Hz), used by MAVProxy
  (``set streamrate``, default 4 Hz). Groups follow ArduPilot's SRx_ streams for the
  messages we produce (``GCS_MAVLink`` ``STREAM_*`` tables): EXTENDED_STATUS = SYS_STATUS,
  POWER_STATUS, MISSION_CURRENT, NAV_CONTROLLER_OUTPUT, GPS_RAW_INT, EXTENDED_SYS_STATE; POSITION =
  GLOBAL_POSITION_INT, LOCAL_POSITION_NED; EXTRA1 = ATTITUDE; EXTRA2 = VFR_HUD; EXTRA3 =
  SYSTEM_TIME, BATTERY_STATUS, EKF_STATUS_REPORT, VIBRATION, WIND. ATTITUDE_QUATERNION and GPS_GLOBAL_ORIGIN are
  in no group (as in ArduPilot): SET_MESSAGE_INTERVAL or REQUEST_MESSAGE.

Time is the caller's clock (``now_s`` given to :meth:`TelemetryScheduler.due`), so message
counts over a window are deterministic under a simulated clock; except for the messages in
``WALL_CLOCK_MSG_IDS`` (HEARTBEAT), which are scheduled on the wall clock (``wall_s``) so that a
frozen simulated clock (a lockstep wait for perception of up to 5 s) never starves a ground
station of heartbeats: QGC declares the link lost after ~3.5 s without one, MAVSDK after 3 s.

Encoders never raise on odd vehicle values: NaN/inf and out-of-range numbers are mapped to
MAVLink's "unknown" encodings or clamped to the field type.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Callable, Mapping

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.modes import POSITION_CONTROLLED_MODES, CopterMode
from autopilot_bridge.vehicle_interface import SensorFlag, VehicleTelemetry
from scenenav.core.rotations import quat_from_euler_zyx

INT16_MAX = 2 ** 15 - 1
INT32_MIN, INT32_MAX = -(2 ** 31), 2 ** 31 - 1
UINT16_MAX = 2 ** 16 - 1
FLOAT32_MAX = 3.4028234663852886e38
STATUSTEXT_CHUNK_LEN = 50

# What we claim to be: ArduCopter 4.5.7, official build (AUTOPILOT_VERSION.flight_sw_version
# layout major<<24 | minor<<16 | patch<<8 | FIRMWARE_VERSION_TYPE).
FIRMWARE_VERSION = (4, 5, 7)
FIRMWARE_VERSION_TYPE = mavlink2.FIRMWARE_VERSION_TYPE_OFFICIAL
FLIGHT_CUSTOM_VERSION = b"scenenav"  # 8 bytes where ArduPilot puts its git hash

# AUTOPILOT_VERSION.capabilities: what this emulator implements (FTP: the packed parameter file,
# autopilot_bridge.mavlink_ftp; MISSION_FENCE / MISSION_RALLY: geofence.py). Not claimed:
# SET_ATTITUDE_TARGET, FLIGHT_TERMINATION, COMPASS_CALIBRATION, TERRAIN.
CAPABILITIES = (mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_FTP
                | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE    # fence_rally_protocol
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)


class DataStream(IntEnum):
    """MAV_DATA_STREAM (REQUEST_DATA_STREAM.req_stream_id)."""

    ALL = 0
    RAW_SENSORS = 1
    EXTENDED_STATUS = 2
    RC_CHANNELS = 3
    RAW_CONTROLLER = 4
    POSITION = 6
    EXTRA1 = 10
    EXTRA2 = 11
    EXTRA3 = 12


class MissionMode(IntEnum):
    """MISSION_CURRENT.mission_mode."""

    UNKNOWN = 0
    IN_MISSION_MODE = 1
    SUSPENDED = 2


_M = mavlink2
STREAM_GROUPS: Mapping[DataStream, tuple[int, ...]] = {
    DataStream.RAW_SENSORS: (_M.MAVLINK_MSG_ID_RAW_IMU, _M.MAVLINK_MSG_ID_SCALED_IMU),
    DataStream.EXTENDED_STATUS: (_M.MAVLINK_MSG_ID_SYS_STATUS, _M.MAVLINK_MSG_ID_POWER_STATUS,
                                 _M.MAVLINK_MSG_ID_MISSION_CURRENT,
                                 _M.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT,
                                 _M.MAVLINK_MSG_ID_GPS_RAW_INT,
                                 _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                                 _M.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT),
    DataStream.RC_CHANNELS: (_M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, _M.MAVLINK_MSG_ID_RC_CHANNELS),
    DataStream.RAW_CONTROLLER: (),
    DataStream.POSITION: (_M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                          _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    DataStream.EXTRA1: (_M.MAVLINK_MSG_ID_ATTITUDE,),
    DataStream.EXTRA2: (_M.MAVLINK_MSG_ID_VFR_HUD,),
    DataStream.EXTRA3: (_M.MAVLINK_MSG_ID_SYSTEM_TIME, _M.MAVLINK_MSG_ID_BATTERY_STATUS,
                        _M.MAVLINK_MSG_ID_EKF_STATUS_REPORT, _M.MAVLINK_MSG_ID_VIBRATION,
                        _M.MAVLINK_MSG_ID_WIND, _M.MAVLINK_MSG_ID_OPTICAL_FLOW,
                        _M.MAVLINK_MSG_ID_DISTANCE_SENSOR, _M.MAVLINK_MSG_ID_RANGEFINDER),
}

# Default rates of a new link (Hz). HEARTBEAT and HOME_POSITION belong to no stream group.
DEFAULT_RATES_HZ: Mapping[int, float] = {
    _M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    _M.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
    _M.MAVLINK_MSG_ID_POWER_STATUS: 2.0,
    _M.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT: 2.0,
    _M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    _M.MAVLINK_MSG_ID_MISSION_CURRENT: 2.0,
    _M.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
    _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0,
    _M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 4.0,
    _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 4.0,
    _M.MAVLINK_MSG_ID_ATTITUDE: 4.0,
    _M.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    _M.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    _M.MAVLINK_MSG_ID_EKF_STATUS_REPORT: 1.0,
    _M.MAVLINK_MSG_ID_VIBRATION: 1.0,
    _M.MAVLINK_MSG_ID_WIND: 1.0,
    _M.MAVLINK_MSG_ID_OPTICAL_FLOW: 1.0,
    _M.MAVLINK_MSG_ID_DISTANCE_SENSOR: 1.0,
    _M.MAVLINK_MSG_ID_RANGEFINDER: 1.0,
    _M.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT: 2.0,
    _M.MAVLINK_MSG_ID_HOME_POSITION: 0.2,
}


# Scheduled on the wall clock, not the caller's (see the module docstring).
WALL_CLOCK_MSG_IDS: frozenset[int] = frozenset({_M.MAVLINK_MSG_ID_HEARTBEAT})


class TelemetryScheduler:
    """Which message ids are due on one link at a given time of the caller's clock."""

    MIN_INTERVAL_S = 0.01  # 100 Hz cap
    MAX_INTERVAL_S = 3600.0

    def __init__(self, default_rates_hz: Mapping[int, float] | None = None,
                 streamable: frozenset[int] | None = None) -> None:
        self._defaults = dict(DEFAULT_RATES_HZ if default_rates_hz is None else default_rates_hz)
        self._streamable = streamable if streamable is not None else STREAMABLE_MSG_IDS
        self._interval_s: dict[int, float] = {}
        self._next_due_s: dict[int, float | None] = {}
        # Nothing is due before these (the caller's clock, the wall clock) while the schedule is
        # unchanged: ``due`` returns at once without walking the schedule. ``_earliest_wall_given``
        # is whether the last full walk timed the wall-clock messages by ``wall_s``.
        self._earliest_s = -math.inf
        self._earliest_wall_s = -math.inf
        self._earliest_wall_given = False
        for msg_id, rate in self._defaults.items():
            self._set_rate(msg_id, rate)

    def is_streamable(self, msg_id: int) -> bool:
        return msg_id in self._streamable

    def interval_s(self, msg_id: int) -> float | None:
        """Current interval, None when the message is not streamed."""
        return self._interval_s.get(msg_id)

    def interval_us(self, msg_id: int) -> int:
        """For MESSAGE_INTERVAL: -1 disabled, 0 not available, else the interval in us."""
        if msg_id not in self._streamable:
            return 0
        interval = self._interval_s.get(msg_id)
        return -1 if interval is None else int(round(interval * 1e6))

    def set_interval_us(self, msg_id: int, interval_us: float) -> bool:
        """SET_MESSAGE_INTERVAL semantics; False when the id or interval is not acceptable."""
        if msg_id not in self._streamable or not math.isfinite(interval_us):
            return False
        if interval_us == -1:
            self._disable(msg_id)
        elif interval_us == 0:
            self._set_rate(msg_id, self._defaults.get(msg_id, 0.0))
        elif interval_us > 0:
            self._set_interval(msg_id, interval_us * 1e-6)
        else:
            return False
        return True

    def set_stream_rate(self, stream: int, rate_hz: float) -> bool:
        """REQUEST_DATA_STREAM semantics: rate 0 stops the group. False for unknown streams."""
        if not math.isfinite(rate_hz) or rate_hz < 0:
            return False
        if stream == DataStream.ALL:
            groups = list(STREAM_GROUPS)
        else:
            try:
                groups = [DataStream(stream)]
            except ValueError:
                return False
        for group in groups:
            for msg_id in STREAM_GROUPS[group]:
                self._set_rate(msg_id, rate_hz)
        return True

    def due(self, now_s: float, wall_s: float | None = None) -> list[int]:
        """Message ids to send now; each scheduled message advances by its interval.
        ``wall_s`` (monotonic wall seconds) times the ``WALL_CLOCK_MSG_IDS``; None = ``now_s``."""
        wall_given = wall_s is not None
        if (wall_given == self._earliest_wall_given and now_s < self._earliest_s
                and (wall_s if wall_given else now_s) < self._earliest_wall_s):
            return []
        out = []
        earliest = earliest_wall = math.inf
        for msg_id, interval in self._interval_s.items():
            on_wall = wall_given and msg_id in WALL_CLOCK_MSG_IDS
            t = wall_s if on_wall else now_s
            nxt = self._next_due_s.get(msg_id)
            if nxt is None:
                out.append(msg_id)
                nxt = t + interval
                self._next_due_s[msg_id] = nxt
            elif t >= nxt:
                out.append(msg_id)
                nxt += interval
                if nxt <= t:  # fell behind (e.g. the clock jumped): restart the phase
                    nxt = t + interval
                self._next_due_s[msg_id] = nxt
            if on_wall:
                earliest_wall = min(earliest_wall, nxt)
            else:
                earliest = min(earliest, nxt)
        self._earliest_s, self._earliest_wall_s = earliest, earliest_wall
        self._earliest_wall_given = wall_given
        return out

    def _set_rate(self, msg_id: int, rate_hz: float) -> None:
        if rate_hz <= 0:
            self._disable(msg_id)
        else:
            self._set_interval(msg_id, 1.0 / rate_hz)

    def _set_interval(self, msg_id: int, interval_s: float) -> None:
        interval_s = min(max(interval_s, self.MIN_INTERVAL_S), self.MAX_INTERVAL_S)
        if self._interval_s.get(msg_id) != interval_s:
            self._interval_s[msg_id] = interval_s
            self._next_due_s[msg_id] = None
            self._earliest_s = self._earliest_wall_s = -math.inf

    def _disable(self, msg_id: int) -> None:
        self._interval_s.pop(msg_id, None)
        self._next_due_s.pop(msg_id, None)
        self._earliest_s = self._earliest_wall_s = -math.inf


# ----------------------------------------------------------------------------- encoding


def clamp_int(value: float, lo: int, hi: int, unknown: int) -> int:
    """Round and clamp to [lo, hi]; NaN (and None) -> ``unknown``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return unknown
    if math.isnan(v):
        return unknown
    if v >= hi:
        return hi
    if v <= lo:
        return lo
    return int(round(v))


def finite_float(value: float, default: float = 0.0) -> float:
    """A float32-representable finite value; NaN -> ``default``, inf -> +-FLOAT32_MAX."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return default
    if math.isnan(v):
        return default
    return min(max(v, -FLOAT32_MAX), FLOAT32_MAX)


def deg_e7(deg: float) -> int:
    return clamp_int(deg * 1e7, INT32_MIN, INT32_MAX, 0)


def _mm(m: float) -> int:
    return clamp_int(m * 1000.0, INT32_MIN, INT32_MAX, 0)


def _heading_cdeg(deg: float) -> int:
    """Compass angle in centidegrees 0..35999, UINT16_MAX when unknown."""
    try:
        v = float(deg)
    except (TypeError, ValueError):
        return UINT16_MAX
    if not math.isfinite(v):
        return UINT16_MAX
    return clamp_int((v % 360.0) * 100.0, 0, 35999, UINT16_MAX)


def _triple(values: tuple[float, ...]) -> tuple[float, float, float]:
    vals = tuple(values)[:3] + (0.0, 0.0, 0.0)
    return (finite_float(vals[0]), finite_float(vals[1]), finite_float(vals[2]))


def heartbeat_base_mode(tel: VehicleTelemetry) -> int:
    """HEARTBEAT.base_mode as ArduCopter builds it (``GCS_MAVLINK_Copter::base_mode``)."""
    base = (mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
            | mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)
    if tel.mode in POSITION_CONTROLLED_MODES:
        base |= mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
    if tel.armed:
        base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    return base


@dataclass(frozen=True)
class EncodeContext:
    """Server state the encoders need besides the vehicle telemetry."""

    mission_item_count: int   # stored items excluding home
    battery_monitor: int      # BATT_MONITOR parameter
    unix_time_us: int = 0     # wall clock for SYSTEM_TIME (0 = unknown)


Encoder = Callable[[VehicleTelemetry, EncodeContext], "mavlink2.MAVLink_message | None"]


def encode_heartbeat(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_heartbeat_message(
        mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
        heartbeat_base_mode(tel), clamp_int(int(tel.mode), 0, 2 ** 32 - 1, 0),
        clamp_int(int(tel.system_status), 0, 255, 0), 3)


def encode_sys_status(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    present, enabled, health = tel.sensors_present, tel.sensors_enabled, tel.sensors_health
    battery = ctx.battery_monitor != 0
    if battery:
        present |= SensorFlag.BATTERY
        enabled |= SensorFlag.BATTERY
        health |= SensorFlag.BATTERY
    voltage_mv = clamp_int(tel.battery_voltage_v * 1000.0, 0, UINT16_MAX - 1, UINT16_MAX)
    current_ca = clamp_int(tel.battery_current_a * 100.0, -1, INT16_MAX, -1)
    if not battery:
        voltage_mv, current_ca = UINT16_MAX, -1
    if ctx.battery_monitor == 3:  # voltage only
        current_ca = -1
    remaining = clamp_int(tel.battery_remaining_pct, -1, 100, -1) if battery else -1
    mask = 0xFFFFFFFF
    return mavlink2.MAVLink_sys_status_message(
        int(present) & mask, int(enabled) & mask, int(health) & mask,
        clamp_int(tel.cpu_load_pct * 10.0, 0, 1000, 0), voltage_mv, current_ca, remaining,
        0, 0, 0, 0, 0, 0, 0, 0, 0)


def encode_attitude(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    r, p, y = _triple(tel.attitude_rpy_rad)
    rr, pr, yr = _triple(tel.body_rates_rad_s)
    return mavlink2.MAVLink_attitude_message(_time_ms(tel), r, p, y, rr, pr, yr)


def encode_global_position_int(tel: VehicleTelemetry, ctx: EncodeContext
                               ) -> mavlink2.MAVLink_message:
    vn, ve, vd = _triple(tel.velocity_ned_m_s)
    hdg = _heading_cdeg(tel.heading_deg)
    return mavlink2.MAVLink_global_position_int_message(
        _time_ms(tel), deg_e7(tel.lat_deg), deg_e7(tel.lon_deg), _mm(tel.alt_amsl_m),
        _mm(tel.relative_alt_m), clamp_int(vn * 100.0, -32768, INT16_MAX, 0),
        clamp_int(ve * 100.0, -32768, INT16_MAX, 0), clamp_int(vd * 100.0, -32768, INT16_MAX, 0),
        hdg)


def encode_local_position_ned(tel: VehicleTelemetry, ctx: EncodeContext
                              ) -> mavlink2.MAVLink_message:
    x, y, z = _triple(tel.position_ned_m)
    vx, vy, vz = _triple(tel.velocity_ned_m_s)
    return mavlink2.MAVLink_local_position_ned_message(_time_ms(tel), x, y, z, vx, vy, vz)


def encode_gps_raw_int(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_gps_raw_int_message(
        clamp_int(tel.time_boot_ms * 1000, 0, 2 ** 63 - 1, 0),
        clamp_int(int(tel.gps_fix_type), 0, 255, 0),
        deg_e7(tel.gps_lat_deg), deg_e7(tel.gps_lon_deg), _mm(tel.gps_alt_amsl_m),
        clamp_int(tel.gps_hdop * 100.0, 0, UINT16_MAX - 1, UINT16_MAX),
        clamp_int(tel.gps_vdop * 100.0, 0, UINT16_MAX - 1, UINT16_MAX),
        clamp_int(tel.gps_ground_speed_m_s * 100.0, 0, UINT16_MAX - 1, UINT16_MAX),
        _heading_cdeg(tel.gps_course_deg),
        clamp_int(tel.gps_satellites, 0, 254, 255),
        0, 0, 0, 0, 0, 0)


def encode_vfr_hud(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    heading = clamp_int(tel.heading_deg % 360.0 if math.isfinite(tel.heading_deg) else 0.0,
                        0, 359, 0)
    return mavlink2.MAVLink_vfr_hud_message(
        finite_float(tel.airspeed_m_s), finite_float(tel.groundspeed_m_s), heading,
        clamp_int(tel.throttle_pct, 0, 100, 0), finite_float(tel.alt_amsl_m),
        finite_float(tel.climb_m_s))


def encode_home_position(tel: VehicleTelemetry, ctx: EncodeContext
                         ) -> mavlink2.MAVLink_message | None:
    if not tel.home_set:
        return None
    x, y, z = _triple(tel.home_position_ned_m)
    return mavlink2.MAVLink_home_position_message(
        deg_e7(tel.home_lat_deg), deg_e7(tel.home_lon_deg), _mm(tel.home_alt_amsl_m),
        x, y, z, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0)


def encode_extended_sys_state(tel: VehicleTelemetry, ctx: EncodeContext
                              ) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_extended_sys_state_message(
        mavlink2.MAV_VTOL_STATE_UNDEFINED, clamp_int(int(tel.landed_state), 0, 255, 0))


def encode_battery_status(tel: VehicleTelemetry, ctx: EncodeContext
                          ) -> mavlink2.MAVLink_message | None:
    if ctx.battery_monitor == 0:
        return None
    # Per the MAVLink spec: unknown cell voltages -> total voltage in cell 0, others UINT16_MAX.
    voltages = [UINT16_MAX] * 10
    voltages[0] = clamp_int(tel.battery_voltage_v * 1000.0, 0, UINT16_MAX - 1, UINT16_MAX)
    current_ca = (-1 if ctx.battery_monitor == 3
                  else clamp_int(tel.battery_current_a * 100.0, -1, INT16_MAX, -1))
    return mavlink2.MAVLink_battery_status_message(
        0, mavlink2.MAV_BATTERY_FUNCTION_ALL, mavlink2.MAV_BATTERY_TYPE_LIPO, INT16_MAX,
        voltages, current_ca, -1, -1, clamp_int(tel.battery_remaining_pct, -1, 100, -1),
        0, mavlink2.MAV_BATTERY_CHARGE_STATE_OK, [0, 0, 0, 0], 0, 0)


def encode_mission_current(tel: VehicleTelemetry, ctx: EncodeContext
                           ) -> mavlink2.MAVLink_message:
    total = ctx.mission_item_count if ctx.mission_item_count > 0 else UINT16_MAX
    mode = MissionMode.IN_MISSION_MODE if tel.mode in (CopterMode.AUTO, CopterMode.AUTO_RTL) else MissionMode.SUSPENDED
    return mavlink2.MAVLink_mission_current_message(
        clamp_int(tel.mission_current_seq, 0, UINT16_MAX, 0), total,
        clamp_int(int(tel.mission_state), 0, 255, 0), int(mode))


def encode_ekf_status_report(tel: VehicleTelemetry, ctx: EncodeContext
                             ) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_ekf_status_report_message(
        clamp_int(tel.ekf_flags, 0, UINT16_MAX, 0), finite_float(tel.ekf_velocity_variance),
        finite_float(tel.ekf_pos_horiz_variance), finite_float(tel.ekf_pos_vert_variance),
        finite_float(tel.ekf_compass_variance), finite_float(tel.ekf_terrain_alt_variance), 0.0)


def encode_attitude_quaternion(tel: VehicleTelemetry, ctx: EncodeContext
                               ) -> mavlink2.MAVLink_message:
    """ATTITUDE's angles as a quaternion (w, x, y, z; body FRD -> NED): the Z-Y-X Euler formula
    of ``rotations.quat_from_euler_zyx`` is the same for NED/FRD angles."""
    r, p, y = _triple(tel.attitude_rpy_rad)
    rr, pr, yr = _triple(tel.body_rates_rad_s)
    w, x, qy, z = quat_from_euler_zyx(y, p, r)
    return mavlink2.MAVLink_attitude_quaternion_message(_time_ms(tel), w, x, qy, z, rr, pr, yr,
                                                        [0.0, 0.0, 0.0, 0.0])


def encode_system_time(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    """Unix time from the wall clock (ArduPilot: its RTC, set from GPS) and the boot time."""
    return mavlink2.MAVLink_system_time_message(max(0, int(ctx.unix_time_us)), _time_ms(tel))


def encode_gps_global_origin(tel: VehicleTelemetry, ctx: EncodeContext
                             ) -> mavlink2.MAVLink_message | None:
    """The EKF origin: where the EKF aligned (ArduPilot: at the first good GPS fix), or the one
    SET_GPS_GLOBAL_ORIGIN gave before that; nothing before it is set."""
    if not tel.origin_set:
        return None
    return mavlink2.MAVLink_gps_global_origin_message(
        deg_e7(tel.origin_lat_deg), deg_e7(tel.origin_lon_deg), _mm(tel.origin_alt_amsl_m),
        clamp_int(tel.time_boot_ms * 1000, 0, 2 ** 63 - 1, 0))


def encode_nav_controller_output(tel: VehicleTelemetry, ctx: EncodeContext
                                 ) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_nav_controller_output_message(
        finite_float(tel.nav_roll_deg), finite_float(tel.nav_pitch_deg),
        clamp_int(tel.nav_bearing_deg, -32768, INT16_MAX, 0),
        clamp_int(tel.target_bearing_deg, -32768, INT16_MAX, 0),
        clamp_int(tel.wp_dist_m, 0, UINT16_MAX, 0), finite_float(tel.alt_error_m), 0.0,
        finite_float(tel.xtrack_error_m))


# A healthy board as ArduPilot SITL reports it: 5 V rail, brick valid (AP_HAL board voltage).
POWER_STATUS_VCC_MV = 5000


def encode_power_status(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_power_status_message(POWER_STATUS_VCC_MV, 0,
                                                 mavlink2.MAV_POWER_STATUS_BRICK_VALID)


# RC_CHANNELS.rssi: 255 = unknown (there is no receiver; overrides carry no signal strength)
RSSI_UNKNOWN = 255
RC_CHANNELS_COUNT = 18
SERVO_OUTPUT_COUNT = 16


def encode_rc_channels(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    """RC_CHANNELS: the pilot's overrides (chancount = the channels with input, as ArduPilot's
    count of received channels)."""
    pwm = [clamp_int(v, 0, UINT16_MAX, 0) for v in tel.rc_channels_pwm][:RC_CHANNELS_COUNT]
    pwm += [0] * (RC_CHANNELS_COUNT - len(pwm))
    count = max((i + 1 for i, v in enumerate(pwm) if v > 0), default=0)
    return mavlink2.MAVLink_rc_channels_message(_time_ms(tel), count, *pwm, RSSI_UNKNOWN)


def encode_servo_output_raw(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    """SERVO_OUTPUT_RAW port 0: the motors' PWM on servo1..4, the rest 0."""
    pwm = [clamp_int(v, 0, UINT16_MAX, 0) for v in tel.servo_pwm][:SERVO_OUTPUT_COUNT]
    pwm += [0] * (SERVO_OUTPUT_COUNT - len(pwm))
    usec = clamp_int(tel.time_boot_ms * 1000, 0, 2 ** 32 - 1, 0)
    return mavlink2.MAVLink_servo_output_raw_message(usec, 0, *pwm)


def encode_autopilot_version(tel: VehicleTelemetry, ctx: EncodeContext
                             ) -> mavlink2.MAVLink_message:
    major, minor, patch = FIRMWARE_VERSION
    version = (major << 24) | (minor << 16) | (patch << 8) | FIRMWARE_VERSION_TYPE
    return mavlink2.MAVLink_autopilot_version_message(
        CAPABILITIES, version, 0, 0, 0, list(FLIGHT_CUSTOM_VERSION[:8].ljust(8, b"\0")),
        [0] * 8, [0] * 8, 0, 0, 0, [0] * 18)


MG_PER_M_S2 = 1000.0 / 9.80665      # RAW_IMU / SCALED_IMU accelerations in milli-g
INT16_MIN, INT16_MAX = -(2 ** 15), 2 ** 15 - 1
# POSITION_TARGET_* type_mask bits (POSITION_TARGET_TYPEMASK, a set bit = field not used)
_TM_VEL = 0b111 << 3
_TM_ACC = 0b111 << 6
_TM_YAW, _TM_YAW_RATE = 1 << 10, 1 << 11


def _imu_ints(tel: VehicleTelemetry) -> list[int]:
    acc = [clamp_int(round(v * MG_PER_M_S2), INT16_MIN, INT16_MAX, 0) if math.isfinite(v) else 0
           for v in tel.imu_accel_frd_m_s2]
    gyro = [clamp_int(round(v * 1000.0), INT16_MIN, INT16_MAX, 0) if math.isfinite(v) else 0
            for v in tel.imu_gyro_frd_rad_s]
    return acc + gyro + [0, 0, 0]     # no magnetometer vector here (the compass gives a heading)


def encode_raw_imu(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    """ArduPilot's RAW_IMU: the first IMU in milli-g and mrad/s (it is not raw there either)."""
    return mavlink2.MAVLink_raw_imu_message(_time_ms(tel) * 1000, *_imu_ints(tel), 0, 0)


def encode_scaled_imu(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_scaled_imu_message(_time_ms(tel), *_imu_ints(tel), 0)


def encode_vibration(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    vx, vy, vz = _triple(tel.vibration_m_s2)
    c = [clamp_int(int(v), 0, 2 ** 32 - 1, 0) for v in tuple(tel.accel_clipping)[:3]]
    return mavlink2.MAVLink_vibration_message(_time_ms(tel) * 1000, vx, vy, vz, *c)


def encode_wind(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message:
    """WIND (ardupilotmega) as ArduPilot's ``send_wind``: the direction the wind comes *from*
    (degrees, 0 = from the north), its horizontal speed and its vertical component (m/s)."""
    n, e, d = _triple(tel.wind_ned_m_s)
    speed = math.hypot(n, e)
    direction = math.degrees(math.atan2(-e, -n)) if speed > 0.0 else 0.0
    return mavlink2.MAVLink_wind_message(finite_float(direction), finite_float(speed), finite_float(d))


def encode_optical_flow(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message | None:
    """OPTICAL_FLOW as ArduPilot's ``send_opticalflow`` fills it: the raw flow rate (rad/s, about
    body x and y, FRD) in flow_rate_x/y, the flow with the body rotation removed times the range in
    flow_comp_m_x/y (m/s), quality, the range (m; -1 unknown); flow_x/y (dezi-pixels) 0. None without
    the sensor."""
    if not tel.flow_fitted:
        return None
    rx, ry = (finite_float(v) for v in tel.flow_rate_frd_rad_s)
    cx, cy = (finite_float(v) for v in tel.flow_comp_frd_m_s)
    d = tel.rangefinder_distance_m
    return mavlink2.MAVLink_optical_flow_message(
        clamp_int(tel.flow_time_us, 0, 2 ** 63 - 1, 0), 0, 0, 0, cx, cy, clamp_int(tel.flow_quality, 0, 255, 0),
        finite_float(d, -1.0), rx, ry)


def encode_distance_sensor(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message | None:
    """DISTANCE_SENSOR of the flow module's range finder, facing down (MAV_SENSOR_ROTATION_PITCH_270),
    type laser; the limits (RNGFND1_MIN_CM, RNGFND1_MAX_CM) and the current distance in cm (0 when
    the module measured nothing). None without the sensor."""
    if not tel.flow_fitted:
        return None

    def cm(m: float) -> int:
        return clamp_int(m * 100.0, 0, 65535, 0) if math.isfinite(m) else 0
    return mavlink2.MAVLink_distance_sensor_message(
        _time_ms(tel), cm(tel.rangefinder_min_m), cm(tel.rangefinder_max_m), cm(tel.rangefinder_distance_m), mavlink2.MAV_DISTANCE_SENSOR_LASER, 0, mavlink2.MAV_SENSOR_ROTATION_PITCH_270,
        255)


def encode_rangefinder(tel: VehicleTelemetry, ctx: EncodeContext) -> mavlink2.MAVLink_message | None:
    """RANGEFINDER (ardupilotmega): the range finder's distance (m; 0 out of range) and voltage (0).
    None without the sensor."""
    if not tel.flow_fitted:
        return None
    return mavlink2.MAVLink_rangefinder_message(finite_float(tel.rangefinder_distance_m), 0.0)


def encode_position_target_local_ned(tel: VehicleTelemetry, ctx: EncodeContext
                                     ) -> mavlink2.MAVLink_message | None:
    """The position controller's target (position, velocity and acceleration feed-forward, yaw);
    nothing without one (disarmed, landed)."""
    if tel.target_position_ned_m is None:
        return None
    yaw = tel.target_yaw_rad
    mask = _TM_YAW_RATE | (0 if math.isfinite(yaw) else _TM_YAW)
    return mavlink2.MAVLink_position_target_local_ned_message(
        _time_ms(tel), mavlink2.MAV_FRAME_LOCAL_NED, mask, *_triple(tel.target_position_ned_m),
        *_triple(tel.target_velocity_ned_m_s), *_triple(tel.target_accel_ned_m_s2),
        finite_float(yaw), 0.0)


def encode_position_target_global_int(tel: VehicleTelemetry, ctx: EncodeContext
                                      ) -> mavlink2.MAVLink_message | None:
    """The target position as ArduCopter sends it (position only, GLOBAL_INT, AMSL)."""
    if tel.target_position_ned_m is None:
        return None
    return mavlink2.MAVLink_position_target_global_int_message(
        _time_ms(tel), mavlink2.MAV_FRAME_GLOBAL_INT, _TM_VEL | _TM_ACC | _TM_YAW | _TM_YAW_RATE,
        deg_e7(tel.target_lat_deg), deg_e7(tel.target_lon_deg),
        finite_float(tel.target_alt_amsl_m), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


ENCODERS: Mapping[int, Encoder] = {
    _M.MAVLINK_MSG_ID_HEARTBEAT: encode_heartbeat,
    _M.MAVLINK_MSG_ID_SYS_STATUS: encode_sys_status,
    _M.MAVLINK_MSG_ID_ATTITUDE: encode_attitude,
    _M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: encode_global_position_int,
    _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: encode_local_position_ned,
    _M.MAVLINK_MSG_ID_GPS_RAW_INT: encode_gps_raw_int,
    _M.MAVLINK_MSG_ID_VFR_HUD: encode_vfr_hud,
    _M.MAVLINK_MSG_ID_HOME_POSITION: encode_home_position,
    _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: encode_extended_sys_state,
    _M.MAVLINK_MSG_ID_BATTERY_STATUS: encode_battery_status,
    _M.MAVLINK_MSG_ID_MISSION_CURRENT: encode_mission_current,
    _M.MAVLINK_MSG_ID_EKF_STATUS_REPORT: encode_ekf_status_report,
    _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: encode_autopilot_version,
    _M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: encode_attitude_quaternion,
    _M.MAVLINK_MSG_ID_SYSTEM_TIME: encode_system_time,
    _M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: encode_gps_global_origin,
    _M.MAVLINK_MSG_ID_POWER_STATUS: encode_power_status,
    _M.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT: encode_nav_controller_output,
    _M.MAVLINK_MSG_ID_RC_CHANNELS: encode_rc_channels,
    _M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: encode_servo_output_raw,
    _M.MAVLINK_MSG_ID_RAW_IMU: encode_raw_imu,
    _M.MAVLINK_MSG_ID_SCALED_IMU: encode_scaled_imu,
    _M.MAVLINK_MSG_ID_VIBRATION: encode_vibration,
    _M.MAVLINK_MSG_ID_WIND: encode_wind,
    _M.MAVLINK_MSG_ID_OPTICAL_FLOW: encode_optical_flow,
    _M.MAVLINK_MSG_ID_DISTANCE_SENSOR: encode_distance_sensor,
    _M.MAVLINK_MSG_ID_RANGEFINDER: encode_rangefinder,
    _M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: encode_position_target_local_ned,
    _M.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT: encode_position_target_global_int,
}

STREAMABLE_MSG_IDS: frozenset[int] = frozenset(ENCODERS)
# Messages ArduPilot has an ap_message for but this autopilot does not send (the "not implemented"
# telemetry rows of docs/mavlink.md): SET_MESSAGE_INTERVAL of one is ACCEPTED and nothing is sent,
# as ArduPilot answers for a sensor that is not fitted (no second barometer: no SCALED_PRESSURE2).
# OPTICAL_FLOW, DISTANCE_SENSOR and RANGEFINDER are encoded, and likewise send nothing without the
# flow module.
ARDUPILOT_UNSENT_MSG_IDS: frozenset[int] = frozenset(getattr(_M, f"MAVLINK_MSG_ID_{name}") for name in (
    "MEMINFO", "GPS2_RAW", "GPS_RTK", "SIMSTATE", "AHRS", "AHRS2", "SCALED_IMU2", "SCALED_IMU3",
    "SCALED_PRESSURE", "SCALED_PRESSURE2", "RC_CHANNELS_RAW",
    "ESC_TELEMETRY_1_TO_4", "PID_TUNING", "MCU_STATUS", "FENCE_STATUS", "ATTITUDE_TARGET",
    "HWSTATUS", "TERRAIN_REQUEST", "TERRAIN_REPORT"))


def encode(msg_id: int, tel: VehicleTelemetry, ctx: EncodeContext
           ) -> mavlink2.MAVLink_message | None:
    """The message for ``msg_id`` from the telemetry, or None (unknown id / nothing to say)."""
    encoder = ENCODERS.get(msg_id)
    return None if encoder is None else encoder(tel, ctx)


def statustext_messages(severity: int, text: str, chunk_id: int
                        ) -> list[mavlink2.MAVLink_message]:
    """STATUSTEXT message(s) for a text; longer than 50 bytes -> chunks sharing ``chunk_id``."""
    data = text.encode("ascii", errors="replace")
    sev = clamp_int(int(severity), 0, 7, 6)
    if len(data) <= STATUSTEXT_CHUNK_LEN:
        return [mavlink2.MAVLink_statustext_message(sev, data, 0, 0)]
    chunks = [data[i:i + STATUSTEXT_CHUNK_LEN] for i in range(0, len(data), STATUSTEXT_CHUNK_LEN)]
    if len(chunks[-1]) == STATUSTEXT_CHUNK_LEN:
        chunks.append(b"")  # a short final chunk marks the end
    chunks = chunks[:256]
    cid = chunk_id & 0xFFFF or 1
    return [mavlink2.MAVLink_statustext_message(sev, c, cid, i) for i, c in enumerate(chunks)]


def _time_ms(tel: VehicleTelemetry) -> int:
    return clamp_int(tel.time_boot_ms, 0, 2 ** 32 - 1, 0)
