"""The abstract vehicle the MAVLink server talks to, and the plain data it exchanges with it.

Pure module (no pymavlink): the flight core implements :class:`Vehicle`; the MAVLink server
(``autopilot_bridge.mavlink_server``) calls it. Enum values mirror the MAVLink constants of
the same name so the server can put them on the wire unchanged (``tests/test_mavlink_commands.py``
checks every value against pymavlink).

Frames and units (MAVLink conventions, *not* the scenenav bus conventions of
``scenenav/core/frames.py``; the implementer converts):

* local positions/velocities are NED metres relative to the EKF origin (``*_ned_m``);
* attitude is the aerospace convention, body FRD relative to NED: roll, pitch, yaw where
  yaw is the compass heading (clockwise from north), radians;
* latitude/longitude in degrees (WGS-84), altitudes in metres, AMSL unless named
  ``relative_alt_m`` (above home).

Every :class:`Vehicle` method is called from the server's ``poll()`` only, never concurrently.
Methods returning an :class:`Outcome` must not raise; ``Outcome(False, reason)`` refuses the
request and ``reason`` (<= 50 characters reads best) is sent to the ground stations as a
STATUSTEXT, as ArduPilot does ("PreArm: ...", "Flight mode change failed").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import NamedTuple, Protocol, runtime_checkable

from autopilot_bridge.modes import CopterMode
from scenenav.core.contracts import GpsFixType, Severity

# --------------------------------------------------------------------------- enums


# MAV_SEVERITY (STATUSTEXT severity, RFC-5424): the bus's Event severity is the same enum.
MavSeverity = Severity


class LandedState(IntEnum):
    """MAV_LANDED_STATE (EXTENDED_SYS_STATE.landed_state)."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class SystemStatus(IntEnum):
    """MAV_STATE (HEARTBEAT.system_status). ArduCopter: STANDBY when landed, ACTIVE when
    flying, CRITICAL while any failsafe is active, BOOT before initialisation."""

    UNINIT = 0
    BOOT = 1
    CALIBRATING = 2
    STANDBY = 3
    ACTIVE = 4
    CRITICAL = 5
    EMERGENCY = 6
    POWEROFF = 7
    FLIGHT_TERMINATION = 8


class MissionState(IntEnum):
    """MISSION_STATE (MISSION_CURRENT.mission_state)."""

    UNKNOWN = 0
    NO_MISSION = 1
    NOT_STARTED = 2
    ACTIVE = 3
    PAUSED = 4
    COMPLETE = 5


class MavFrame(IntEnum):
    """MAV_FRAME values used by missions, COMMAND_INT and SET_POSITION_TARGET_*."""

    GLOBAL = 0
    LOCAL_NED = 1
    MISSION = 2
    GLOBAL_RELATIVE_ALT = 3
    LOCAL_ENU = 4
    GLOBAL_INT = 5
    GLOBAL_RELATIVE_ALT_INT = 6
    LOCAL_OFFSET_NED = 7
    BODY_NED = 8
    BODY_OFFSET_NED = 9
    GLOBAL_TERRAIN_ALT = 10
    GLOBAL_TERRAIN_ALT_INT = 11


class AltFrame(IntEnum):
    """What an altitude is measured from."""

    AMSL = 0            # MAV_FRAME_GLOBAL / GLOBAL_INT
    RELATIVE_HOME = 1   # MAV_FRAME_GLOBAL_RELATIVE_ALT / GLOBAL_RELATIVE_ALT_INT


class SensorFlag(IntFlag):
    """MAV_SYS_STATUS_SENSOR bits used in SYS_STATUS (subset)."""

    GYRO_3D = 0x1
    ACCEL_3D = 0x2
    MAG_3D = 0x4
    ABSOLUTE_PRESSURE = 0x8
    GPS = 0x20
    OPTICAL_FLOW = 0x40
    VISION_POSITION = 0x80
    ANGULAR_RATE_CONTROL = 0x400
    ATTITUDE_STABILIZATION = 0x800
    YAW_POSITION = 0x1000
    Z_ALTITUDE_CONTROL = 0x2000
    XY_POSITION_CONTROL = 0x4000
    MOTOR_OUTPUTS = 0x8000
    RC_RECEIVER = 0x10000
    GEOFENCE = 0x100000
    AHRS = 0x200000
    BATTERY = 0x2000000
    PREARM_CHECK = 0x10000000  # health bit set = pre-arm checks pass (QGC "Ready to fly")


