"""Every message on the scenenav bus: one frozen dataclass each, versioned, with ``timestamp_us``.

Encoding (documented for other languages in docs/interfaces.md):

* Small messages are UTF-8 JSON objects: ``{"type": <class name>, "version": <int>, <fields>...}``.
  Vectors are JSON arrays of fixed length; non-finite floats (NaN, inf) travel as ``null`` and decode
  to NaN. Unknown extra keys are ignored (forward compatibility); missing keys are errors, except
  that a message of an older version a class still reads (``READABLE_VERSIONS``) may lack the fields
  a later version added (those with a default; ``FIELD_VERSIONS`` says which version added which),
  which then take their default.
* ``CameraFrame`` is binary: ``uint32 little-endian header length N`` + ``N bytes JSON header`` (the
  same JSON form as above, without the pixels) + raw pixel bytes, row-major, top row first, with the
  shape and encoding stated in the header.

``encode(msg) -> bytes`` and ``decode(cls, payload) -> msg`` are the one encode/decode pair; decode
raises ``DecodeError`` (never anything else) on garbage, so nodes can count and drop it.
All times are simulated time in microseconds since the start of the run unless a field says otherwise.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import typing
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import Any, ClassVar

import numpy as np
import orjson


class DecodeError(ValueError):
    """A payload that is not a valid message of the expected type and version."""


# ----------------------------------------------------------------------------------------- enums
class ClockMode(str, Enum):
    LOCKSTEP = "lockstep"   # the simulator waits for every lockstep member before stepping
    REALTIME = "realtime"   # paced to the wall clock times a speed factor


class RunState(str, Enum):
    STARTING = "starting"
    RUNNING = "running"
    FINISHED = "finished"


class GpsFixType(IntEnum):
    """MAVLink GPS_FIX_TYPE values."""

    NO_GPS = 0
    NO_FIX = 1
    FIX_2D = 2
    FIX_3D = 3


class ImageEncoding(str, Enum):
    RGB8 = "rgb8"    # 3 bytes per pixel, R G B
    MONO8 = "mono8"  # 1 byte per pixel


class LockstepRole(str, Enum):
    """What a lockstep member must acknowledge before the simulator steps on."""

    TICK = "tick"      # every clock tick (the autopilot: its motor command)
    CAMERA = "camera"  # every camera frame (perception: its fix for that frame)


class RotorSpin(IntEnum):
    """Spin direction of a rotor seen from above."""

    CCW = 1    # counter-clockwise: its reaction torque yaws the body clockwise
    CW = -1


class QuadXRotor(IntEnum):
    """Index of each rotor in ``MotorCommand.command``: ArduPilot's quad-X order (motors 1-4)."""

    FRONT_RIGHT = 0
    BACK_LEFT = 1
    FRONT_LEFT = 2
    BACK_RIGHT = 3

    @property
    def spin(self) -> RotorSpin:
        """ArduPilot quad X: front right and back left CCW, front left and back right CW."""
        return RotorSpin.CCW if self in (QuadXRotor.FRONT_RIGHT, QuadXRotor.BACK_LEFT) else RotorSpin.CW


class Severity(IntEnum):
    """MAVLink MAV_SEVERITY values."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


# -------------------------------------------------------------------------------------- messages
@dataclass(frozen=True)
class ClockTick:
    """Simulated time. Published by the simulator once per control tick, after that tick's sensors."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    tick: int
    tick_period_us: int
    camera_seq_acked: int        # newest camera frame every CAMERA member has answered (-1: none)
    mode: str                    # ClockMode value
    state: str                   # RunState value


@dataclass(frozen=True)
class ImuSample:
    """Accelerometer (specific force) and gyro, averaged over the tick. Body frame FLU."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    tick: int
    dt_s: float
    accel_flu_m_s2: tuple[float, float, float]
    gyro_flu_rad_s: tuple[float, float, float]


@dataclass(frozen=True)
class BaroSample:
    """Barometric altitude above the world's ground plane (z = 0) and static pressure."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    altitude_m: float
    pressure_pa: float


