"""ArduCopter-compatible flight core: the :class:`~autopilot_bridge.vehicle_interface.Vehicle` that the
MAVLink server flies, on the scenenav algorithms (navigation filter, cascaded controller, mixer,
guidance laws).

Pure module: no zenoh, no pymavlink. The autopilot node (``autopilot_bridge.node``) feeds it bus
sensor data and ticks it; the MAVLink server (``autopilot_bridge.mavlink_server``) calls the
Vehicle methods from the same thread. Everything runs on simulated time (``now_s``), so a lockstep
run is deterministic.

Per control tick (``step``): EKF predict with the tick's IMU sample, fuse the buffered baro /
compass / GPS / vision measurements, run the failsafes, compute the mode's target, run the
controller and the mixer; the result is the four normalised motor commands (zeros disarmed).

Frames. Bus side (inputs, ``NavEstimate``): world ENU metres, body FLU, heading clockwise from north.
MAVLink side (``VehicleTelemetry`` and the targets the server hands over): NED metres from the EKF
origin (= the point where the filter was aligned, on the ground), body FRD, latitude/longitude through
``scenenav.core.frames`` around the world's geodetic origin, altitudes AMSL = ``origin_alt_amsl_m`` + ENU z.

Modes (ArduCopter numbers, ``autopilot_bridge.modes``): STABILIZE and ALT_HOLD without RC (level
attitude; hover thrust / hold altitude), GUIDED (position, position+velocity, velocity and
acceleration targets, DO_REPOSITION, takeoff), AUTO (NAV_TAKEOFF, NAV_WAYPOINT with hold time,
NAV_LAND, NAV_RETURN_TO_LAUNCH, DO_CHANGE_SPEED; other stored commands are skipped), LOITER (hold),
RTL (climb to RTL_ALT, return, loiter RTL_LOIT_TIME, land or hold at RTL_ALT_FINAL) and LAND. LAND,
RTL and AUTO landings disarm at touchdown; other modes disarm DISARM_DELAY s after landing.

Position source (EK3_SRC1_POSXY, switchable in flight): 3 GPS, 6 external navigation (scene-matching
fixes from the bus, or VISION_POSITION_ESTIMATE / ODOMETRY over MAVLink), 0 none. Vision fixes are
fused only when valid and accepted by the perception node, younger than ``vision_max_age_s`` and
taken at least SN_VIS_MIN_ALT above home (scene matching needs a large ground footprint). On the
ground without a position source the last landed position is fused as a pseudo-measurement (as
ArduPilot's EKF does when it is not aiding), so the estimate does not drift before take-off.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter
from dataclasses import dataclass
from enum import Enum, IntFlag
from typing import NamedTuple, Sequence

import numpy as np

from autopilot_bridge.airframe import AIRFRAME_PARAM_NAMES, Airframe
from autopilot_bridge.battery import BatteryMonitor
from autopilot_bridge.config import (AutopilotAlgorithmsConfig, ControlConfig, FlightCoreConfig,
                                     GuidanceConfig, MissionEndMode, PositionSource, YawBehaviour)
from autopilot_bridge.control import ControlOutput, FlightController, PositionTarget, stopping_point
from autopilot_bridge.ekf import NavFilter, NavState
from autopilot_bridge.failsafe import (FailsafeAction, FailsafeEvent, FailsafeInputs,
                                       FailsafeKind, FailsafeMonitor, FailsafeSettings)
from autopilot_bridge.guidance_law import (GuidanceEventKind, Lander, ReturnToLaunch, RtlPhase,
                                           Waypoint, WaypointTracker, make_takeoff)
from autopilot_bridge.mixer import QuadXMixer
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.vehicle_interface import (
    DEFAULT_SENSORS,
    AltFrame,
    GlobalPositionTarget,
    HomeChangedEvent,
    LandedState,
    LocalPositionTarget,
    MavFrame,
    MavSeverity,
    MissionCommand,
    MissionItem,
    MissionItemReachedEvent,
    MissionState,
    ModeChangedEvent,
    Odometry,
    Outcome,
    SensorFlag,
    SetpointKind,
    SpeedType,
    StatusTextEvent,
    SystemStatus,
    VehicleEvent,
    VehicleTelemetry,
)
from scenenav.core.contracts import GpsFixType
from scenenav.core.frames import enu_to_geodetic, geodetic_to_enu, wrap_pi
from scenenav.core.numeric import all_finite
from scenenav.core.rotations import aviation_euler_from_quat

logger = logging.getLogger(__name__)

_TWO_PI = 2.0 * math.pi

NAV_COMMANDS = frozenset({MissionCommand.NAV_WAYPOINT, MissionCommand.NAV_TAKEOFF,
                          MissionCommand.NAV_LAND, MissionCommand.NAV_RETURN_TO_LAUNCH})
POSITION_MODES = frozenset({CopterMode.GUIDED, CopterMode.AUTO, CopterMode.LOITER,
                            CopterMode.RTL, CopterMode.LAND})
# Modes that need a horizontal position estimate to be entered (ArduCopter requires_GPS()).
NEEDS_POSITION = frozenset({CopterMode.GUIDED, CopterMode.AUTO, CopterMode.LOITER, CopterMode.RTL})
# Modes a ground station may arm in (ArduCopter Mode::allows_arming for GCS arming).
ARMABLE_MODES = frozenset({CopterMode.STABILIZE, CopterMode.ALT_HOLD, CopterMode.GUIDED,
                           CopterMode.LOITER})
GPS_FRESH_S = 2.0
TAKEOFF_DONE_TOLERANCE_M = 0.5
SAME_TARGET_M = 0.01
MAX_VELOCITY_TARGET_M_S = 30.0


class EkfStatusFlag(IntFlag):
    """MAVLink EKF_STATUS_FLAGS (EKF_STATUS_REPORT.flags)."""

    ATTITUDE = 1
    VELOCITY_HORIZ = 2
    VELOCITY_VERT = 4
    POS_HORIZ_REL = 8
    POS_HORIZ_ABS = 16
    POS_VERT_ABS = 32
    POS_VERT_AGL = 64
    CONST_POS_MODE = 128
    PRED_POS_HORIZ_REL = 256
    PRED_POS_HORIZ_ABS = 512
    UNINITIALIZED = 1024
    GPS_GLITCH = 32768


class LawKind(Enum):
    """What the active guidance law is doing (decides e.g. whether it may leave the ground)."""

    HOLD = "hold"
    TAKEOFF = "takeoff"
    TRACK = "track"
    LAND = "land"
    RTL = "rtl"


class AutoStage(Enum):
    """Where AUTO is in the current mission item."""

    IDLE = "idle"
    TAKEOFF = "takeoff"
    WAYPOINTS = "waypoints"
    WP_DELAY = "wp_delay"
    LAND_APPROACH = "land_approach"
    LAND = "land"
    RTL = "rtl"
    COMPLETE = "complete"


# ------------------------------------------------------------------------------- data


class ImuReading(NamedTuple):
    accel_flu_m_s2: tuple[float, float, float]
    gyro_flu_rad_s: tuple[float, float, float]


@dataclass(frozen=True)
class GpsReading:
    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float                                  # above the world's ground plane
    velocity_enu_m_s: tuple[float, float, float]
    eph_m: float
    epv_m: float
    fix_type: int
    satellites: int


@dataclass(frozen=True)
class _VisionReading:
    t_s: float                                    # capture time
    xy_enu_m: tuple[float, float]
    cov_m2: np.ndarray                            # (2, 2)
    source: str


@dataclass(frozen=True)
class CoreStatus:
    """What the node publishes as AutopilotStatus."""

    armed: bool
    mode: str
    landed: bool
    mission_seq: int
    mission_count: int
    mission_complete: bool
    gps_used: bool


@dataclass(frozen=True)
class GeoFrame:
    """ENU metres <-> WGS-84 around the world origin (scenenav.core.frames), AMSL = origin + z."""

    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_amsl_m: float = 0.0

    def to_geodetic(self, x_m: float, y_m: float) -> tuple[float, float]:
        return enu_to_geodetic(x_m, y_m, self.origin_lat_deg, self.origin_lon_deg)

    def to_enu(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        return geodetic_to_enu(lat_deg, lon_deg, self.origin_lat_deg, self.origin_lon_deg)


def ned_to_enu(v) -> np.ndarray:
    return np.array([float(v[1]), float(v[0]), -float(v[2])])


def enu_to_ned(v) -> tuple[float, float, float]:
    return (float(v[1]), float(v[0]), -float(v[2]))


def build_route_mission(geo: GeoFrame, route_enu_m: Sequence[Sequence[float]], altitude_m: float,
                        end: MissionEndMode) -> tuple[MissionItem, ...]:
    """A mission for a route: NAV_TAKEOFF to ``altitude_m`` above home, one NAV_WAYPOINT per route
    point at that height, then NAV_LAND at the last point or NAV_RETURN_TO_LAUNCH (seq 1..n)."""
    rel = int(MavFrame.GLOBAL_RELATIVE_ALT_INT)
    items = [MissionItem(seq=1, command=int(MissionCommand.NAV_TAKEOFF), frame=rel,
                         alt_m=float(altitude_m))]
    last = (0, 0)
    for x, y in route_enu_m:
        lat, lon = geo.to_geodetic(float(x), float(y))
        last = (int(round(lat * 1e7)), int(round(lon * 1e7)))
        items.append(MissionItem(seq=len(items) + 1, command=int(MissionCommand.NAV_WAYPOINT),
                                 frame=rel, lat_e7=last[0], lon_e7=last[1],
                                 alt_m=float(altitude_m)))
    if end == MissionEndMode.RTL:
        items.append(MissionItem(seq=len(items) + 1,
                                 command=int(MissionCommand.NAV_RETURN_TO_LAUNCH), frame=rel))
    else:
        items.append(MissionItem(seq=len(items) + 1, command=int(MissionCommand.NAV_LAND),
                                 frame=rel, lat_e7=last[0], lon_e7=last[1]))
    return tuple(items)


# ------------------------------------------------------------------------------- laws


class _Hold:
    """Hold a fixed point (LOITER, GUIDED without a target, end of mission, vision failsafe)."""

    kind = LawKind.HOLD

    def __init__(self, position_enu_m, heading_rad: float | None) -> None:
        p = np.asarray(position_enu_m, dtype=float)
        self.position = np.array([p[0], p[1], p[2]])
        self.heading = heading_rad

    @property
    def complete(self) -> bool:
        return True

    def pop_events(self) -> list:
        return []

    def handle_position_reset(self, delta_xy_m) -> None:
        self.position[0] += float(delta_xy_m[0])
        self.position[1] += float(delta_xy_m[1])

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        p = self.position
        return PositionTarget((float(p[0]), float(p[1]), float(p[2])), heading_rad=self.heading)


class _Tracker(WaypointTracker):
    """WaypointTracker that can change speed and destination in flight (DO_CHANGE_SPEED,
    WPNAV_SPEED, streamed GUIDED targets) without restarting the carrot from rest.

    Relies on WaypointTracker's protected state (``_wps``, ``_index``, ``_origin``, ``_s``, ``_v``,
    ``_setup_segment``): the carrot keeps its along-track speed, capped by the new limits.
    """

    kind = LawKind.TRACK

    @property
    def destination(self) -> np.ndarray:
        return np.array(self._wps[-1].position_enu_m)

    def retune(self, cfg: GuidanceConfig) -> None:
        self._cfg = cfg
        self._restart_segment(keep_origin=True)

    def set_speed(self, speed_m_s: float | None) -> None:
        """Horizontal speed of the current and the remaining legs (None: WPNAV_SPEED)."""
        self._wps = [Waypoint(w.position_enu_m, w.acceptance_radius_m, speed_m_s) for w in self._wps]
        self._restart_segment(keep_origin=True)

    def redirect(self, waypoints: Sequence[Waypoint]) -> None:
        """New destination(s) from the current carrot, keeping its speed."""
        carrot = self._carrot()
        self._wps = [Waypoint(tuple(float(a) for a in w.position_enu_m), w.acceptance_radius_m,
                              w.speed_m_s) for w in waypoints]
        self._index = 0
        self._complete = False
        self._origin = carrot
        self._s = 0.0
        self._restart_segment(keep_origin=True)

    def _restart_segment(self, keep_origin: bool) -> None:
        if self._complete:
            return
        v = self._v
        s = self._s
        self._setup_segment()
        self._s = min(s, self._length)
        self._v = min(v, self._v_max)


class _Rtl:
    """ReturnToLaunch plus RTL_ALT_FINAL (hold above home instead of landing when > 0)."""

    kind = LawKind.RTL

    def __init__(self, cfg: GuidanceConfig, home_enu_m, nav: NavState, final_alt_m: float,
                 heading_rad: float | None) -> None:
        self._rtl = ReturnToLaunch(cfg, home_enu_m, nav)
        self._home = np.asarray(home_enu_m, dtype=float)
        self._final_alt_m = final_alt_m
        self._final: _Hold | None = None
        self._heading = heading_rad
        self._events: list = []

    @property
    def complete(self) -> bool:
        return False

    @property
    def landing(self) -> bool:
        return self._final is None and self._rtl.phase == RtlPhase.LAND

    @property
    def phase_name(self) -> str:
        return "final" if self._final is not None else self._rtl.phase.value

    def pop_events(self) -> list:
        events, self._events = self._events, []
        return events

    def handle_position_reset(self, delta_xy_m) -> None:
        if self._final is not None:
            self._final.handle_position_reset(delta_xy_m)
        else:
            self._rtl.handle_position_reset(delta_xy_m)

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        if self._final is not None:
            return self._final.update(nav, dt_s)
        target = self._rtl.update(nav, dt_s)
        for ev in self._rtl.pop_events():
            self._events.append(ev)
            if (ev.kind == GuidanceEventKind.PHASE_CHANGED and ev.detail == RtlPhase.LAND.value
                    and self._final_alt_m > 0.0):
                h = self._home
                self._final = _Hold((h[0], h[1], h[2] + self._final_alt_m), target.heading_rad)
        if target.heading_rad is None and self._heading is not None:
            target = dataclasses.replace(target, heading_rad=self._heading)
        return target


class _Land(Lander):
    kind = LawKind.LAND


@dataclass
class _GuidedCommand:
    """A GUIDED velocity / position+velocity / acceleration setpoint and when it arrived."""

    kind: SetpointKind
    position_enu_m: np.ndarray | None
    velocity_enu_m_s: np.ndarray | None
    accel_enu_m_s2: np.ndarray | None
    t_s: float


# ------------------------------------------------------------------------------- core


class FlightCore:
    """The flight core; see the module docstring. Not thread-safe: call from one thread."""

    def __init__(self, params: ParameterStore, cfg: FlightCoreConfig | None = None,
                 algorithms: AutopilotAlgorithmsConfig | None = None) -> None:
        self.params = params
        self.cfg = cfg if cfg is not None else FlightCoreConfig()
        self._algo = algorithms if algorithms is not None else AutopilotAlgorithmsConfig()
        self.airframe = Airframe.from_params(params)
        self.geo = GeoFrame(self.cfg.origin_lat_deg, self.cfg.origin_lon_deg,
                            self.cfg.origin_alt_amsl_m)
        source = self._source_param()
        self.nav = NavFilter(dataclasses.replace(self._algo.ekf, position_source=source))
        self.fc = FlightController(self._control_config(), self.airframe)
        self.mixer = QuadXMixer(self.airframe)
        self.failsafe = FailsafeMonitor()
        self.battery = BatteryMonitor()
        self.stats: Counter[str] = Counter()
        self._now_s = 0.0
        self._armed = False
        self._mode = CopterMode.STABILIZE
        self._home: np.ndarray | None = None
        self._origin: np.ndarray | None = None
        self._ground_xy = np.array(self.cfg.start_enu_m, dtype=float)
        self._ground_next_s = 0.0
        self._landed_since_s: float | None = None
        self._contact_s = 0.0
        # alignment accumulators
        self._align_t0: float | None = None
        self._align_accel = np.zeros(3)
        self._align_gyro = np.zeros(3)
        self._align_n = 0
        self._align_baro: list[float] = []
        self._align_hdg = np.zeros(2)
        self._align_hdg_n = 0
        self._align_gps: list[tuple[float, float]] = []
        # buffered measurements (fused at the next step, after the predict)
        self._baro: list[float] = []
        self._compass: list[float] = []
        self._gps: list[GpsReading] = []
        self._vision: list[_VisionReading] = []
        self._last_gps: GpsReading | None = None
        self._last_gps_fused_s: float | None = None
        self._last_usable_vision_s: float | None = None
        self._last_ext_nav_s: float | None = None
        self._vision_available = False
        self._gcs_heartbeat_s: float | None = None
        # guidance
        self._law: object | None = None
        self._guided: _GuidedCommand | None = None
        self._guided_heading: float | None = None
        self._guided_yaw_rate: float | None = None
        self._guided_yaw_until_s = 0.0
        self._vision_hold: _Hold | None = None
        self._speed_xy: float | None = None
        self._speed_up: float | None = None
        self._speed_dn: float | None = None
        self._gcfg = self._guidance_config()
        self._last_target: PositionTarget | None = None
        self._pos_resets = 0
        # mission
        self._mission: tuple[MissionItem, ...] = ()
        self._mission_index = 0
        self._mission_state = MissionState.NO_MISSION
        self._auto_stage = AutoStage.IDLE
        self._auto_group: list[int] = []
        self._auto_group_speeds: list[float | None] = []
        self._auto_delay_until_s = 0.0
        self._auto_land_xy: tuple[float, float] | None = None
        # outputs
        self._motors = np.zeros(4)
        self._last_out: ControlOutput | None = None
        self._gyro = np.zeros(3)
        self._events: list[VehicleEvent] = []
        self._texts: list[tuple[MavSeverity, str]] = []
        self._tel: VehicleTelemetry | None = None
        params.add_observer(self._on_param)

    # =========================================================================== properties
    @property
    def now_s(self) -> float:
        return self._now_s

    @property
    def aligned(self) -> bool:
        return self.nav.aligned

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def mode(self) -> CopterMode:
        return self._mode

    @property
    def landed(self) -> bool:
        return self.fc.landed

    @property
    def home_enu_m(self) -> np.ndarray | None:
        return None if self._home is None else self._home.copy()

    @property
    def mission(self) -> tuple[MissionItem, ...]:
        return self._mission

    @property
    def mission_state(self) -> MissionState:
        return self._mission_state

    @property
    def position_source(self) -> PositionSource:
        return self.nav.position_source

    @property
    def gps_used(self) -> bool:
        return (self.nav.position_source == PositionSource.GPS and self._last_gps_fused_s is not None
                and self._now_s - self._last_gps_fused_s <= GPS_FRESH_S)

    def estimate(self) -> NavState | None:
        return self.nav.state() if self.nav.aligned else None

    def status(self) -> CoreStatus:
        seq = self._mission_index + 1 if self._mission else 0
        return CoreStatus(armed=self._armed, mode=self._mode.name, landed=self.fc.landed,
                          mission_seq=seq, mission_count=len(self._mission),
                          mission_complete=self._mission_state == MissionState.COMPLETE,
                          gps_used=self.gps_used)

    def drain_texts(self) -> list[tuple[MavSeverity, str]]:
        """Everything worth an Event on the bus since the last call (STATUSTEXTs included)."""
        texts, self._texts = self._texts, []
        return texts

    def close(self) -> None:
        self.params.remove_observer(self._on_param)

    # =========================================================================== inputs
    def set_gcs_heartbeat(self, last_heartbeat_s: float | None) -> None:
        """Newest heartbeat time (simulated seconds) of the ground station SYSID_MYGCS."""
        self._gcs_heartbeat_s = last_heartbeat_s

    def set_vision_available(self, available: bool) -> None:
        """Whether a perception node is being followed (a pre-arm check in GPS-denied flight)."""
        self._vision_available = bool(available)

    def on_baro(self, t_s: float, altitude_m: float) -> None:
        if not all_finite(altitude_m):
            self.stats["baro_nan"] += 1
            return
        if self.nav.aligned:
            self._baro.append(float(altitude_m))
        else:
            self._align_baro.append(float(altitude_m))

    def on_compass(self, t_s: float, heading_rad: float) -> None:
        if not all_finite(heading_rad):
            self.stats["compass_nan"] += 1
            return
        h = float(heading_rad) % _TWO_PI
        if self.nav.aligned:
            self._compass.append(h)
        else:
            self._align_hdg += (math.cos(h), math.sin(h))
            self._align_hdg_n += 1

    def on_gps(self, reading: GpsReading) -> None:
        values = (reading.lat_deg, reading.lon_deg, reading.alt_m, *reading.velocity_enu_m_s)
        if not all_finite(*values) or abs(reading.lat_deg) > 90.0 or abs(reading.lon_deg) > 180.0:
            self.stats["gps_nan"] += 1
            return
        self._last_gps = reading
        if reading.fix_type < GpsFixType.FIX_3D:
            return
        if self.nav.aligned:
            self._gps.append(reading)
        else:
            self._align_gps.append(self.geo.to_enu(reading.lat_deg, reading.lon_deg))

    def on_power(self, t_s: float, voltage_v: float, current_a: float) -> None:
        """A power-module measurement (battery voltage and current), reported over MAVLink."""
        self.battery.on_sample(t_s, voltage_v, current_a)

    def on_vision_fix(self, capture_t_s: float, xy_enu_m, cov_2x2_m2, valid: bool, accepted: bool,
                      source: str = "") -> None:
        """A scene-matching fix from the followed perception node; fused at the next step when
        usable (valid, accepted, finite, recent, taken above SN_VIS_MIN_ALT)."""
        self.stats["vision_fixes"] += 1
        if not (valid and accepted):
            self.stats["vision_not_accepted"] += 1
            return
        xy = tuple(float(v) for v in xy_enu_m)
        if len(xy) != 2 or not all_finite(*xy, capture_t_s):
            self.stats["vision_nan"] += 1
            return
        cov = np.asarray(cov_2x2_m2, dtype=float).reshape(2, 2)
        if not np.all(np.isfinite(cov)) or cov[0, 0] <= 0.0 or cov[1, 1] <= 0.0:
            cov = np.eye(2) * self.cfg.ext_nav_std_m ** 2
        self._vision.append(_VisionReading(float(capture_t_s), (xy[0], xy[1]), cov, source))

    # =========================================================================== control tick
    def step(self, dt_s: float, imu: ImuReading, now_s: float) -> np.ndarray:
        """One control tick; returns the motor commands (4,) in [0, 1] (zeros when disarmed)."""
        self._now_s = float(now_s)
        self._tel = None
        accel = np.asarray(imu.accel_flu_m_s2, dtype=float)
        gyro = np.asarray(imu.gyro_flu_rad_s, dtype=float)
        if accel.shape != (3,) or gyro.shape != (3,) or not (
                np.all(np.isfinite(accel)) and np.all(np.isfinite(gyro))
                and math.isfinite(dt_s) and 0.0 < dt_s < 1.0):
            self.stats["imu_bad"] += 1
            return self._motors.copy()
        self._gyro = gyro
        if not self.nav.aligned:
            self._accumulate_alignment(accel, gyro, dt_s)
            return self._motors.copy()
        self.nav.predict(accel, gyro, dt_s)
        self._fuse_pending()
        est = self.nav.state()
        if self.nav.position_reset_count != self._pos_resets:
            self._pos_resets = self.nav.position_reset_count
            self._handle_position_reset(self.nav.last_position_reset_m)
        self._run_failsafes(est)
        self._auto_disarm_check()
        out = self._control(est, gyro, dt_s)
        self._last_out = out
        if out is not None and (out.touchdown or self._ground_contact(out, est, dt_s)):
            self._on_touchdown(est)
        if self._armed and out is not None:
            mix = self.mixer.mix(out.thrust_n, out.torque_flu_n_m)
            self.fc.set_mixer_limits(mix.limits)
            self._motors = np.asarray(mix.commands, dtype=float)
        else:
            self._motors = np.zeros(4)
        return self._motors.copy()

    # --------------------------------------------------------------------------- alignment
    def _accumulate_alignment(self, accel: np.ndarray, gyro: np.ndarray, dt_s: float) -> None:
        if self._align_t0 is None:
            self._align_t0 = self._now_s
        self._align_accel += accel
        self._align_gyro += gyro
        self._align_n += 1
        elapsed = self._now_s - self._align_t0
        if elapsed < self.cfg.align_time_s or len(self._align_baro) < 3 or self._align_hdg_n < 3:
            return
        gps_source = self.nav.position_source == PositionSource.GPS
        if gps_source and len(self._align_gps) < 3 and elapsed < self.cfg.gps_wait_s:
            return
        accel_mean = self._align_accel / self._align_n
        gyro_mean = self._align_gyro / self._align_n
        heading = math.atan2(self._align_hdg[1], self._align_hdg[0]) % _TWO_PI
        baro = float(np.mean(self._align_baro))
        if gps_source and self._align_gps:
            xy = np.mean(np.array(self._align_gps), axis=0)
            how = "GPS"
        else:
            xy = np.array(self.cfg.start_enu_m, dtype=float)
            how = "the known take-off point"
        pos = (float(xy[0]), float(xy[1]), self.cfg.ground_z_m)
        try:
            self.nav.initialise(accel_mean, heading, baro, gyro_flu_rad_s=gyro_mean,
                                position_enu_m=pos)
        except ValueError as exc:
            logger.warning("EKF alignment failed (%s); retrying", exc)
            self._reset_alignment()
            return
        self._origin = np.array(pos)
        self._home = np.array(pos)
        self._ground_xy = np.array(pos[:2])
        self._ground_next_s = self._now_s
        self.fc.reset(self.nav.state(), landed=True)
        self._events.append(HomeChangedEvent())
        self._announce(MavSeverity.INFO, "EKF3 IMU0 origin set")
        self._announce(MavSeverity.INFO, f"EKF3 IMU0 is using {self._source_name()}")
        self._bus_text(MavSeverity.INFO, f"EKF aligned at ({pos[0]:.1f}, {pos[1]:.1f}) m from {how}")
        self._baro.clear()
        self._compass.clear()

    def _reset_alignment(self) -> None:
        self._align_t0 = None
        self._align_accel[:] = 0.0
        self._align_gyro[:] = 0.0
        self._align_n = 0
        self._align_baro.clear()
        self._align_hdg[:] = 0.0
        self._align_hdg_n = 0
        self._align_gps.clear()

    # --------------------------------------------------------------------------- fusion
    def _fuse_pending(self) -> None:
        nav = self.nav
        for alt in self._baro:
            nav.fuse_baro(alt)
        self._baro.clear()
        for hdg in self._compass:
            nav.fuse_compass(hdg)
        self._compass.clear()
        for g in self._gps:
            x, y = self.geo.to_enu(g.lat_deg, g.lon_deg)
            age = max(0.0, self._now_s - g.t_s)
            r = nav.fuse_gps_position((x, y, g.alt_m), max(g.eph_m, 0.1), age_s=age)
            nav.fuse_gps_velocity(g.velocity_enu_m_s, self.cfg.gps_velocity_std_m_s)
            if r.accepted and nav.position_source == PositionSource.GPS:
                self._last_gps_fused_s = self._now_s
        self._gps.clear()
        for v in self._vision:
            self._fuse_vision(v)
        self._vision.clear()
        self._ground_fusion()

    def _height_above_home(self) -> float:
        home_z = self._home[2] if self._home is not None else self.cfg.ground_z_m
        return float(self.nav.state().position_enu_m[2]) - float(home_z)

    def _fuse_vision(self, v: _VisionReading) -> None:
        age = self._now_s - v.t_s
        if age > self.cfg.vision_max_age_s or age < -0.5:
            self.stats["vision_stale"] += 1
            return
        if v.source != "mavlink" and self._height_above_home() < self.params.get("SN_VIS_MIN_ALT"):
            self.stats["vision_below_min_alt"] += 1
            return
        self._last_usable_vision_s = self._now_s
        r = self.nav.fuse_vision_position(v.xy_enu_m, v.cov_m2, age_s=max(age, 0.0))
        if self.nav.position_source != PositionSource.EXTNAV:
            self.stats["vision_monitored"] += 1
        elif r.accepted:
            self.stats["vision_fused"] += 1
        else:
            self.stats["vision_rejected"] += 1

    def _ground_fusion(self) -> None:
        """On the ground without a usable external-nav fix: fuse the landed position."""
        if self.nav.position_source != PositionSource.EXTNAV or not self.fc.landed:
            return
        if (self._last_usable_vision_s is not None
                and self._now_s - self._last_usable_vision_s < 1.0):
            return
        if self._now_s < self._ground_next_s:
            return
        self._ground_next_s = self._now_s + self.cfg.ground_fusion_period_s
        std = self.cfg.ground_position_std_m
        self.nav.fuse_vision_position(self._ground_xy, np.eye(2) * std * std)
        self.stats["ground_fusions"] += 1

    def _handle_position_reset(self, delta_xy) -> None:
        logger.warning("EKF position reset by (%.1f, %.1f) m", float(delta_xy[0]), float(delta_xy[1]))
        self._bus_text(MavSeverity.WARNING, f"EKF position reset by ({float(delta_xy[0]):.1f}, "
                                            f"{float(delta_xy[1]):.1f}) m")
        for law in (self._law, self._vision_hold):
            if law is not None:
                law.handle_position_reset(delta_xy)

    # --------------------------------------------------------------------------- failsafes
    def _landing(self) -> bool:
        if self._mode == CopterMode.LAND:
            return True
        if self._mode == CopterMode.RTL and isinstance(self._law, _Rtl):
            return self._law.landing
        if self._mode == CopterMode.AUTO:
            if self._auto_stage == AutoStage.LAND:
                return True
            if self._auto_stage == AutoStage.RTL and isinstance(self._law, _Rtl):
                return self._law.landing
        return False

    def _run_failsafes(self, est: NavState) -> None:
        p = self.params
        settings = FailsafeSettings(gcs_action=p.get_int("FS_GCS_ENABLE"),
                                    gcs_timeout_s=p.get("FS_GCS_TIMEOUT"),
                                    vision_timeout_s=p.get("SN_VIS_TIMEOUT"),
                                    vision_land_after_s=p.get("SN_VIS_FS_LAND"))
        home_z = self._home[2] if self._home is not None else 0.0
        inputs = FailsafeInputs(
            now_s=self._now_s, armed=self._armed, flying=self._armed and not self.fc.landed,
            position_mode=self._mode in POSITION_MODES, landing=self._landing(),
            gcs_last_heartbeat_s=self._gcs_heartbeat_s,
            vision_required=self.nav.position_source == PositionSource.EXTNAV,
            vision_height_ok=float(est.position_enu_m[2]) - home_z >= p.get("SN_VIS_MIN_ALT"),
            last_vision_fix_s=self._last_usable_vision_s)
        for ev in self.failsafe.update(inputs, settings):
            self._apply_failsafe(ev, est)

    def _apply_failsafe(self, ev: FailsafeEvent, est: NavState) -> None:
        self._announce(ev.severity, ev.text)
        if ev.action == FailsafeAction.RTL:
            if not self._enter_mode(CopterMode.RTL, from_gcs=False).ok:
                self._enter_mode(CopterMode.LAND, from_gcs=False)
        elif ev.action == FailsafeAction.LAND:
            self._vision_hold = None
            self._enter_mode(CopterMode.LAND, from_gcs=False)
        elif ev.action == FailsafeAction.HOLD:
            stop = stopping_point(est.position_enu_m, est.velocity_enu_m_s, self._gcfg.wp_accel_m_s2)
            self._vision_hold = _Hold(stop, float(est.heading_rad))
        elif ev.action == FailsafeAction.RESUME and self._vision_hold is not None:
            self._vision_hold = None
            self._restart_mode_law(est)
        if ev.kind == FailsafeKind.GCS:
            self.stats[f"failsafe_gcs_{ev.action.value}"] += 1
        else:
            self.stats[f"failsafe_vision_{ev.action.value}"] += 1

    def _auto_disarm_check(self) -> None:
        if not self._armed:
            self._landed_since_s = None
            return
        if not self.fc.landed or self._law_kind() == LawKind.TAKEOFF or self._climb_demanded():
            self._landed_since_s = None
            return
        if self._mode == CopterMode.LAND:
            self._disarm("landed")
            return
        if self._landed_since_s is None:
            self._landed_since_s = self._now_s
        delay = self.params.get("DISARM_DELAY")
        if delay > 0 and self._now_s - self._landed_since_s >= delay:
            self._announce(MavSeverity.INFO, "Auto disarm: landed")
            self._disarm("auto disarm")

    def _climb_demanded(self) -> bool:
        g = self._guided
        return (self._mode == CopterMode.GUIDED and g is not None and g.velocity_enu_m_s is not None
                and float(g.velocity_enu_m_s[2]) > self.fc.config.takeoff_min_climb_m_s)

    # --------------------------------------------------------------------------- control
    def _law_kind(self) -> LawKind | None:
        return getattr(self._law, "kind", None) if self._law is not None else None

    def _control(self, est: NavState, gyro: np.ndarray, dt: float) -> ControlOutput | None:
        if not self._armed:
            return None
        fc = self.fc
        mode = self._mode
        if mode == CopterMode.STABILIZE:
            frac = 0.0 if fc.landed else self.airframe.hover_thrust_fraction
            return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, frac, dt)
        if mode == CopterMode.ALT_HOLD:
            return fc.update_alt_hold(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)
        if self._vision_hold is not None:
            return fc.update_position(est, gyro, self._vision_hold.update(est, dt), dt)
        if mode == CopterMode.GUIDED and self._guided is not None:
            return self._guided_control(est, gyro, dt)
        if self._law is None:
            self._law = _Hold(est.position_enu_m, float(est.heading_rad))
        if fc.landed and self._law_kind() != LawKind.TAKEOFF:
            return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)   # ground idle
        target = self._law.update(est, dt)
        events = self._law.pop_events()
        if mode == CopterMode.AUTO:
            self._auto_events(events, est)
            if self._law is None:
                return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)
        else:
            for ev in events:
                if ev.kind == GuidanceEventKind.PHASE_CHANGED:
                    self._bus_text(MavSeverity.INFO, f"{mode.name}: {ev.detail}")
        if mode == CopterMode.GUIDED and self._guided_heading is not None:
            target = dataclasses.replace(target, heading_rad=self._guided_heading_now(dt))
        self._last_target = target
        return fc.update_position(est, gyro, target, dt)

    def _guided_heading_now(self, dt: float) -> float | None:
        if self._guided_yaw_rate is not None and self._guided_heading is not None:
            if self._now_s <= self._guided_yaw_until_s:
                self._guided_heading = (self._guided_heading + self._guided_yaw_rate * dt) % _TWO_PI
        return self._guided_heading

    def _guided_control(self, est: NavState, gyro: np.ndarray, dt: float) -> ControlOutput:
        g = self._guided
        assert g is not None
        timeout = self.params.get("GUID_TIMEOUT")
        fresh = self._now_s - g.t_s <= timeout
        heading = self._guided_heading_now(dt)
        fc = self.fc
        if g.kind == SetpointKind.POSITION_VELOCITY and g.position_enu_m is not None:
            vel = g.velocity_enu_m_s if g.velocity_enu_m_s is not None else np.zeros(3)
            moved = min(self._now_s - g.t_s, timeout)
            pos = g.position_enu_m + vel * moved
            if fc.landed and pos[2] - float(est.position_enu_m[2]) < 0.5:
                return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)
            target = PositionTarget(tuple(float(a) for a in pos),
                                    tuple(float(a) for a in (vel if fresh else np.zeros(3))),
                                    heading_rad=heading)
            self._last_target = target
            return fc.update_position(est, gyro, target, dt)
        if g.kind == SetpointKind.ACCELERATION and g.accel_enu_m_s2 is not None:
            if g.velocity_enu_m_s is None:
                g.velocity_enu_m_s = np.array(est.velocity_enu_m_s, dtype=float)
            if fresh:
                g.velocity_enu_m_s = np.clip(g.velocity_enu_m_s + g.accel_enu_m_s2 * dt,
                                             -MAX_VELOCITY_TARGET_M_S, MAX_VELOCITY_TARGET_M_S)
            else:
                g.velocity_enu_m_s = np.zeros(3)
        vel = g.velocity_enu_m_s if (g.velocity_enu_m_s is not None and fresh) else np.zeros(3)
        accel = g.accel_enu_m_s2 if (g.accel_enu_m_s2 is not None and fresh) else np.zeros(3)
        if fc.landed and float(vel[2]) <= fc.config.takeoff_min_climb_m_s:
            return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, 0.0, dt)
        return fc.update_velocity(est, gyro, vel, dt, heading_rad=heading,
                                  accel_enu_m_s2=tuple(float(a) for a in accel))

    def _ground_contact(self, out: ControlOutput, est: NavState, dt: float) -> bool:
        """Touchdown in a landing descent without looking at the horizontal speed.

        The controller's land detector also wants a low horizontal speed, which a dead-reckoned
        estimate (GPS-denied, no fixes near the ground) may never show. ArduCopter's land detector
        does not use it either: low thrust demand and no vertical motion for the trigger time.
        """
        c = self.fc.config
        if self.fc.landed or not self._landing():
            self._contact_s = 0.0
            return False
        if (out.thrust_n < c.land_detect_thrust_fraction * self.fc.hover_thrust_n
                and abs(float(est.velocity_enu_m_s[2])) < c.land_detect_max_speed_z_m_s):
            self._contact_s += dt
        else:
            self._contact_s = 0.0
        if self._contact_s < c.land_detect_time_s:
            return False
        self._contact_s = 0.0
        self.fc.set_landed(True)
        self.stats["ground_contact_touchdowns"] += 1
        logger.info("touchdown (thrust and vertical speed; horizontal speed estimate %.1f m/s)",
                    math.hypot(float(est.velocity_enu_m_s[0]), float(est.velocity_enu_m_s[1])))
        return True

    def _on_touchdown(self, est: NavState) -> None:
        self._ground_xy = np.array(est.position_enu_m[:2], dtype=float)
        self._bus_text(MavSeverity.INFO, "touchdown")
        landing_mode = self._mode == CopterMode.LAND or (
            self._mode == CopterMode.RTL and self._law_kind() == LawKind.RTL)
        if self._mode == CopterMode.AUTO and self._auto_stage in (AutoStage.LAND, AutoStage.RTL):
            self._item_reached(self._mission_index)
            self._auto_advance(self._mission_index)
            landing_mode = True
        if landing_mode:
            self._disarm("landed")

    # =========================================================================== modes
    def _position_ok(self) -> bool:
        return (self.nav.aligned and self.nav.position_source != PositionSource.NONE
                and self.nav.position_ok())

    def _enter_mode(self, mode: CopterMode, from_gcs: bool) -> Outcome:
        if mode == self._mode and (from_gcs or mode in (CopterMode.RTL, CopterMode.LAND)):
            return Outcome(True)
        if mode in NEEDS_POSITION and not self._position_ok():
            return self._refuse(f"Mode change to {mode.name} failed: requires position")
        if mode == CopterMode.AUTO:
            if not self._mission:
                return self._refuse("Mode change to AUTO failed: no mission")
            if self._armed and self.fc.landed and not self._mission_starts_with_takeoff():
                return self._refuse("Auto: Missing Takeoff Cmd")
        if self._mode == CopterMode.AUTO and mode != CopterMode.AUTO \
                and self._mission_state == MissionState.ACTIVE:
            self._mission_state = MissionState.PAUSED
        previous = self._mode
        self._mode = mode
        self._tel = None
        self._guided = None
        self._guided_heading = None
        self._guided_yaw_rate = None
        if from_gcs:
            self._vision_hold = None
        if previous != mode:
            self._speed_xy = self._speed_up = self._speed_dn = None
            self._gcfg = self._guidance_config()
        est = self.nav.state() if self.nav.aligned else None
        self._law = None
        if est is not None:
            self._start_mode_law(est)
        self._events.append(ModeChangedEvent(mode))
        self._bus_text(MavSeverity.INFO, f"mode {mode.name}" + ("" if from_gcs else " (failsafe)"))
        return Outcome(True)

    def _start_mode_law(self, est: NavState) -> None:
        mode = self._mode
        stop = stopping_point(est.position_enu_m, est.velocity_enu_m_s, self._gcfg.wp_accel_m_s2)
        heading = float(est.heading_rad)
        if mode in (CopterMode.GUIDED, CopterMode.LOITER):
            self._law = _Hold(stop if not self.fc.landed else est.position_enu_m, heading)
        elif mode == CopterMode.AUTO:
            self._auto_enter(est)
        elif mode == CopterMode.RTL:
            self._law = self._make_rtl(est)
        elif mode == CopterMode.LAND:
            self._law = _Land(self._gcfg, stop, self._home_z(), heading_rad=heading)
        else:
            self._law = None

    def _restart_mode_law(self, est: NavState) -> None:
        """After a vision-failsafe hold: continue the mode from where the vehicle now is."""
        if self._mode == CopterMode.AUTO and self._mission_state == MissionState.ACTIVE:
            self._auto_start(self._mission_index, est)
        elif self._mode == CopterMode.GUIDED and isinstance(self._law, _Tracker):
            dest = self._law.destination
            self._law = self._new_tracker([Waypoint(tuple(dest))], est)
        elif self._mode not in (CopterMode.GUIDED,):
            self._start_mode_law(est)

    def _make_rtl(self, est: NavState) -> _Rtl:
        cfg = self._gcfg
        rtl_speed = self.params.get("RTL_SPEED") / 100.0
        if rtl_speed > 0:
            cfg = dataclasses.replace(cfg, wp_speed_m_s=rtl_speed)
        if self.params.get_int("WP_YAW_BEHAVIOR") in (0, 2):
            cfg = dataclasses.replace(cfg, yaw_behaviour=YawBehaviour.NEVER_CHANGE)
        home = self._home if self._home is not None else est.position_enu_m
        return _Rtl(cfg, home, est, self.params.get("RTL_ALT_FINAL") / 100.0,
                    heading_rad=float(est.heading_rad))

    def _home_z(self) -> float:
        return float(self._home[2]) if self._home is not None else self.cfg.ground_z_m

    def _new_tracker(self, waypoints: Sequence[Waypoint], est: NavState,
                     start=None) -> _Tracker:
        if start is None:
            start = stopping_point(est.position_enu_m, est.velocity_enu_m_s,
                                   self._gcfg.wp_accel_m_s2)
        return _Tracker(self._gcfg, waypoints, start)

    # =========================================================================== AUTO
    def _mission_starts_with_takeoff(self) -> bool:
        for item in self._mission:
            if item.command in NAV_COMMANDS:
                return item.command == MissionCommand.NAV_TAKEOFF
        return False

    def _auto_enter(self, est: NavState) -> None:
        if self._mission_state in (MissionState.PAUSED, MissionState.ACTIVE):
            index = self._mission_index
        else:
            index = 0
        self._mission_state = MissionState.ACTIVE
        self._speed_xy = None
        self._auto_start(index, est)

    def _auto_start(self, index: int, est: NavState) -> None:
        """Start the first NAV command at or after ``index`` (running the DO commands that follow it)."""
        items = self._mission
        nav_index = index
        while nav_index < len(items) and items[nav_index].command not in NAV_COMMANDS:
            self._run_do_command(items[nav_index])
            nav_index += 1
        if nav_index >= len(items):
            self._mission_complete(est)
            return
        self._mission_index = nav_index
        self._mission_state = MissionState.ACTIVE
        self._tel = None
        item = items[nav_index]
        self._run_do_commands_after(nav_index)
        prev = self._last_target_position(est)
        heading = float(est.heading_rad)
        self._bus_text(MavSeverity.INFO, f"mission: item {nav_index + 1} "
                                         f"{MissionCommand(item.command).name}")
        if item.command == MissionCommand.NAV_TAKEOFF:
            goal_z = self._item_z(item, prev)
            here = np.array(est.position_enu_m, dtype=float)
            if not self.fc.landed and here[2] >= goal_z - TAKEOFF_DONE_TOLERANCE_M:
                self._auto_stage = AutoStage.TAKEOFF
                self._law = _Hold(here, heading)
                self._item_reached(nav_index)
                self._auto_advance(nav_index)
                return
            start = here if self.fc.landed else np.array(self._last_target_position(est))
            climb = max(goal_z - float(start[2]), 1.0)
            self._law = make_takeoff(self._gcfg, start, climb)
            self._law.kind = LawKind.TAKEOFF
            self._auto_stage = AutoStage.TAKEOFF
        elif item.command == MissionCommand.NAV_WAYPOINT:
            self._auto_waypoints(nav_index, est, prev)
        elif item.command == MissionCommand.NAV_LAND:
            if item.lat_e7 == 0 and item.lon_e7 == 0:
                self._auto_land_xy = None
                stop = stopping_point(est.position_enu_m, est.velocity_enu_m_s,
                                      self._gcfg.wp_accel_m_s2)
                self._law = _Land(self._gcfg, stop, self._home_z(), heading_rad=heading)
                self._auto_stage = AutoStage.LAND
            else:
                x, y = self.geo.to_enu(item.lat_deg, item.lon_deg)
                self._auto_land_xy = (x, y)
                z = float(self._last_target_position(est)[2])
                self._law = self._new_tracker([Waypoint((x, y, z))], est,
                                              start=self._last_target_position(est))
                self._auto_stage = AutoStage.LAND_APPROACH
        elif item.command == MissionCommand.NAV_RETURN_TO_LAUNCH:
            self._law = self._make_rtl(est)
            self._auto_stage = AutoStage.RTL

    def _auto_waypoints(self, first: int, est: NavState, prev: np.ndarray) -> None:
        """Fly a run of consecutive NAV_WAYPOINTs with one tracker (corners without stopping)."""
        items = self._mission
        group: list[int] = []
        speeds: list[float | None] = []
        positions: list[tuple[float, float, float]] = []
        speed = self._speed_xy
        i = first
        last_pos = prev
        while i < len(items):
            item = items[i]
            if item.command != MissionCommand.NAV_WAYPOINT:
                if item.command in NAV_COMMANDS:
                    break
                i += 1
                continue
            if group:
                speed = self._speed_after(i, speed)
            else:
                speed = self._speed_xy
            pos = self._item_position(item, last_pos)
            group.append(i)
            speeds.append(speed)
            positions.append(pos)
            last_pos = np.array(pos)
            if item.param1 > 0.0:
                break
            i += 1
        start = self._last_target_position(est) if not self.fc.landed else est.position_enu_m
        wps = [Waypoint(p, speed_m_s=s) for p, s in zip(positions, speeds)]
        self._law = _Tracker(self._gcfg, wps, start)
        self._auto_group = group
        self._auto_group_speeds = speeds
        self._auto_stage = AutoStage.WAYPOINTS

    def _speed_after(self, index: int, speed: float | None) -> float | None:
        """The horizontal speed after the DO_CHANGE_SPEED commands that follow nav item ``index``."""
        for item in self._mission[index + 1:]:
            if item.command in NAV_COMMANDS:
                break
            if item.command == MissionCommand.DO_CHANGE_SPEED and item.param1 in (
                    SpeedType.AIRSPEED, SpeedType.GROUNDSPEED) and item.param2 > 0:
                speed = self._speed_limit(SpeedType.GROUNDSPEED, float(item.param2))
        return speed

    def _run_do_commands_after(self, nav_index: int) -> None:
        for item in self._mission[nav_index + 1:]:
            if item.command in NAV_COMMANDS:
                break
            self._run_do_command(item)

    def _run_do_command(self, item: MissionItem) -> None:
        if item.command == MissionCommand.DO_CHANGE_SPEED and item.param2 > 0:
            try:
                kind = SpeedType(int(item.param1))
            except ValueError:
                kind = SpeedType.GROUNDSPEED
            self._apply_speed(kind, self._speed_limit(kind, float(item.param2)))

    def _speed_limit(self, kind: SpeedType, speed_m_s: float) -> float:
        """A DO_CHANGE_SPEED speed capped at the range of the parameter it overrides (a mission item
        may carry any finite value)."""
        name = {SpeedType.CLIMB_SPEED: "WPNAV_SPEED_UP",
                SpeedType.DESCENT_SPEED: "WPNAV_SPEED_DN"}.get(kind, "WPNAV_SPEED")
        return min(speed_m_s, self.params.spec(name).max_value / 100.0)

    def _auto_events(self, events: list, est: NavState) -> None:
        stage = self._auto_stage
        for ev in events:
            if stage == AutoStage.WAYPOINTS and ev.kind == GuidanceEventKind.WAYPOINT_REACHED:
                if 0 <= ev.index < len(self._auto_group):
                    index = self._auto_group[ev.index]
                    self._item_reached(index)
                    if ev.index + 1 < len(self._auto_group):
                        self._mission_index = self._auto_group[ev.index + 1]
                        self._speed_xy = self._auto_group_speeds[ev.index + 1]
                        self._tel = None
            elif ev.kind == GuidanceEventKind.MISSION_COMPLETE:
                if stage == AutoStage.TAKEOFF:
                    self._item_reached(self._mission_index)
                    self._auto_advance(self._mission_index)
                elif stage == AutoStage.WAYPOINTS:
                    last = self._auto_group[-1] if self._auto_group else self._mission_index
                    self._mission_index = last
                    hold_s = self._mission[last].param1 if last < len(self._mission) else 0.0
                    if hold_s > 0.0:
                        self._auto_stage = AutoStage.WP_DELAY
                        self._auto_delay_until_s = self._now_s + hold_s
                        self._law = _Hold(self._law.destination, None)
                    else:
                        self._auto_advance(last)
                elif stage == AutoStage.LAND_APPROACH and self._auto_land_xy is not None:
                    x, y = self._auto_land_xy
                    self._law = _Land(self._gcfg, (x, y, float(est.position_enu_m[2])),
                                      self._home_z(), heading_rad=None)
                    self._auto_stage = AutoStage.LAND
            elif ev.kind == GuidanceEventKind.PHASE_CHANGED:
                self._bus_text(MavSeverity.INFO, f"AUTO RTL: {ev.detail}")
            stage = self._auto_stage
        if self._auto_stage == AutoStage.WP_DELAY and self._now_s >= self._auto_delay_until_s:
            self._auto_advance(self._mission_index)

    def _auto_advance(self, index: int) -> None:
        est = self.nav.state()
        if index + 1 >= len(self._mission):
            self._mission_complete(est)
            return
        self._auto_start(index + 1, est)

    def _item_reached(self, index: int) -> None:
        seq = index + 1
        self._events.append(MissionItemReachedEvent(seq))
        self._announce(MavSeverity.INFO, f"Reached command #{seq}")

    def _mission_complete(self, est: NavState) -> None:
        if self._mission_state != MissionState.COMPLETE:
            self._announce(MavSeverity.INFO, "Mission complete")
        self._mission_state = MissionState.COMPLETE
        self._auto_stage = AutoStage.COMPLETE
        self._tel = None
        if self.fc.landed or not self._armed:
            self._law = None
        else:
            self._law = _Hold(self._last_target_position(est), None)

    def _last_target_position(self, est: NavState) -> np.ndarray:
        if self._last_target is not None and not self.fc.landed:
            return np.array(self._last_target.position_enu_m, dtype=float)
        return np.array(est.position_enu_m, dtype=float)

    def _item_z(self, item: MissionItem, default: np.ndarray) -> float:
        if item.alt_m == 0.0:
            return float(default[2])
        if item.alt_frame == AltFrame.AMSL:
            return float(item.alt_m) - self.geo.origin_alt_amsl_m
        return self._home_z() + float(item.alt_m)

    def _item_position(self, item: MissionItem, default: np.ndarray) -> tuple[float, float, float]:
        if item.lat_e7 == 0 and item.lon_e7 == 0:
            x, y = float(default[0]), float(default[1])
        else:
            x, y = self.geo.to_enu(item.lat_deg, item.lon_deg)
        return (float(x), float(y), self._item_z(item, default))

    # =========================================================================== helpers
    def _announce(self, severity: MavSeverity, text: str) -> None:
        """A STATUSTEXT for the ground stations and an Event on the bus."""
        self._events.append(StatusTextEvent(severity, text))
        self._texts.append((severity, text))

    def _bus_text(self, severity: MavSeverity, text: str) -> None:
        self._texts.append((severity, text))

    def _refuse(self, reason: str) -> Outcome:
        """A refused request: the server sends ``reason`` as STATUSTEXT; the bus gets an Event."""
        self._texts.append((MavSeverity.WARNING, reason))
        return Outcome(False, reason)

    def _source_param(self) -> PositionSource:
        try:
            return PositionSource(self.params.get_int("EK3_SRC1_POSXY"))
        except ValueError:
            return PositionSource.NONE

    def _source_name(self) -> str:
        return {PositionSource.GPS: "GPS", PositionSource.EXTNAV: "external nav data"}.get(
            self.nav.position_source, "no position source")

    def _control_config(self) -> ControlConfig:
        p = self.params
        up = max(p.get("WPNAV_SPEED_UP"), p.get("PILOT_SPEED_UP")) / 100.0
        dn_pilot = p.get("PILOT_SPEED_DN") or p.get("PILOT_SPEED_UP")
        dn = max(p.get("WPNAV_SPEED_DN"), dn_pilot, p.get("LAND_SPEED"),
                 p.get("LAND_SPEED_HIGH")) / 100.0
        return dataclasses.replace(self._algo.control, max_lean_angle_deg=p.get("ANGLE_MAX") / 100.0,
                                   max_climb_m_s=up, max_descent_m_s=dn)

    def _guidance_config(self) -> GuidanceConfig:
        p = self.params
        yaw = YawBehaviour.NEVER_CHANGE if p.get_int("WP_YAW_BEHAVIOR") == 0 \
            else YawBehaviour.FACE_NEXT_WAYPOINT
        up = self._speed_up if self._speed_up is not None else p.get("WPNAV_SPEED_UP") / 100.0
        dn = self._speed_dn if self._speed_dn is not None else p.get("WPNAV_SPEED_DN") / 100.0
        return dataclasses.replace(
            self._algo.guidance,
            wp_speed_m_s=p.get("WPNAV_SPEED") / 100.0, wp_speed_up_m_s=up, wp_speed_down_m_s=dn,
            wp_accel_m_s2=p.get("WPNAV_ACCEL") / 100.0, wp_radius_m=p.get("WPNAV_RADIUS") / 100.0,
            yaw_behaviour=yaw, takeoff_speed_m_s=up, rtl_alt_m=p.get("RTL_ALT") / 100.0,
            rtl_loiter_s=p.get("RTL_LOIT_TIME") / 1000.0, land_speed_m_s=p.get("LAND_SPEED") / 100.0,
            land_speed_high_m_s=p.get("LAND_SPEED_HIGH") / 100.0)

    def _apply_speed(self, kind: SpeedType, speed_m_s: float) -> None:
        if kind in (SpeedType.AIRSPEED, SpeedType.GROUNDSPEED):
            self._speed_xy = speed_m_s
            if isinstance(self._law, _Tracker):
                self._law.set_speed(speed_m_s)
        elif kind == SpeedType.CLIMB_SPEED:
            self._speed_up = speed_m_s
        else:
            self._speed_dn = speed_m_s
        self._gcfg = self._guidance_config()
        if isinstance(self._law, _Tracker):
            self._law.retune(self._gcfg)
        self._bus_text(MavSeverity.INFO, f"speed {kind.name.lower()} {speed_m_s:.1f} m/s")

    def _on_param(self, name: str, value: float) -> None:
        """Parameter observer (the store calls it after every change, from any caller)."""
        try:
            self._apply_param(name, value)
        except (ValueError, ArithmeticError) as exc:
            logger.warning("parameter %s = %g not applied: %s", name, value, exc)

    def _apply_param(self, name: str, value: float) -> None:
        self._tel = None
        if name == "EK3_SRC1_POSXY":
            self.nav.set_position_source(self._source_param())
            self._announce(MavSeverity.INFO, f"EKF3 IMU0 is using {self._source_name()}")
        if name in ("ANGLE_MAX", "PILOT_SPEED_UP", "PILOT_SPEED_DN", "WPNAV_SPEED_UP",
                    "WPNAV_SPEED_DN", "LAND_SPEED", "LAND_SPEED_HIGH"):
            self._rebuild_controller()
        if name in AIRFRAME_PARAM_NAMES:
            self.airframe = Airframe.from_params(self.params)
            self.mixer = QuadXMixer(self.airframe)
            self._rebuild_controller()
        if name.startswith(("WPNAV_", "RTL_", "LAND_", "WP_YAW", "PILOT_")):
            self._gcfg = self._guidance_config()
            if isinstance(self._law, _Tracker):
                self._law.retune(self._gcfg)

    def _rebuild_controller(self) -> None:
        """A new controller for changed limits or a changed airframe model (integrators restart)."""
        landed = self.fc.landed
        self.fc = FlightController(self._control_config(), self.airframe)
        if self.nav.aligned:
            self.fc.reset(self.nav.state(), landed=landed)
        else:
            self.fc.set_landed(landed)

    def _disarm(self, why: str) -> None:
        if not self._armed:
            return
        self._armed = False
        self._tel = None
        self._motors = np.zeros(4)
        self._vision_hold = None
        self.failsafe.reset()
        self._landed_since_s = None
        if self.nav.aligned:
            est = self.nav.state()
            self._ground_xy = np.array(est.position_enu_m[:2], dtype=float)
            self.fc.reset(est, landed=True)
        self._bus_text(MavSeverity.INFO, f"disarmed ({why})")

    def _prearm_failures(self) -> list[str]:
        if not self.nav.aligned or not self.nav.is_healthy():
            return ["PreArm: EKF not ready"]
        out = []
        if self._mode not in ARMABLE_MODES:
            out.append("Arm: Mode not armable")
        if self._mode in NEEDS_POSITION:
            source = self.nav.position_source
            if source == PositionSource.NONE:
                out.append("PreArm: no position source")
            elif source == PositionSource.GPS and not self._gps_fix_fresh():
                out.append("PreArm: Need 3D Fix")
            elif source == PositionSource.EXTNAV and not self._ext_nav_available():
                out.append("PreArm: no position source")
            elif not self.nav.position_ok():
                out.append("PreArm: Need Position Estimate")
        return out

    def _gps_fix_fresh(self) -> bool:
        g = self._last_gps
        return (g is not None and g.fix_type >= GpsFixType.FIX_3D
                and self._now_s - g.t_s <= GPS_FRESH_S)

    def _ext_nav_available(self) -> bool:
        mavlink = (self._last_ext_nav_s is not None
                   and self._now_s - self._last_ext_nav_s <= self.cfg.ext_nav_fresh_s)
        return self._vision_available or mavlink

    # =========================================================================== Vehicle
    def drain_events(self) -> list[VehicleEvent]:
        events, self._events = self._events, []
        return events

    def arm(self, force: bool) -> Outcome:
        if self._armed:
            return Outcome(True)
        if not self.nav.aligned:
            return self._refuse("PreArm: EKF not ready")
        if not force and self.params.get_int("ARMING_CHECK") != 0:
            failures = self._prearm_failures()
            if failures:
                for text in failures[1:]:
                    self._texts.append((MavSeverity.CRITICAL, text))
                return self._refuse(failures[0])
        est = self.nav.state()
        self._armed = True
        self._tel = None
        self.fc.reset(est, landed=True)
        self._landed_since_s = self._now_s
        self._home = np.array([float(est.position_enu_m[0]), float(est.position_enu_m[1]),
                               self._home_z()])
        self._events.append(HomeChangedEvent())
        if self._mode in POSITION_MODES:
            self._law = None
            self._start_mode_law(est)
        self._bus_text(MavSeverity.INFO, f"armed in {self._mode.name}" + (" (forced)" if force else ""))
        return Outcome(True)

    def disarm(self, force: bool) -> Outcome:
        if not self._armed:
            return Outcome(True)
        if not force and not self.fc.landed:
            return self._refuse("Disarm: vehicle is flying")
        self._disarm("forced" if force else "command")
        return Outcome(True)

    def set_mode(self, mode: CopterMode) -> Outcome:
        return self._enter_mode(mode, from_gcs=True)

    def takeoff(self, alt_m: float) -> Outcome:
        if self._mode != CopterMode.GUIDED:
            return self._refuse("Takeoff: mode must be GUIDED")
        if not self._armed:
            return self._refuse("Takeoff: motors not armed")
        if not self.fc.landed:
            return self._refuse("Takeoff: already flying")
        if not (math.isfinite(alt_m) and alt_m > 0):
            return self._refuse("Takeoff: bad altitude")
        est = self.nav.state()
        start = np.array(est.position_enu_m, dtype=float)
        climb = max(self._home_z() + float(alt_m) - float(start[2]), 1.0)
        law = make_takeoff(self._gcfg, start, climb)
        law.kind = LawKind.TAKEOFF
        self._law = law
        self._guided = None
        self._landed_since_s = None
        self._tel = None
        self._bus_text(MavSeverity.INFO, f"takeoff to {alt_m:.1f} m")
        return Outcome(True)

    def land(self) -> Outcome:
        return self._enter_mode(CopterMode.LAND, from_gcs=True)

    def return_to_launch(self) -> Outcome:
        return self._enter_mode(CopterMode.RTL, from_gcs=True)

    def start_mission(self, first_seq: int, last_seq: int) -> Outcome:
        if not self._mission:
            return self._refuse("Mission start failed: no mission")
        if self._mission_state == MissionState.COMPLETE:
            self._mission_state = MissionState.NOT_STARTED
        if self._mode == CopterMode.AUTO:
            if self.nav.aligned and self._mission_state != MissionState.ACTIVE:
                self._auto_enter(self.nav.state())
            return Outcome(True)
        return self._enter_mode(CopterMode.AUTO, from_gcs=True)

    def set_current_mission_item(self, seq: int) -> Outcome:
        index = int(seq) - 1
        if not 0 <= index < len(self._mission):
            return self._refuse(f"Mission: no item {seq}")
        self._mission_index = index
        self._tel = None
        if self._mode == CopterMode.AUTO and self._armed and self.nav.aligned \
                and self._mission_state == MissionState.ACTIVE:
            self._auto_start(index, self.nav.state())
        elif self._mission_state == MissionState.COMPLETE:
            self._mission_state = MissionState.PAUSED
        return Outcome(True)

    def reposition(self, lat_deg: float, lon_deg: float, alt_m: float, alt_frame: AltFrame,
                   speed_m_s: float | None, yaw_deg: float | None) -> Outcome:
        if self._mode != CopterMode.GUIDED:
            return self._refuse("Reposition: mode must be GUIDED")
        if not self._position_ok():
            return self._refuse("Reposition: no position estimate")
        x, y = self.geo.to_enu(lat_deg, lon_deg)
        z = self._alt_to_z(alt_m, alt_frame)
        if yaw_deg is not None:
            self._guided_heading = math.radians(yaw_deg) % _TWO_PI
            self._guided_yaw_rate = None
        self._guided_goto((x, y, z), speed_m_s)
        return Outcome(True)

    def change_speed(self, speed_type: SpeedType, speed_m_s: float) -> Outcome:
        if not (math.isfinite(speed_m_s) and speed_m_s > 0):
            return self._refuse("Change speed: bad speed")
        kind = SpeedType(speed_type)
        self._apply_speed(kind, self._speed_limit(kind, float(speed_m_s)))
        return Outcome(True)

    def set_position_target_local_ned(self, target: LocalPositionTarget) -> None:
        if not self.nav.aligned:
            return
        est = self.nav.state()
        heading = float(est.heading_rad)
        body = target.frame in (MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED)

        def rotate(v) -> np.ndarray:
            n, e = float(v[0]), float(v[1])
            if body:
                n, e = n * math.cos(heading) - e * math.sin(heading), \
                    n * math.sin(heading) + e * math.cos(heading)
            return ned_to_enu((n, e, float(v[2])))

        pos = vel = acc = None
        if target.kind in (SetpointKind.POSITION, SetpointKind.POSITION_VELOCITY):
            if target.frame == MavFrame.LOCAL_NED:
                pos = self._origin_enu() + ned_to_enu(target.position_m)
            else:
                pos = np.array(est.position_enu_m, dtype=float) + rotate(target.position_m)
        if target.kind in (SetpointKind.POSITION_VELOCITY, SetpointKind.VELOCITY) or \
                (target.kind == SetpointKind.ACCELERATION and all_finite(*target.velocity_m_s)):
            if all_finite(*target.velocity_m_s):
                vel = rotate(target.velocity_m_s)
        if all_finite(*target.acceleration_m_s2):
            acc = rotate(target.acceleration_m_s2)
        yaw = target.yaw_rad
        if yaw is not None and body:
            yaw = heading + yaw
        self._guided_setpoint(target.kind, pos, vel, acc, yaw, target.yaw_rate_rad_s)

    def set_position_target_global_int(self, target: GlobalPositionTarget) -> None:
        if not self.nav.aligned:
            return
        pos = vel = acc = None
        if target.kind in (SetpointKind.POSITION, SetpointKind.POSITION_VELOCITY):
            x, y = self.geo.to_enu(target.lat_deg, target.lon_deg)
            pos = np.array([x, y, self._alt_to_z(target.alt_m, target.alt_frame)])
        if all_finite(*target.velocity_m_s):
            vel = ned_to_enu(target.velocity_m_s)
        if all_finite(*target.acceleration_m_s2):
            acc = ned_to_enu(target.acceleration_m_s2)
        self._guided_setpoint(target.kind, pos, vel, acc, target.yaw_rad, target.yaw_rate_rad_s)

    def _alt_to_z(self, alt_m: float, alt_frame: AltFrame) -> float:
        if alt_frame == AltFrame.AMSL:
            return float(alt_m) - self.geo.origin_alt_amsl_m
        return self._home_z() + float(alt_m)

    def _origin_enu(self) -> np.ndarray:
        return self._origin.copy() if self._origin is not None else np.zeros(3)

    def _guided_setpoint(self, kind: SetpointKind, pos, vel, acc, yaw, yaw_rate) -> None:
        self._tel = None
        if yaw is not None and math.isfinite(yaw):
            self._guided_heading = float(yaw) % _TWO_PI
            self._guided_yaw_rate = None
        elif yaw_rate is not None and math.isfinite(yaw_rate):
            if self._guided_heading is None:
                self._guided_heading = float(self.nav.state().heading_rad)
            self._guided_yaw_rate = float(yaw_rate)
            self._guided_yaw_until_s = self._now_s + self.params.get("GUID_TIMEOUT")
        if kind == SetpointKind.POSITION and pos is not None:
            self._guided = None
            self._guided_goto(tuple(float(a) for a in pos), None)
            return
        if kind in (SetpointKind.POSITION_VELOCITY, SetpointKind.VELOCITY,
                    SetpointKind.ACCELERATION):
            if vel is not None:
                vel = np.clip(vel, -MAX_VELOCITY_TARGET_M_S, MAX_VELOCITY_TARGET_M_S)
            keep_vel = (kind == SetpointKind.ACCELERATION and vel is None
                        and self._guided is not None and self._guided.velocity_enu_m_s is not None)
            if keep_vel:
                vel = self._guided.velocity_enu_m_s
            self._guided = _GuidedCommand(kind, pos, vel, acc, self._now_s)
            self.stats[f"guided_{kind.name.lower()}"] += 1

    def _guided_goto(self, dest: tuple[float, float, float], speed_m_s: float | None) -> None:
        est = self.nav.state()
        self._guided = None
        wp = Waypoint(dest, speed_m_s=speed_m_s if speed_m_s is not None else self._speed_xy)
        law = self._law
        if isinstance(law, _Tracker) and law.kind == LawKind.TRACK and not self.fc.landed:
            if float(np.linalg.norm(law.destination - np.array(dest))) < SAME_TARGET_M \
                    and not law.complete:
                return
            law.redirect([wp])
        elif self._law_kind() == LawKind.TAKEOFF and self.fc.landed:
            return
        else:
            start = self._last_target_position(est) if not self.fc.landed else est.position_enu_m
            self._law = _Tracker(self._gcfg, [wp], start)
        self.stats["guided_position"] += 1

    def vision_position_estimate(self, usec: int, x_ned_m: float, y_ned_m: float,
                                 z_ned_m: float, roll_rad: float, pitch_rad: float,
                                 yaw_rad: float, covariance: tuple[float, ...],
                                 reset_counter: int) -> None:
        self._ext_nav((x_ned_m, y_ned_m, z_ned_m), covariance)

    def odometry(self, odom: Odometry) -> None:
        self._ext_nav(odom.position_m, odom.pose_covariance)

    def _ext_nav(self, pos_ned, cov21) -> None:
        """MAVLink external navigation: NED metres from the EKF origin, 21-element covariance."""
        if not self.nav.aligned:
            return
        enu = self._origin_enu() + ned_to_enu(pos_ned)
        cov = None
        if len(cov21) >= 7 and all_finite(cov21[0], cov21[1], cov21[6]) and cov21[0] > 0 and cov21[6] > 0:
            # upper triangle of the 6x6 (x, y, z, roll, pitch, yaw): [0] xx, [1] xy, [6] yy (NED)
            cov = np.array([[cov21[6], cov21[1]], [cov21[1], cov21[0]]])   # ENU: swap x/y
        if cov is None:
            cov = np.eye(2) * self.cfg.ext_nav_std_m ** 2
        self._last_ext_nav_s = self._now_s
        self.stats["ext_nav_mavlink"] += 1
        self._vision.append(_VisionReading(self._now_s, (float(enu[0]), float(enu[1])), cov,
                                           "mavlink"))

    def param_changed(self, name: str, value: float) -> None:
        # The store's observer (_on_param) has already applied it; nothing more to do here.
        logger.debug("param_changed %s = %g", name, value)

    def mission_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        self._mission = tuple(items)
        self._tel = None
        running = self._mode == CopterMode.AUTO and self._mission_state == MissionState.ACTIVE
        if not items:
            self._mission_index = 0
            self._mission_state = MissionState.NO_MISSION
            if running and self.nav.aligned:
                self._mission_complete(self.nav.state())
                self._mission_state = MissionState.NO_MISSION
            return Outcome(True)
        self._mission_index = min(self._mission_index, len(items) - 1)
        if running and self.nav.aligned and self._armed:
            self._announce(MavSeverity.CRITICAL, "Auto mission changed, restarted command")
            self._auto_start(self._mission_index, self.nav.state())
        else:
            self._mission_index = 0
            self._mission_state = MissionState.NOT_STARTED
            self._auto_stage = AutoStage.IDLE
        return Outcome(True)

    # =========================================================================== telemetry
    def telemetry(self) -> VehicleTelemetry:
        if self._tel is None:
            self._tel = self._build_telemetry()
        return self._tel

    def _build_telemetry(self) -> VehicleTelemetry:
        aligned = self.nav.aligned
        if aligned:
            est = self.nav.state()
            pos = np.asarray(est.position_enu_m, dtype=float)
            vel = np.asarray(est.velocity_enu_m_s, dtype=float)
            roll, pitch, heading = aviation_euler_from_quat(tuple(float(a) for a in est.q_wxyz))
            w = self._gyro - np.asarray(est.gyro_bias, dtype=float)
            std = np.asarray(est.position_std_m, dtype=float)
            vstd = np.asarray(est.velocity_std_m_s, dtype=float)
        else:
            pos = np.array([*self.cfg.start_enu_m, self.cfg.ground_z_m], dtype=float)
            vel = np.zeros(3)
            roll = pitch = heading = 0.0
            w = np.zeros(3)
            std = np.full(3, math.inf)
            vstd = np.full(3, math.inf)
        lat, lon = self.geo.to_geodetic(float(pos[0]), float(pos[1]))
        home = self._home if self._home is not None else pos
        home_lat, home_lon = self.geo.to_geodetic(float(home[0]), float(home[1]))
        origin = self._origin_enu() if self._origin is not None else pos
        thrust = self._last_out.thrust_n if (self._last_out is not None and self._armed) else 0.0
        g = self._last_gps
        gps_fix = GpsFixType(min(max(g.fix_type, 0), GpsFixType.FIX_3D)) if g is not None \
            else GpsFixType.NO_GPS
        sensors = self._sensor_flags(aligned)
        battery = self.battery.state(self.params.get("BATT_CAPACITY"))
        ok = self.nav.config.position_ok_max_std_m
        return VehicleTelemetry(
            time_boot_ms=int(self._now_s * 1000.0), armed=self._armed, mode=self._mode,
            landed_state=self._landed_state(), system_status=self._system_status(),
            lat_deg=lat, lon_deg=lon, alt_amsl_m=self.geo.origin_alt_amsl_m + float(pos[2]),
            relative_alt_m=float(pos[2] - home[2]),
            position_ned_m=enu_to_ned(pos - origin), velocity_ned_m_s=enu_to_ned(vel),
            attitude_rpy_rad=(roll, pitch, wrap_pi(heading)),
            body_rates_rad_s=(float(w[0]), -float(w[1]), -float(w[2])),
            heading_deg=math.degrees(heading) % 360.0,
            groundspeed_m_s=float(math.hypot(vel[0], vel[1])),
            airspeed_m_s=float(math.hypot(vel[0], vel[1])), climb_m_s=float(vel[2]),
            throttle_pct=100.0 * thrust / self.airframe.max_thrust_n,
            gps_fix_type=gps_fix, gps_satellites=g.satellites if g is not None else 0,
            gps_hdop=g.eph_m if g is not None else math.nan,
            gps_vdop=g.epv_m if g is not None else math.nan,
            gps_lat_deg=g.lat_deg if g is not None else 0.0,
            gps_lon_deg=g.lon_deg if g is not None else 0.0,
            gps_alt_amsl_m=(self.geo.origin_alt_amsl_m + g.alt_m) if g is not None else 0.0,
            gps_ground_speed_m_s=float(math.hypot(*g.velocity_enu_m_s[:2])) if g is not None else math.nan,
            gps_course_deg=(math.degrees(math.atan2(g.velocity_enu_m_s[0], g.velocity_enu_m_s[1])) % 360.0)
            if g is not None else math.nan,
            battery_voltage_v=battery.voltage_v, battery_current_a=battery.current_a,
            battery_remaining_pct=battery.remaining_pct,
            home_set=self._home is not None, home_lat_deg=home_lat, home_lon_deg=home_lon,
            home_alt_amsl_m=self.geo.origin_alt_amsl_m + float(home[2]),
            home_position_ned_m=enu_to_ned(np.asarray(home) - origin),
            mission_current_seq=self._mission_index + 1 if self._mission else 0,
            mission_state=self._mission_state,
            ekf_flags=int(self._ekf_flags(aligned)),
            ekf_velocity_variance=float(max(vstd[0], vstd[1]) / self.nav.config.velocity_ok_max_std_m_s),
            ekf_pos_horiz_variance=float(max(std[0], std[1]) / ok),
            ekf_pos_vert_variance=float(std[2] / ok),
            ekf_compass_variance=float(self.nav.attitude_std_rad()[2] / 0.2) if aligned else 1.0,
            sensors_present=int(sensors[0]), sensors_enabled=int(sensors[1]),
            sensors_health=int(sensors[2]))

    def _landed_state(self) -> LandedState:
        if not self.nav.aligned:
            return LandedState.UNDEFINED
        if self.fc.landed or not self._armed:
            return LandedState.ON_GROUND
        if self._law_kind() == LawKind.TAKEOFF and not self._law.complete:
            return LandedState.TAKEOFF
        if self._landing():
            return LandedState.LANDING
        return LandedState.IN_AIR

    def _system_status(self) -> SystemStatus:
        if not self.nav.aligned:
            return SystemStatus.BOOT
        if self.failsafe.any_active:
            return SystemStatus.CRITICAL
        return SystemStatus.ACTIVE if self._armed and not self.fc.landed else SystemStatus.STANDBY

    def _ekf_flags(self, aligned: bool) -> EkfStatusFlag:
        if not aligned:
            return EkfStatusFlag.UNINITIALIZED
        flags = EkfStatusFlag(0)
        if self.nav.is_healthy():
            flags |= EkfStatusFlag.ATTITUDE | EkfStatusFlag.POS_VERT_ABS | EkfStatusFlag.POS_VERT_AGL
        if self.nav.velocity_ok():
            flags |= EkfStatusFlag.VELOCITY_HORIZ | EkfStatusFlag.VELOCITY_VERT
        if self._position_ok():
            flags |= (EkfStatusFlag.POS_HORIZ_REL | EkfStatusFlag.POS_HORIZ_ABS
                      | EkfStatusFlag.PRED_POS_HORIZ_REL | EkfStatusFlag.PRED_POS_HORIZ_ABS)
        return flags

    def _sensor_flags(self, aligned: bool) -> tuple[SensorFlag, SensorFlag, SensorFlag]:
        present = SensorFlag(int(DEFAULT_SENSORS)) & ~SensorFlag.VISION_POSITION
        if self._last_gps is not None:
            present |= SensorFlag.GPS
        if self.nav.position_source == PositionSource.EXTNAV:
            present |= SensorFlag.VISION_POSITION
        enabled = present
        health = present
        if not (aligned and self.nav.is_healthy()):
            health &= ~SensorFlag.AHRS
        if not self._gps_fix_fresh():
            health &= ~SensorFlag.GPS
        if self.nav.position_source == PositionSource.EXTNAV and not (
                self._ext_nav_available() or (self._last_usable_vision_s is not None
                                              and self._now_s - self._last_usable_vision_s < 2.0)):
            health &= ~SensorFlag.VISION_POSITION
        if not (aligned and not self._prearm_failures()):
            health &= ~SensorFlag.PREARM_CHECK
        return present, enabled, health