DEFAULT_SENSORS = (SensorFlag.GYRO_3D | SensorFlag.ACCEL_3D | SensorFlag.MAG_3D
                   | SensorFlag.ABSOLUTE_PRESSURE | SensorFlag.VISION_POSITION
                   | SensorFlag.ANGULAR_RATE_CONTROL | SensorFlag.ATTITUDE_STABILIZATION
                   | SensorFlag.YAW_POSITION | SensorFlag.Z_ALTITUDE_CONTROL
                   | SensorFlag.XY_POSITION_CONTROL | SensorFlag.MOTOR_OUTPUTS
                   | SensorFlag.AHRS | SensorFlag.PREARM_CHECK)


class SpeedType(IntEnum):
    """SPEED_TYPE (MAV_CMD_DO_CHANGE_SPEED param1). ArduCopter treats AIRSPEED as ground speed."""

    AIRSPEED = 0
    GROUNDSPEED = 1
    CLIMB_SPEED = 2
    DESCENT_SPEED = 3


class MissionCommand(IntEnum):
    """The MAV_CMD ids ArduPilot's AP_Mission stores (``AP_Mission::mavlink_int_to_mission_cmd``,
    4.5); the mission protocol accepts exactly these (``autopilot_bridge.mission``), the flight
    core executes some (``autopilot_bridge.auto_mission``) and skips the rest."""

    NAV_WAYPOINT = 16
    NAV_LOITER_UNLIM = 17
    NAV_LOITER_TURNS = 18
    NAV_LOITER_TIME = 19
    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22
    NAV_CONTINUE_AND_CHANGE_ALT = 30
    NAV_LOITER_TO_ALT = 31
    NAV_SPLINE_WAYPOINT = 82
    NAV_ALTITUDE_WAIT = 83
    NAV_VTOL_TAKEOFF = 84
    NAV_VTOL_LAND = 85
    NAV_GUIDED_ENABLE = 92
    NAV_DELAY = 93
    NAV_PAYLOAD_PLACE = 94
    CONDITION_DELAY = 112
    CONDITION_DISTANCE = 114
    CONDITION_YAW = 115
    DO_SET_MODE = 176
    DO_JUMP = 177
    DO_CHANGE_SPEED = 178
    DO_SET_HOME = 179
    DO_SET_RELAY = 181
    DO_REPEAT_RELAY = 182
    DO_SET_SERVO = 183
    DO_REPEAT_SERVO = 184
    DO_LAND_START = 189
    DO_GO_AROUND = 191
    DO_SET_REVERSE = 194
    DO_SET_ROI_LOCATION = 195
    DO_SET_ROI_NONE = 197
    DO_SET_ROI = 201
    DO_DIGICAM_CONFIGURE = 202
    DO_DIGICAM_CONTROL = 203
    DO_MOUNT_CONTROL = 205
    DO_SET_CAM_TRIGG_DIST = 206
    DO_FENCE_ENABLE = 207
    DO_PARACHUTE = 208
    DO_INVERTED_FLIGHT = 210
    DO_GRIPPER = 211
    DO_AUTOTUNE_ENABLE = 212
    NAV_SET_YAW_SPEED = 213
    DO_SET_RESUME_REPEAT_DIST = 215
    DO_SPRAYER = 216
    DO_SEND_SCRIPT_MESSAGE = 217
    DO_AUX_FUNCTION = 218
    DO_GUIDED_LIMITS = 222
    DO_ENGINE_CONTROL = 223
    SET_CAMERA_ZOOM = 531
    SET_CAMERA_FOCUS = 532
    JUMP_TAG = 600
    DO_JUMP_TAG = 601
    DO_GIMBAL_MANAGER_PITCHYAW = 1000
    IMAGE_START_CAPTURE = 2000
    IMAGE_STOP_CAPTURE = 2001
    VIDEO_START_CAPTURE = 2500
    VIDEO_STOP_CAPTURE = 2501
    DO_VTOL_TRANSITION = 3000
    DO_WINCH = 42600
    NAV_SCRIPT_TIME = 42702
    NAV_ATTITUDE_TIME = 42703