@dataclass(frozen=True)
class CompassSample:
    """Compass heading: clockwise from north, radians in [0, 2*pi)."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    heading_rad: float


@dataclass(frozen=True)
class GpsSample:
    """GNSS fix: WGS-84 latitude/longitude, altitude above the ground plane, ENU velocity."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    velocity_enu_m_s: tuple[float, float, float]
    eph_m: float
    epv_m: float
    fix_type: int                # GpsFixType
    satellites: int


@dataclass(frozen=True)
class FlowSample:
    """Downward optical-flow sensor with its range finder on the same axis (one module, like the ARK
    Flow: a PAW3902 flow sensor and an AFBR-S50 time-of-flight range finder), both looking along the
    body's -z axis. ``timestamp_us``: simulated time at the end of the integration interval.

    ``flow_flu_rad_s``: the apparent angular velocity (rad/s, about body x and y, FLU) of the surface
    point on the sensor's axis, averaged over the interval. For a vehicle moving with body velocity
    (vx, vy, vz) at range r and turning at body rate (wx, wy, wz) it is (-vy / r - wx, vx / r - wy):
    forward motion gives +y, rightward motion (vy < 0) +x, and a body rotation shows as its negative.
    ``body_rate_flu_rad_s``: the module's own gyro (rad/s, body x and y) over the same interval, so
    that ``flow + body_rate`` is the part due to translation. ``distance_m``: range along the axis to
    the surface (roof or ground), NaN outside the range finder's limits. ``quality``: 0 (no flow
    measured) .. 255 (MAVLink OPTICAL_FLOW's scale)."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    integration_time_us: int
    flow_flu_rad_s: tuple[float, float]
    body_rate_flu_rad_s: tuple[float, float]
    distance_m: float
    quality: int


@dataclass(frozen=True)
class CameraFrame:
    """Downward camera image. Binary payload (see module docstring).

    Image top = drone forward, image right = drone right. With ``mount == "gimbal"`` the optical axis
    is nadir whatever the attitude; with ``"fixed"`` it follows the body. ``timestamp_us`` is the
    camera's clock at the capture (docs/interfaces.md). The calibration: pinhole intrinsics (fx, fy,
    cx, cy) in continuous pixel coordinates and the Brown-Conrady distortion (k1, k2, p1, p2, OpenCV's
    order) of the lens the pixels were taken through (all zero: an ideal pinhole).
    """

    VERSION: ClassVar[int] = 2
    timestamp_us: int
    seq: int
    width_px: int
    height_px: int
    encoding: str                # ImageEncoding value
    fov_deg: float
    mount: str
    intrinsics_fx_fy_cx_cy_px: tuple[float, float, float, float]
    distortion_k1_k2_p1_p2: tuple[float, float, float, float]
    pixels: np.ndarray = field(repr=False, compare=False)


@dataclass(frozen=True)
class PowerSample:
    """What the vehicle's power module measures (ArduPilot BATT_MONITOR 4: analog voltage and
    current): battery terminal voltage and the current drawn by the whole vehicle. Published by the
    simulator; ``timestamp_us`` is the simulated time of the measurement."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    voltage_v: float
    current_a: float


@dataclass(frozen=True)
class MotorCommand:
    """Normalised rotor speed commands in [0, 1] (rotor speed = command * max rotor speed).

    ``command[i]`` drives rotor ``QuadXRotor(i)``: ArduPilot's quad-X motor order (MOT 1-4), front
    right CCW, back left CCW, front left CW, back right CW, seen from above.

    It is also the sender's lockstep answer to ``tick``: the simulator counts it as the
    ``LockstepAck`` (role tick, seq ``tick``) of the tick member ``node_id``, which then sends no
    separate ack (version 2; one bus message per tick fewer each way).
    """

    VERSION: ClassVar[int] = 2
    timestamp_us: int
    tick: int
    command: tuple[float, float, float, float]
    armed: bool
    node_id: str                 # the tick member that answers the tick with it


@dataclass(frozen=True)
class LockstepAck:
    """A lockstep member is done with a tick (role tick) or a camera frame (role camera).

    Published after the member's outputs for that tick or frame, on the same session, so the
    simulator has those outputs when it sees the ack.
    """

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    node_id: str
    role: str                    # LockstepRole value
    seq: int                     # tick number (role tick) or camera frame seq (role camera);
    #                              answers every seq up to it (a tick member may answer ahead)


@dataclass(frozen=True)
class VisionFix:
    """A scene-matching position fix for one camera frame (one per frame, even when invalid).

    ``timestamp_us`` is the capture time of the frame. ``valid`` is false when no match could be
    computed (the position is then NaN); ``accepted`` is the false-match detector's verdict.
    """

    VERSION: ClassVar[int] = 3
    #: older versions this node still reads: version 1 had no heading, version 2 no camera flow
    #: (they decode to NaN)
    READABLE_VERSIONS: ClassVar[tuple[int, ...]] = (1, 2)
    #: the version that added each later field: a message of an older version may lack it (and
    #: decodes with its default), one of that version or later must carry it
    FIELD_VERSIONS: ClassVar[dict[str, int]] = {"heading_rad": 2, "heading_std_rad": 2, "flow_flu_rad_s": 3,
                                                "flow_interval_us": 3, "flow_quality": 3}
    timestamp_us: int
    frame_seq: int
    node_id: str
    method: str                  # "cnn" | "assistant-map" | "statistical" | "none"
    valid: bool
    accepted: bool
    position_xy_enu_m: tuple[float, float]
    covariance_xy_m2: tuple[float, float, float, float]   # row-major 2x2
    p_true: float                # probability of a true match (NaN: not evaluated)
    p_classes: tuple[float, float, float, float]          # CNN softmax (bad, 4-, 3-, 2-arm); NaN if none
    ncc_peak: float
    ncc_psr: float
    ncc_second_peak_ratio: float
    time_align_ms: float
    time_ncc_ms: float
    time_cnn_ms: float
    time_lookup_ms: float
    time_total_ms: float
    # Version 2: the heading the map measured for this frame (clockwise from true north, rad, the
    # body's heading at the capture time) and its 1-sigma (rad); both NaN when not measured. The
    # autopilot fuses it as external-navigation yaw (EK3_SRC1_YAW = 6) with an accepted fix.
    heading_rad: float = math.nan
    heading_std_rad: float = math.nan
    # Version 3: the camera's own optical flow between the previous frame and this one (a camera
    # fixed to the body only): the mean apparent angular rate (rad/s about body x and y, FLU, the
    # convention of FlowSample.flow_flu_rad_s) of the surface at the image centre over
    # ``flow_interval_us`` (microseconds from the previous frame's capture time to this one's), the
    # body rotation NOT removed; ``flow_quality`` in [0, 1] (phase-correlation response). NaN / 0:
    # not measured. The autopilot fuses it with SN_CAM_FLOW 1.
    flow_flu_rad_s: tuple[float, float] = (math.nan, math.nan)
    flow_interval_us: int = 0
    flow_quality: float = math.nan


@dataclass(frozen=True)
class NavEstimate:
    """The autopilot's own navigation estimate (never ground truth)."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    position_enu_m: tuple[float, float, float]
    velocity_enu_m_s: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]
    heading_rad: float
    position_std_m: tuple[float, float, float]
    position_source: int         # ArduPilot EK3_SRC1_POSXY: 0 none, 3 GPS, 6 external nav
    vision_node_id: str          # perception node whose fixes are followed ("" when none)


@dataclass(frozen=True)
class AutopilotStatus:
    """Flight state for logs and the launcher (1 Hz and on change)."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    armed: bool
    mode: str                    # ArduCopter mode name
    landed: bool
    mission_seq: int
    mission_count: int
    mission_complete: bool
    gps_used: bool