class PositionTargetTypeMask(IntFlag):
    """POSITION_TARGET_TYPEMASK: a set bit means "ignore this field"."""

    X_IGNORE = 1
    Y_IGNORE = 2
    Z_IGNORE = 4
    VX_IGNORE = 8
    VY_IGNORE = 16
    VZ_IGNORE = 32
    AX_IGNORE = 64
    AY_IGNORE = 128
    AZ_IGNORE = 256
    FORCE_SET = 512
    YAW_IGNORE = 1024
    YAW_RATE_IGNORE = 2048


POSITION_IGNORE = (PositionTargetTypeMask.X_IGNORE | PositionTargetTypeMask.Y_IGNORE
                   | PositionTargetTypeMask.Z_IGNORE)
VELOCITY_IGNORE = (PositionTargetTypeMask.VX_IGNORE | PositionTargetTypeMask.VY_IGNORE
                   | PositionTargetTypeMask.VZ_IGNORE)
ACCEL_IGNORE = (PositionTargetTypeMask.AX_IGNORE | PositionTargetTypeMask.AY_IGNORE
                | PositionTargetTypeMask.AZ_IGNORE)


class SetpointKind(IntEnum):
    """Which guided-mode controller a SET_POSITION_TARGET_* addresses (ArduCopter's decoding
    of type_mask, ``GCS_MAVLINK_Copter::handle_message_set_position_target_*``)."""

    POSITION = 0
    POSITION_VELOCITY = 1   # position + velocity (+ acceleration feed-forward if not ignored)
    VELOCITY = 2            # velocity (+ acceleration feed-forward if not ignored)
    ACCELERATION = 3


def setpoint_kind(type_mask: int) -> SetpointKind | None:
    """Decode type_mask as ArduCopter does; None for combinations it rejects.

    Any bit of a group set means the whole group is ignored (ArduCopter tests
    ``type_mask & GROUP``). FORCE_SET together with used accelerations is rejected.
    """
    pos = not (type_mask & POSITION_IGNORE)
    vel = not (type_mask & VELOCITY_IGNORE)
    acc = not (type_mask & ACCEL_IGNORE)
    if (type_mask & PositionTargetTypeMask.FORCE_SET) and acc:
        return None
    if pos and vel:
        return SetpointKind.POSITION_VELOCITY
    if vel:
        return SetpointKind.VELOCITY
    if acc and not pos:
        return SetpointKind.ACCELERATION
    if pos and not acc:
        return SetpointKind.POSITION
    return None


# --------------------------------------------------------------------------- data


class Outcome(NamedTuple):
    """Result of a vehicle request: ``(ok, reason)``; reason is shown to the operator on failure."""

    ok: bool
    reason: str = ""


@dataclass(frozen=True)
class MissionItem:
    """One stored mission item, exactly as MISSION_ITEM_INT carries it.

    ``seq`` 0 is home and is never handed to the vehicle: ``Vehicle.mission_changed`` gets
    the items with seq 1..n. For location commands ``lat_e7``/``lon_e7`` are degrees * 1e7 and
    ``alt_m`` is metres in ``frame`` (see :attr:`alt_frame`). For DO_DIGICAM_* they are the raw
    x/y fields.
    """

    seq: int
    command: int
    frame: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    lat_e7: int = 0
    lon_e7: int = 0
    alt_m: float = 0.0
    autocontinue: bool = True

    @property
    def lat_deg(self) -> float:
        return self.lat_e7 * 1e-7

    @property
    def lon_deg(self) -> float:
        return self.lon_e7 * 1e-7

    @property
    def terrain_frame(self) -> bool:
        """Altitude above terrain (MAV_FRAME_GLOBAL_TERRAIN_ALT(_INT))."""
        return self.frame in (MavFrame.GLOBAL_TERRAIN_ALT, MavFrame.GLOBAL_TERRAIN_ALT_INT)

    @property
    def alt_frame(self) -> AltFrame | None:
        """Altitude reference of a location command, None for frames without one (and for the
        terrain frames: there are no terrain data here, see ``terrain_frame``)."""
        if self.frame in (MavFrame.GLOBAL, MavFrame.GLOBAL_INT, MavFrame.MISSION):
            return AltFrame.AMSL
        if self.frame in (MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_RELATIVE_ALT_INT):
            return AltFrame.RELATIVE_HOME
        return None


@dataclass(frozen=True)
class HomeLocation:
    """A DO_SET_HOME location: degrees, metres in ``alt_frame`` (AMSL or above the current home)."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    alt_frame: AltFrame


@dataclass(frozen=True)
class LocalPositionTarget:
    """SET_POSITION_TARGET_LOCAL_NED, already validated by the server.

    Fields whose group is ignored (see :attr:`kind`) are NaN. Positions are metres in
    ``frame`` (LOCAL_NED: from the EKF origin; LOCAL_OFFSET_NED: offset from the current
    position, NED; BODY_NED: body-yaw-rotated, from the current position;
    BODY_OFFSET_NED: same as BODY_NED), velocities m/s, accelerations m/s^2, yaw rad
    (relative to the current heading in the BODY frames), yaw_rate rad/s.
    """

    time_boot_ms: int
    frame: MavFrame
    type_mask: int
    kind: SetpointKind
    position_m: tuple[float, float, float]
    velocity_m_s: tuple[float, float, float]
    acceleration_m_s2: tuple[float, float, float]
    yaw_rad: float | None
    yaw_rate_rad_s: float | None


@dataclass(frozen=True)
class GlobalPositionTarget:
    """SET_POSITION_TARGET_GLOBAL_INT, already validated by the server.

    ``lat_deg``/``lon_deg``/``alt_m`` are NaN when position is ignored; ``alt_frame`` says
    what ``alt_m`` is relative to. Velocities NED m/s, accelerations NED m/s^2.
    """

    time_boot_ms: int
    frame: MavFrame
    type_mask: int
    kind: SetpointKind
    lat_deg: float
    lon_deg: float
    alt_m: float
    alt_frame: AltFrame
    velocity_m_s: tuple[float, float, float]
    acceleration_m_s2: tuple[float, float, float]
    yaw_rad: float | None
    yaw_rate_rad_s: float | None


@dataclass(frozen=True)
class Odometry:
    """ODOMETRY (external navigation), already checked for finite position and a unit quaternion.

    ``frame_id``/``child_frame_id`` are MAV_FRAME values as sent (ArduPilot expects
    LOCAL_FRD/BODY_FRD or LOCAL_NED...). ``q_wxyz`` rotates child (body) to parent.
    Covariances are the 21-element upper triangles; NaN in element 0 means unknown.
    """

    time_usec: int
    frame_id: int
    child_frame_id: int
    position_m: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]
    velocity_m_s: tuple[float, float, float]
    body_rates_rad_s: tuple[float, float, float]
    pose_covariance: tuple[float, ...]
    velocity_covariance: tuple[float, ...]
    reset_counter: int
    estimator_type: int
    quality_pct: int


@dataclass(frozen=True)
class MotorTestRequest:
    """DO_MOTOR_TEST's parameters as ArduCopter casts them (uint8 / uint16; ``autopilot_bridge.motor_test``)."""

    motor_seq: int
    throttle_type: int
    throttle_value: int
    timeout_s: float
    motor_count: int

    @classmethod
    def from_params(cls, p1: float, p2: float, p3: float, p4: float, p5: float) -> MotorTestRequest | None:
        """None for non-finite or negative values (the server answers DENIED)."""
        values = (p1, p2, p3, p4, p5)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            return None
        return cls(int(p1) & 0xFF, int(p2) & 0xFF, int(p3) & 0xFFFF, float(p4), int(p5) & 0xFF)