@dataclass(frozen=True)
class TruthPose:
    """Ground truth. Only evaluation and logs read ``truth/`` keys."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    position_enu_m: tuple[float, float, float]
    velocity_enu_m_s: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]
    angular_velocity_flu_rad_s: tuple[float, float, float]
    heading_rad: float


@dataclass(frozen=True)
class NodeInfo:
    """What a node is; published when it starts (and on request by the launcher's logs)."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    node_id: str
    role: str                    # "sim", "autopilot", "perception", "guidance", "recorder", ...
    detail: str                  # e.g. the perception method


@dataclass(frozen=True)
class Event:
    """A human-readable event (like MAVLink STATUSTEXT), logged by the recorder."""

    VERSION: ClassVar[int] = 1
    timestamp_us: int
    node_id: str
    severity: int                # Severity
    text: str


MESSAGE_TYPES: tuple[type, ...] = (
    ClockTick, ImuSample, BaroSample, CompassSample, GpsSample, PowerSample, FlowSample, CameraFrame,
    MotorCommand,
    LockstepAck, VisionFix, NavEstimate, AutopilotStatus, TruthPose, NodeInfo, Event,
)
_BY_NAME = {cls.__name__: cls for cls in MESSAGE_TYPES}

# --------------------------------------------------------------------------------- field schemas
_SCHEMAS: dict[type, list[tuple[str, Any]]] = {}


def _schema(cls: type) -> list[tuple[str, Any]]:
    sch = _SCHEMAS.get(cls)
    if sch is None:
        hints = typing.get_type_hints(cls)
        sch = [(f.name, hints[f.name]) for f in dataclasses.fields(cls) if f.name != "pixels"]
        _SCHEMAS[cls] = sch
    return sch


def _enc_value(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (tuple, list)):
        return [_enc_value(v) for v in value]
    if isinstance(value, np.generic):
        return _enc_value(value.item())
    return value


def _dec_value(tp: Any, value: Any, name: str) -> Any:
    if tp is float:
        if value is None:
            return math.nan
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise DecodeError(f"field {name!r}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise DecodeError(f"field {name!r}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise DecodeError(f"field {name!r}: expected true/false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise DecodeError(f"field {name!r}: expected a string, got {value!r}")
        return value
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list) or len(value) != len(args):
            raise DecodeError(f"field {name!r}: expected a list of {len(args)} values, got {value!r}")
        return tuple(_dec_value(a, v, name) for a, v in zip(args, value, strict=False))
    raise DecodeError(f"field {name!r}: unsupported type {tp}")


_KIND_FLOAT, _KIND_FLOATS, _KIND_PLAIN = 0, 1, 2
_FLOAT_ONLY = frozenset({float})
_TUPLE_LEN: dict[Any, int] = {}


def _tuple_len(tp: Any) -> int:
    n = _TUPLE_LEN.get(tp)
    if n is None:
        n = _TUPLE_LEN[tp] = len(typing.get_args(tp))
    return n
_ENC_SPECS: dict[type, list[tuple[str, int]]] = {}
_isfinite = math.isfinite


def _enc_spec(cls: type) -> list[tuple[str, int]]:
    spec = _ENC_SPECS.get(cls)
    if spec is None:
        spec = []
        for name, tp in _schema(cls):
            if tp is float:
                kind = _KIND_FLOAT
            elif typing.get_origin(tp) is tuple and all(a is float for a in typing.get_args(tp)):
                kind = _KIND_FLOATS
            else:
                kind = _KIND_PLAIN
            spec.append((name, kind))
        _ENC_SPECS[cls] = spec
    return spec


def _to_json_obj(msg: Any) -> dict:
    cls = type(msg)
    obj: dict[str, Any] = {"type": cls.__name__, "version": cls.VERSION}
    for name, kind in _enc_spec(cls):
        value = getattr(msg, name)
        if kind == _KIND_FLOAT:
            obj[name] = float(value)          # orjson writes NaN and inf as null
        elif kind == _KIND_FLOATS:
            obj[name] = [float(v) for v in value]
        else:
            obj[name] = _enc_value(value)
    return obj


def _added_fields(cls: type) -> frozenset[str]:
    """The fields with a default: those a later version added (an older message may lack them)."""
    added = _ADDED.get(cls)
    if added is None:
        added = frozenset(f.name for f in dataclasses.fields(cls)
                          if f.default is not dataclasses.MISSING
                          or f.default_factory is not dataclasses.MISSING)
        _ADDED[cls] = added
    return added


_ADDED: dict[type, frozenset[str]] = {}


def _added_in(cls: type[Any], name: str) -> int:
    """The version that added the defaulted field ``name`` (``FIELD_VERSIONS``; without it: the
    class's current version, so that every older version may lack it)."""
    versions: dict[str, int] = getattr(cls, "FIELD_VERSIONS", {})
    return int(versions.get(name, cls.VERSION))


def _from_json_obj(cls: type[Any], obj: Any) -> Any:
    if not isinstance(obj, dict):
        raise DecodeError(f"{cls.__name__}: expected a JSON object")
    if obj.get("type") != cls.__name__:
        raise DecodeError(f"expected type {cls.__name__}, got {obj.get('type')!r}")
    version = obj.get("version")
    older = version != cls.VERSION
    if older and (type(version) is not int or version not in getattr(cls, "READABLE_VERSIONS", ())):
        raise DecodeError(f"{cls.__name__}: unsupported version {version!r} "
                          f"(this node speaks version {cls.VERSION})")
    kwargs: dict[str, Any] = {}
    version_n: int = version if type(version) is int else cls.VERSION      # an int when older
    for (name, tp), (_, kind) in zip(_schema(cls), _enc_spec(cls), strict=False):
        try:
            value = obj[name]
        except KeyError:
            if older and name in _added_fields(cls) and _added_in(cls, name) > version_n:
                continue                    # a field a later version added: its default
            raise DecodeError(f"{cls.__name__}: missing field {name!r}") from None
        if kind == _KIND_FLOAT and type(value) is float:              # fast path
            kwargs[name] = value
        elif kind == _KIND_FLOATS and type(value) is list and len(value) == _tuple_len(tp) \
                and set(map(type, value)) <= _FLOAT_ONLY:
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = _dec_value(tp, value, name)
    return kwargs


_HEADER = struct.Struct("<I")
_CHANNELS = {ImageEncoding.RGB8.value: 3, ImageEncoding.MONO8.value: 1}


def encode(msg: Any) -> bytes:
    """Serialise any bus message to its wire form."""
    if isinstance(msg, CameraFrame):
        header = orjson.dumps(_to_json_obj(msg))
        pixels = np.ascontiguousarray(msg.pixels, dtype=np.uint8)
        return _HEADER.pack(len(header)) + header + pixels.tobytes()
    return orjson.dumps(_to_json_obj(msg))


def decode(cls: type, payload: bytes | bytearray | memoryview) -> Any:
    """Parse ``payload`` as a ``cls`` message; ``DecodeError`` on anything malformed."""
    data = bytes(payload)
    if cls is CameraFrame:
        if len(data) < _HEADER.size:
            raise DecodeError("CameraFrame: truncated header length")
        (n,) = _HEADER.unpack_from(data)
        if n > len(data) - _HEADER.size:
            raise DecodeError("CameraFrame: header length beyond the payload")
        try:
            obj = orjson.loads(data[_HEADER.size:_HEADER.size + n])
        except orjson.JSONDecodeError as exc:
            raise DecodeError(f"CameraFrame: header is not JSON ({exc})") from None
        kwargs = _from_json_obj(cls, obj)
        channels = _CHANNELS.get(kwargs["encoding"])
        if channels is None:
            raise DecodeError(f"CameraFrame: unknown encoding {kwargs['encoding']!r}")
        w, h = kwargs["width_px"], kwargs["height_px"]
        if w <= 0 or h <= 0:
            raise DecodeError(f"CameraFrame: bad size {w}x{h}")
        raw = data[_HEADER.size + n:]
        if len(raw) != w * h * channels:
            raise DecodeError(f"CameraFrame: {len(raw)} pixel bytes, expected {w * h * channels}")
        shape = (h, w, channels) if channels > 1 else (h, w)
        pixels = np.frombuffer(raw, dtype=np.uint8).reshape(shape)
        return cls(pixels=pixels, **kwargs)
    try:
        obj = orjson.loads(data)
    except orjson.JSONDecodeError as exc:
        raise DecodeError(f"{cls.__name__}: not JSON ({exc})") from None
    return cls(**_from_json_obj(cls, obj))


def message_type(name: str) -> type:
    """The message class called ``name`` (for tools such as the recorder)."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise DecodeError(f"unknown message type {name!r}") from None


def schema_of(cls: type) -> list[tuple[str, str]]:
    """(field name, type text) pairs, for documentation and the MCAP schemas."""
    out = []
    for name, tp in _schema(cls):
        out.append((name, getattr(tp, "__name__", str(tp)) if not typing.get_origin(tp) else str(tp)))
    if cls is CameraFrame:
        out.append(("pixels", "raw bytes after the JSON header"))
    return out