@dataclass(frozen=True)
class VehicleTelemetry:
    """A snapshot of the vehicle state, read once per server poll. Every field has a default
    so an implementer can fill what it knows; NaN marks an unknown float where MAVLink has an
    "unknown" encoding."""

    time_boot_ms: int = 0
    armed: bool = False
    mode: CopterMode = CopterMode.STABILIZE
    landed_state: LandedState = LandedState.ON_GROUND
    system_status: SystemStatus = SystemStatus.STANDBY
    # fused (EKF) global position
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_amsl_m: float = 0.0
    relative_alt_m: float = 0.0
    # fused local state, NED from the EKF origin
    position_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # attitude: roll, pitch, yaw (yaw = heading, clockwise from north), body FRD w.r.t. NED
    attitude_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    body_rates_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    heading_deg: float = 0.0
    groundspeed_m_s: float = 0.0
    airspeed_m_s: float = 0.0
    climb_m_s: float = 0.0
    throttle_pct: float = 0.0
    # raw GPS receiver (independent of the fused position: GPS-denied flight keeps it NO_FIX)
    gps_fix_type: GpsFixType = GpsFixType.NO_GPS
    gps_satellites: int = 0
    gps_hdop: float = math.nan
    gps_vdop: float = math.nan
    gps_lat_deg: float = 0.0
    gps_lon_deg: float = 0.0
    gps_alt_amsl_m: float = 0.0
    gps_ground_speed_m_s: float = math.nan
    gps_course_deg: float = math.nan
    # battery
    battery_voltage_v: float = math.nan
    battery_current_a: float = math.nan
    battery_remaining_pct: int = -1
    # home
    home_set: bool = False
    home_lat_deg: float = 0.0
    home_lon_deg: float = 0.0
    home_alt_amsl_m: float = 0.0
    home_position_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # EKF origin (GPS_GLOBAL_ORIGIN; SET_GPS_GLOBAL_ORIGIN before alignment)
    origin_set: bool = False
    origin_lat_deg: float = 0.0
    origin_lon_deg: float = 0.0
    origin_alt_amsl_m: float = 0.0
    # mission execution (seq indexes the stored mission, 0 = home)
    mission_current_seq: int = 0
    mission_state: MissionState = MissionState.NO_MISSION
    # EKF_STATUS_REPORT: EKF_STATUS_FLAGS bitmask and normalised variances (1.0 = failsafe level)
    ekf_flags: int = 0
    ekf_velocity_variance: float = 0.0
    ekf_pos_horiz_variance: float = 0.0
    ekf_pos_vert_variance: float = 0.0
    ekf_compass_variance: float = 0.0
    ekf_terrain_alt_variance: float = 0.0
    # WIND (ardupilotmega): the EKF's wind estimate, NED m/s, the direction it blows towards (zero
    # unless drag fusion is on, EK3_DRAG_*)
    wind_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # OPTICAL_FLOW, DISTANCE_SENSOR, RANGEFINDER: the flow module's last sample (FLOW_TYPE > 0 and a
    # sample received; nothing is sent otherwise, as ArduPilot without the sensor). Body FRD axes: the
    # raw flow rate (rad/s), the flow with the body rotation removed times the range (m/s), the range
    # (m, NaN when the module measured nothing) and its limits (m, RNGFND1_MIN_CM / RNGFND1_MAX_CM)
    flow_fitted: bool = False
    flow_time_us: int = 0
    flow_rate_frd_rad_s: tuple[float, float] = (math.nan, math.nan)
    flow_comp_frd_m_s: tuple[float, float] = (math.nan, math.nan)
    flow_quality: int = 0
    rangefinder_distance_m: float = math.nan
    rangefinder_min_m: float = 0.0        # RNGFND1_MIN_CM, RNGFND1_MAX_CM
    rangefinder_max_m: float = 0.0
    # SYS_STATUS: SensorFlag (MAV_SYS_STATUS_SENSOR) bitmasks
    sensors_present: int = int(DEFAULT_SENSORS)
    sensors_enabled: int = int(DEFAULT_SENSORS)
    # GEOFENCE healthy without a fence, as ArduPilot (not failed when not present)
    sensors_health: int = int(DEFAULT_SENSORS | SensorFlag.GEOFENCE)
    cpu_load_pct: float = 0.0
    # NAV_CONTROLLER_OUTPUT (ArduCopter: attitude target, bearing/distance to the waypoint, the
    # vertical position error, the cross-track error); 0 where the mode has no waypoint
    nav_roll_deg: float = 0.0
    nav_pitch_deg: float = 0.0
    nav_bearing_deg: float = 0.0
    target_bearing_deg: float = 0.0
    wp_dist_m: float = 0.0
    alt_error_m: float = 0.0
    xtrack_error_m: float = 0.0
    # RC_CHANNELS: the pilot's RC input (18 PWM values, 0 = none); SERVO_OUTPUT_RAW: motor outputs
    # 1..4 in PWM (ArduPilot's motor order)
    rc_channels_pwm: tuple[int, ...] = ()
    servo_pwm: tuple[int, ...] = ()
    # RAW_IMU / SCALED_IMU (body FRD, the IMU sample the flight core last used; NaN = none yet)
    imu_accel_frd_m_s2: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    imu_gyro_frd_rad_s: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    # VIBRATION (autopilot_bridge.vibration): levels m/s/s and accelerometer clipping counts
    vibration_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_clipping: tuple[int, int, int] = (0, 0, 0)
    # POSITION_TARGET_*: the position controller's target (NED from the EKF origin); None = none
    target_position_ned_m: tuple[float, float, float] | None = None
    target_velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    target_accel_ned_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    target_yaw_rad: float = math.nan
    target_lat_deg: float = math.nan
    target_lon_deg: float = math.nan
    target_alt_amsl_m: float = math.nan


@dataclass(frozen=True)
class StatusTextEvent:
    """Send a STATUSTEXT (texts longer than 50 characters are split into chunks)."""

    severity: MavSeverity
    text: str


@dataclass(frozen=True)
class MissionItemReachedEvent:
    """The vehicle reached mission item ``seq`` (MISSION_ITEM_REACHED)."""

    seq: int


@dataclass(frozen=True)
class ModeChangedEvent:
    """The flight mode changed (for any reason, e.g. a failsafe); a HEARTBEAT is sent at once."""

    mode: CopterMode


@dataclass(frozen=True)
class HomeChangedEvent:
    """Home was set or moved; HOME_POSITION is sent at once."""


VehicleEvent = StatusTextEvent | MissionItemReachedEvent | ModeChangedEvent | HomeChangedEvent


# --------------------------------------------------------------------------- protocol


@runtime_checkable
class Vehicle(Protocol):
    """What the MAVLink server needs from the flight core.

    The server validates MAVLink input (NaN, ranges, target ids, mode preconditions that
    are pure protocol matters) before calling; the vehicle decides everything that depends
    on its state and answers with an :class:`Outcome`.
    """

    def telemetry(self) -> VehicleTelemetry:
        """Current state snapshot (cheap; called once per poll)."""

    def drain_events(self) -> list[VehicleEvent]:
        """Events since the last call (a new list each call)."""

    def arm(self, force: bool) -> Outcome:
        """Arm the motors; ``force`` skips pre-arm checks (param2 2989 or 21196)."""

    def disarm(self, force: bool) -> Outcome:
        """Disarm; without ``force`` ArduCopter refuses while flying."""

    def set_mode(self, mode: CopterMode) -> Outcome:
        """Change flight mode; only called with a mode in ``modes.SUPPORTED_MODES``."""

    def takeoff(self, alt_m: float, must_navigate: bool = True) -> Outcome:
        """Take off to ``alt_m`` metres above home (armed, landed; GUIDED, LOITER, POSHOLD, and
        ALT_HOLD when not ``must_navigate``: NAV_TAKEOFF param3 != 0, as ArduCopter)."""

    def land(self) -> Outcome:
        """Land at the current position (ArduCopter switches to LAND)."""

    def return_to_launch(self) -> Outcome:
        """Return home (ArduCopter switches to RTL; RTL_ALT etc. apply)."""

    def start_mission(self, first_seq: int, last_seq: int) -> Outcome:
        """MAV_CMD_MISSION_START: switch to AUTO and run the mission. The server only passes
        ``0, 0`` (the whole mission); ArduCopter refuses first/last items too."""

    def set_current_mission_item(self, seq: int) -> Outcome:
        """Continue the mission at item ``seq`` (1..n)."""

    def jump_to_landing_sequence(self) -> Outcome:
        """MAV_CMD_DO_LAND_START: continue the mission in AUTO at the DO_LAND_START item nearest
        to the vehicle, reported as mode AUTO_RTL (ArduCopter ``jump_to_landing_sequence_auto_RTL``)."""

    def fence_enable(self, action: int, fence_mask: int) -> Outcome:
        """MAV_CMD_DO_FENCE_ENABLE: ``action`` 0 disable, 1 enable, 2 disable the floor only, for
        the FENCE_TYPE bits ``fence_mask`` (0 = every fence); not stored in FENCE_ENABLE
        (ArduPilot ``GCS_MAVLINK::handle_command_do_fence_enable``)."""

    def reposition(self, lat_deg: float, lon_deg: float, alt_m: float, alt_frame: AltFrame,
                   speed_m_s: float | None, yaw_deg: float | None) -> Outcome:
        """Fly to a point in GUIDED (MAV_CMD_DO_REPOSITION); the server has already switched
        to GUIDED when the command asked for it. ``None`` = keep the current speed/yaw."""

    def change_speed(self, speed_type: SpeedType, speed_m_s: float) -> Outcome:
        """MAV_CMD_DO_CHANGE_SPEED (speed > 0)."""

    def condition_yaw(self, angle_deg: float, rate_deg_s: float, direction: int,
                      relative: bool) -> Outcome:
        """MAV_CMD_CONDITION_YAW: heading 0..360 deg (relative: an offset, ``direction`` -1 ccw)."""

    def set_roi(self, lat_deg: float, lon_deg: float, alt_m: float, alt_frame: AltFrame) -> Outcome:
        """MAV_CMD_DO_SET_ROI(_LOCATION) / DO_SET_ROI_NONE: face the location; lat = lon = 0 clears."""

    def pause_continue(self, pause: bool) -> Outcome:
        """MAV_CMD_DO_PAUSE_CONTINUE: stop and hold (``pause``) or continue."""

    def rc_channels_override(self, channels: tuple[int, ...]) -> None:
        """RC_CHANNELS_OVERRIDE chan1_raw..chan18_raw from SYSID_MYGCS (raw, as sent)."""

    def manual_control(self, x: float, y: float, z: float, r: float) -> None:
        """MANUAL_CONTROL from SYSID_MYGCS: pitch, roll, throttle, yaw (-1000..1000; z 0..1000)."""

    def set_position_target_local_ned(self, target: LocalPositionTarget) -> None:
        """GUIDED setpoint; only called in GUIDED mode with a valid target."""

    def set_position_target_global_int(self, target: GlobalPositionTarget) -> None:
        """GUIDED setpoint; only called in GUIDED mode with a valid target."""

    def vision_position_estimate(self, usec: int, x_ned_m: float, y_ned_m: float,
                                 z_ned_m: float, roll_rad: float, pitch_rad: float,
                                 yaw_rad: float, covariance: tuple[float, ...],
                                 reset_counter: int) -> None:
        """External-navigation pose (VISION_POSITION_ESTIMATE); only called with VISO_TYPE != 0
        and finite position/attitude. ``covariance`` is the 21-element upper triangle."""

    def odometry(self, odom: Odometry) -> None:
        """External-navigation odometry (ODOMETRY); only called with VISO_TYPE != 0."""

    def param_changed(self, name: str, value: float) -> None:
        """A parameter changed (already validated and stored)."""

    def mission_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        """A complete new mission (items seq 1..n; empty = cleared). Refuse to keep the old one."""

    def fence_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        """A complete new fence (mission_type FENCE items, seq 0..n-1; empty = cleared)."""

    def rally_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        """New rally points (mission_type RALLY, NAV_RALLY_POINT items; empty = cleared)."""

    def set_ekf_source_set(self, number: int) -> Outcome:
        """SET_EKF_SOURCE_SET: use the EK3_SRC<number>_* sources (1..3)."""

    def run_prearm_checks(self) -> list[str]:
        """RUN_PREARM_CHECKS (disarmed): every failing pre-arm check's text, [] when all pass."""

    def set_home(self, home: HomeLocation | None) -> Outcome:
        """DO_SET_HOME: at ``home``, or at the current position for None; emits HomeChangedEvent."""

    def set_gps_global_origin(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Outcome:
        """SET_GPS_GLOBAL_ORIGIN (valid lat/lon): the EKF origin, only while none is set (ArduPilot
        ``set_ekf_origin``); refused without a text once it is."""

    def motor_test(self, request: MotorTestRequest) -> Outcome:
        """DO_MOTOR_TEST (``autopilot_bridge.motor_test``); refusals announce their own text."""

    def reboot(self) -> None:
        """PREFLIGHT_REBOOT_SHUTDOWN param1 1 (the server checked: disarmed): start again as after
        power-up: parameters as stored, the EKF aligned anew, home set again; mission, fence and
        rally are handed over again by the server (ArduPilot keeps them in its storage)."""
