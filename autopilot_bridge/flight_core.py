"""ArduCopter-compatible flight core: the :class:`~autopilot_bridge.vehicle_interface.Vehicle` that the
MAVLink server flies, on the scenenav algorithms (navigation filter, cascaded controller, mixer,
guidance laws), flying the autopilot's own airframe model (``autopilot_bridge.airframe``, from its
parameters; never the simulator's truth).

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

Modes (ArduCopter numbers, ``autopilot_bridge.modes``): STABILIZE, ALT_HOLD, LOITER and POSHOLD
flown by the pilot's RC overrides (``pilot``; without them: level at the hover thrust / hold the
altitude / hold the point), GUIDED (position, position+velocity, velocity and acceleration
targets, DO_REPOSITION, takeoff), AUTO (the mission as AP_Mission sequences it:
``auto_mission``), BRAKE (stop at 7.5 m/s/s, then hold), RTL (climb to the return height of
RTL_ALT / RTL_CLIMB_MIN / RTL_CONE_SLOPE, return, loiter RTL_LOIT_TIME, land or hold at
RTL_ALT_FINAL), LAND, CIRCLE (``circle``) and SMART_RTL (``smart_rtl``); CONDITION_YAW, ROI and
DO_PAUSE_CONTINUE in ``mode_commands``. LAND, RTL and AUTO landings disarm at touchdown; other
modes disarm DISARM_DELAY s after landing.

Position source (EK3_SRC1_POSXY, switchable in flight): 3 GPS, 6 external navigation (scene-matching
fixes from the bus, or VISION_POSITION_ESTIMATE / ODOMETRY over MAVLink), 0 none. Vision fixes are
fused only when valid and accepted by the perception node, younger than ``vision_max_age_s`` and
taken at least SN_VIS_MIN_ALT above home (scene matching needs a large ground footprint). On the
ground without a position source the last landed position is fused as a pseudo-measurement (as
ArduPilot's EKF does when it is not aiding), so the estimate does not drift before take-off.

Where each part lives: this module has the control tick, the modes and the failsafes; the class's
mixins are ``fusion`` (sensor inputs), ``arming``, ``guided``, ``auto_mission``,
``param_binding`` and ``core_telemetry`` (the telemetry model); the guidance laws are in
``flight_laws``; the samples at rest before the EKF starts in ``alignment``; battery reporting in
``battery`` (from the simulator's ``PowerSample``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from autopilot_bridge.airframe import Airframe
from autopilot_bridge.alignment import Alignment
from autopilot_bridge.arming import GPS_FRESH_S, ArmingMixin
from autopilot_bridge.auto_mission import AutoMissionMixin, AutoStage
from autopilot_bridge.battery import BatteryMonitor
from autopilot_bridge.circle import Circle, CircleSettings, centre_ahead
from autopilot_bridge.config import AutopilotAlgorithmsConfig, FlightCoreConfig, PositionSource, YawBehaviour
from autopilot_bridge.control import ControlOutput, FlightController, PositionTarget, stopping_point
from autopilot_bridge.core_geofence import GeofenceMixin
from autopilot_bridge.core_telemetry import TelemetryMixin
from autopilot_bridge.ekf import NavFilter, NavState
from autopilot_bridge.failsafe import (
    FailsafeAction,
    FailsafeEvent,
    FailsafeInputs,
    FailsafeKind,
    FailsafeMonitor,
    FailsafeSettings,
    GcsFailsafeAction,
)
from autopilot_bridge.failsafe_checks import BatteryFailsafe, BatterySettings, EkfCheck, EkfVariances
from autopilot_bridge.flight_laws import Hold, Land, LawKind, Rtl, Tracker
from autopilot_bridge.fusion import ImuReading, SensorFusionMixin
from autopilot_bridge.geo_frame import GeoFrame
from autopilot_bridge.guidance_law import GuidanceEventKind, Waypoint, WaypointTracker
from autopilot_bridge.guided import GuidedMixin
from autopilot_bridge.mixer import QuadXMixer
from autopilot_bridge.mode_commands import ModeCommandsMixin
from autopilot_bridge.modes import NEEDS_POSITION, POSITION_MODES, CopterMode
from autopilot_bridge.motor_test import MotorTestMixin
from autopilot_bridge.param_binding import (
    ParamBindingMixin,
    accel_noise_density,
    compass_bias_model,
    drag_model,
    gyro_bias_noise_density,
)
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.pilot import PilotMixin
from autopilot_bridge.smart_rtl import BreadcrumbPath, smart_rtl_law
from autopilot_bridge.vehicle_interface import (
    HomeChangedEvent,
    MavSeverity,
    MissionItem,
    MissionState,
    ModeChangedEvent,
    Outcome,
    StatusTextEvent,
    VehicleEvent,
    VehicleTelemetry,
)
from autopilot_bridge.vibration import VibrationMonitor

logger = logging.getLogger(__name__)

# BRAKE's horizontal deceleration: ArduCopter's BRAKE_MODE_DECEL_RATE, 750 cm/s/s
# (ArduCopter/config.h, used by ModeBrake::init); the position controller's own limits (ANGLE_MAX)
# may decelerate less.
BRAKE_DECEL_M_S2 = 7.5


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


class FlightCore(SensorFusionMixin, ArmingMixin, GuidedMixin, AutoMissionMixin,
                 ModeCommandsMixin, PilotMixin, ParamBindingMixin, TelemetryMixin, GeofenceMixin,
                 MotorTestMixin):
    """The flight core; see the module docstring. Not thread-safe: call from one thread.

    One class, one concept per module: the control tick, modes and failsafes are here (alignment:
    ``alignment.Alignment``); sensor fusion (``fusion``), arming (``arming``), GUIDED (``guided``), AUTO
    missions (``auto_mission``), parameter binding (``param_binding``) and the telemetry model
    (``core_telemetry``) are its mixins, each working on the state it initialises (``_init_*``).
    """

    def __init__(self, params: ParameterStore, cfg: FlightCoreConfig | None = None,
                 algorithms: AutopilotAlgorithmsConfig | None = None) -> None:
        self.params = params
        # settings objects derived from parameters: name -> (params.generation, settings)
        self._settings_cache: dict[str, tuple[int, object]] = {}
        self.cfg = cfg if cfg is not None else FlightCoreConfig()
        self._algo = algorithms if algorithms is not None else AutopilotAlgorithmsConfig()
        self.airframe = Airframe.from_params(params)
        self.geo = GeoFrame(self.cfg.origin_lat_deg, self.cfg.origin_lon_deg,
                            self.cfg.origin_alt_amsl_m)
        self._source_set = 1            # EK3_SRC<n>_*: SET_EKF_SOURCE_SET (param_binding)
        source = self._source_param()
        self.nav = NavFilter(dataclasses.replace(
            self._algo.ekf, position_source=source,
            gyro_bias_noise_rad_s2_per_rt_hz=gyro_bias_noise_density(params.get("EK3_GBIAS_P_NSE"))))
        self.nav.set_drag_model(**drag_model(params))
        self.nav.set_accel_noise(accel_noise_density(params.get("EK3_ACC_P_NSE")))
        self.nav.set_compass_noise(params.get("EK3_YAW_M_NSE"))
        self.nav.set_compass_bias_model(**compass_bias_model(params))
        self.nav.set_position_gate(params.get("EK3_POS_I_GATE") / 100.0)
        self.nav.set_vision_noise_floor(params.get("VISO_POS_M_NSE"))
        self.nav.set_vision_reset_max(params.get("SN_VIS_RST_MAX"))
        self.fc = FlightController(self._control_config(), self.airframe)
        self.mixer = QuadXMixer(self.airframe)
        self.failsafe = FailsafeMonitor()
        self.ekf_check = EkfCheck()
        self.battery_failsafe = BatteryFailsafe()
        self._init_geofence()
        self.battery = BatteryMonitor()
        self.stats: Counter[str] = Counter()
        self._now_s = 0.0
        self._armed = False
        self._mode = CopterMode.STABILIZE
        self._home: np.ndarray | None = None
        self._home_locked = False       # DO_SET_HOME locks home: arming keeps it (ArduCopter)
        self._origin: np.ndarray | None = None
        self._requested_origin: np.ndarray | None = None   # SET_GPS_GLOBAL_ORIGIN before alignment
        self._ground_xy = np.array(self.cfg.start_enu_m, dtype=float)
        self._ground_next_s = 0.0
        self._landed_since_s: float | None = None
        self._contact_s = 0.0
        self.alignment = Alignment()
        self._init_fusion()
        self._vision_available = False
        self._gcs_heartbeat_s: float | None = None
        # guidance
        self._law: object | None = None
        self._init_guided()
        self._vision_hold: Hold | None = None
        self._speed_xy: float | None = None
        self._speed_up: float | None = None
        self._speed_dn: float | None = None
        self._gcfg = self._guidance_config()
        self._last_target: PositionTarget | None = None
        self._pos_resets = 0
        self._refused_resets = 0
        self._init_auto()
        self._init_mode_commands()
        self._init_pilot()
        self._init_motor_test()
        self.srtl_path = BreadcrumbPath()
        # outputs
        self._motors = np.zeros(4)
        self._last_out: ControlOutput | None = None
        self._gyro = np.zeros(3)
        self._imu_dt_s = 0.0
        self._accel = np.full(3, math.nan)     # last IMU accelerometer sample (FLU), RAW_IMU
        self.vibration = VibrationMonitor()
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
        return self._reported_mode()

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
        return CoreStatus(armed=self._armed, mode=self._reported_mode().name, landed=self.fc.landed,
                          mission_seq=seq, mission_count=len(self._mission),
                          mission_complete=self._mission_state == MissionState.COMPLETE,
                          gps_used=self.gps_used)

    def drain_texts(self) -> list[tuple[MavSeverity, str]]:
        """Everything worth an Event on the bus since the last call (STATUSTEXTs included)."""
        texts, self._texts = self._texts, []
        return texts

    def close(self) -> None:
        self.params.remove_observer(self._on_param)

    def set_gps_global_origin(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Outcome:
        """SET_GPS_GLOBAL_ORIGIN (Vehicle protocol): taken while the EKF has no origin, as ArduPilot's
        ``set_ekf_origin``; the EKF then aligns with its NED frame there (the position still from
        GPS or the known take-off point). Once the origin is set it stays."""
        if self._origin is not None:
            return Outcome(False)
        x, y = self.geo.to_enu(lat_deg, lon_deg)
        self._requested_origin = np.array([x, y, alt_amsl_m - self.geo.origin_alt_amsl_m])
        self._bus_text(MavSeverity.INFO, f"EKF origin requested at ({x:.1f}, {y:.1f}) m")
        return Outcome(True)

    def reboot(self) -> None:
        """PREFLIGHT_REBOOT_SHUTDOWN (Vehicle protocol; disarmed): every state as after power-up
        (modes, EKF, home, failsafes, battery count, SmartRTL path), the parameters as stored. The
        vehicle is where it is: without GPS the new EKF aligns at the last estimate (the known
        take-off point of a first start). Inputs the node sets once stay (vision available)."""
        vision = self._vision_available
        gcs = self._gcs_heartbeat_s
        now = self._now_s
        cfg = self.cfg
        est = self.estimate()
        if est is not None:
            cfg = dataclasses.replace(cfg, start_enu_m=(float(est.position_enu_m[0]),
                                                        float(est.position_enu_m[1])))
        self.close()
        FlightCore.__init__(self, self.params, cfg, self._algo)
        self._vision_available = vision
        self._gcs_heartbeat_s = gcs
        self._now_s = now
        self._bus_text(MavSeverity.INFO, "rebooted")

    # =========================================================================== inputs
    def set_gcs_heartbeat(self, last_heartbeat_s: float | None) -> None:
        """Newest heartbeat time (simulated seconds) of the ground station SYSID_MYGCS."""
        self._gcs_heartbeat_s = last_heartbeat_s

    def set_vision_available(self, available: bool) -> None:
        """Whether a perception node is being followed (a pre-arm check in GPS-denied flight)."""
        self._vision_available = bool(available)

    # =========================================================================== control tick
    def step(self, dt_s: float, imu: ImuReading, now_s: float) -> np.ndarray:
        """One control tick; returns the motor commands (4,) in [0, 1] (zeros when disarmed, the
        test's output while a DO_MOTOR_TEST runs: ``motor_test``)."""
        motors = self._step(dt_s, imu, now_s)
        if self.motor_test_state.running and not self._armed:
            self._motors = self._motor_test_output()
            return self._motors.copy()
        return motors

    def _step(self, dt_s: float, imu: ImuReading, now_s: float) -> np.ndarray:
        self._now_s = float(now_s)
        self._tel = None
        accel = np.asarray(imu.accel_flu_m_s2, dtype=float)
        gyro = np.asarray(imu.gyro_flu_rad_s, dtype=float)
        isfinite = math.isfinite
        if accel.shape != (3,) or gyro.shape != (3,) or not (
                all(map(isfinite, accel.tolist())) and all(map(isfinite, gyro.tolist()))
                and isfinite(dt_s) and 0.0 < dt_s < 1.0):
            self.stats["imu_bad"] += 1
            return self._motors.copy()
        self._gyro = gyro
        self._accel = accel
        self._imu_dt_s = float(dt_s)
        self._record_gyro(self._now_s, gyro)
        self.vibration.add(accel, dt_s)
        if not self.nav.aligned:
            self.alignment.add_imu(self._now_s, accel, gyro)
            self._try_align()
            return self._motors.copy()
        self.nav.predict(accel, gyro, dt_s)
        self._fuse_pending()
        est = self.nav.state()
        if self.nav.position_reset_count != self._pos_resets:
            self._pos_resets = self.nav.position_reset_count
            self._handle_position_reset(self.nav.last_position_reset_m)
        if self.nav.refused_reset_count != self._refused_resets:
            self._refused_resets = self.nav.refused_reset_count
            self._handle_refused_reset(self.nav.last_refused_reset_m)
        self._run_failsafes(est)
        self._auto_disarm_check()
        self._record_path(est)
        self._radio_failsafe_check()
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

    # --------------------------------------------------------------------------- failsafes
    def _try_align(self) -> None:
        """Initialise the EKF once the samples at rest suffice; home and the EKF origin go there."""
        gps_source = self.nav.position_source == PositionSource.GPS
        r = self.alignment.result(self._now_s, self.cfg.align_time_s, self.cfg.gps_wait_s, gps_source)
        if r is None:
            return
        if r.gps_xy_enu_m is not None:
            xy, how = r.gps_xy_enu_m, "GPS"
        else:
            xy, how = self.cfg.start_enu_m, "the known take-off point"
        pos = (float(xy[0]), float(xy[1]), self.cfg.ground_z_m)
        try:
            self.nav.initialise(r.accel_flu_m_s2, r.heading_rad, r.baro_alt_m,
                                gyro_flu_rad_s=r.gyro_flu_rad_s, position_enu_m=pos)
        except ValueError as exc:
            logger.warning("EKF alignment failed (%s); retrying", exc)
            self.alignment.reset()
            return
        self._origin = np.array(pos) if self._requested_origin is None else self._requested_origin
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

    def _landing(self) -> bool:
        if self._mode == CopterMode.LAND:
            return True
        if self._mode == CopterMode.RTL and isinstance(self._law, Rtl):
            return self._law.landing
        if self._mode == CopterMode.AUTO:
            if self._auto_stage == AutoStage.LAND:
                return True
            if self._auto_stage == AutoStage.RTL and isinstance(self._law, Rtl):
                return self._law.landing
        return False

    def _run_failsafes(self, est: NavState) -> None:
        p = self.params
        settings = self._failsafe_settings()
        home_z = self._home[2] if self._home is not None else 0.0
        inputs = FailsafeInputs(
            now_s=self._now_s, armed=self._armed, flying=self._armed and not self.fc.landed,
            position_mode=self._mode in POSITION_MODES, landing=self._landing(),
            gcs_last_heartbeat_s=self._gcs_heartbeat_s,
            vision_required=self.nav.position_source == PositionSource.EXTNAV,
            vision_height_ok=float(est.position_enu_m[2]) - home_z >= p.get("SN_VIS_MIN_ALT"),
            last_vision_fix_s=self._last_usable_vision_s,
            taking_off=self._climbing_after_takeoff(),
            position_std_m=self._horizontal_position_std_m())
        for ev in self.failsafe.update(inputs, settings):
            self._apply_failsafe(ev, est)
        for ev in self._failsafe_checks(inputs):
            self._apply_failsafe(ev, est)
        for ev in self._fence_events(inputs.flying, inputs.landing, est.position_enu_m):
            self._apply_failsafe(ev, est)

    def _horizontal_position_std_m(self) -> float:
        """The EKF's horizontal 1-sigma position uncertainty (infinite before alignment)."""
        if not self.nav.aligned:
            return math.inf
        std = self.nav.position_std_m()
        return float(max(std[0], std[1]))

    def _climbing_after_takeoff(self) -> bool:
        """A take-off (GUIDED takeoff or AUTO NAV_TAKEOFF) that has not reached its height yet; a
        GUIDED takeoff's law keeps holding at the top once there, which is no longer a climb."""
        law = self._law
        return (self._law_kind() == LawKind.TAKEOFF and isinstance(law, WaypointTracker)
                and not law.complete)

    def _failsafe_settings(self) -> FailsafeSettings:
        """The GCS / vision failsafe settings, rebuilt only after a parameter change."""
        p = self.params
        cached = self._settings_cache.get("failsafe")
        if cached is not None and cached[0] == p.generation:
            return cached[1]
        settings = FailsafeSettings(gcs_action=p.get_int("FS_GCS_ENABLE"),
                                    gcs_timeout_s=p.get("FS_GCS_TIMEOUT"),
                                    vision_timeout_s=p.get("SN_VIS_TIMEOUT"),
                                    vision_land_after_s=p.get("SN_VIS_FS_LAND"),
                                    vision_dr_max_m=p.get("SN_VIS_DR_MAX"))
        self._settings_cache["failsafe"] = (p.generation, settings)
        return settings

    def _battery_settings(self) -> BatterySettings:
        """The battery failsafe settings, rebuilt only after a parameter change."""
        p = self.params
        cached = self._settings_cache.get("battery")
        if cached is not None and cached[0] == p.generation:
            return cached[1]
        settings = BatterySettings(
            low_volt_v=p.get("BATT_LOW_VOLT"), low_timer_s=p.get("BATT_LOW_TIMER"),
            low_mah=p.get("BATT_LOW_MAH"), crt_volt_v=p.get("BATT_CRT_VOLT"),
            crt_mah=p.get("BATT_CRT_MAH"), capacity_mah=p.get("BATT_CAPACITY"),
            low_action=p.get_int("BATT_FS_LOW_ACT"), crt_action=p.get_int("BATT_FS_CRT_ACT"))
        self._settings_cache["battery"] = (p.generation, settings)
        return settings

    def _failsafe_checks(self, inputs: FailsafeInputs) -> list[FailsafeEvent]:
        """The EKF and battery failsafes (``failsafe_checks``)."""
        p = self.params

        def variances() -> EkfVariances:    # EKF_STATUS_REPORT's, computed only when a check is due
            return EkfVariances(*self._ekf_variances())
        # differs from ArduCopter: with external navigation as the position source the vision
        # failsafe (SN_VIS_*) owns position loss; dead reckoning between fixes is by design there
        thresh = 0.0 if inputs.vision_required else p.get("FS_EKF_THRESH")
        events = self.ekf_check.update(self._now_s, self._armed, inputs.position_mode, variances,
                                       thresh, p.get_int("FS_EKF_ACTION"))
        if p.get_int("BATT_MONITOR") == 0:
            return events
        battery = self.battery.state(p.get("BATT_CAPACITY"))
        events += self.battery_failsafe.update(self._now_s, inputs.flying, battery.voltage_v,
                                               battery.consumed_mah, self._battery_settings())
        return events

    def _apply_failsafe(self, ev: FailsafeEvent, est: NavState) -> None:
        self._announce(ev.severity, ev.text)
        if self._smart_rtl_first(ev):
            self.stats["failsafe_gcs_smart_rtl"] += 1
            return
        if ev.action == FailsafeAction.RTL:
            if not self._enter_mode(CopterMode.RTL, from_gcs=False).ok:
                self._enter_mode(CopterMode.LAND, from_gcs=False)
        elif ev.action == FailsafeAction.LAND:
            self._vision_hold = None
            self._enter_mode(CopterMode.LAND, from_gcs=False)
        elif ev.action == FailsafeAction.LAND_START_OR_RTL:
            self._vision_hold = None
            self._land_start_or_rtl()
        elif ev.action == FailsafeAction.BRAKE:
            self._vision_hold = None
            if not self._enter_mode(CopterMode.BRAKE, from_gcs=False).ok:
                self._enter_mode(CopterMode.LAND, from_gcs=False)
        elif ev.action == FailsafeAction.ALT_HOLD:
            self._vision_hold = None
            self._enter_mode(CopterMode.ALT_HOLD, from_gcs=False)
        elif ev.action == FailsafeAction.HOLD:
            stop = stopping_point(est.position_enu_m, est.velocity_enu_m_s, self._gcfg.wp_accel_m_s2)
            self._vision_hold = Hold(stop, float(est.heading_rad))
        elif ev.action == FailsafeAction.RESUME and self._vision_hold is not None:
            self._vision_hold = None
            self._restart_mode_law(est)
        self.stats[f"failsafe_{ev.kind.value}_{ev.action.value}"] += 1

    def _land_start_or_rtl(self) -> None:
        """ArduCopter ``set_mode_auto_do_land_start_or_RTL``: the landing sequence, else RTL (LAND
        when RTL is refused)."""
        if self._jump_to_landing_sequence(from_gcs=False).ok:
            return
        self._announce(MavSeverity.WARNING, "Trying RTL Mode")
        if not self._enter_mode(CopterMode.RTL, from_gcs=False).ok:
            self._enter_mode(CopterMode.LAND, from_gcs=False)

    def _smart_rtl_first(self, ev: FailsafeEvent) -> bool:
        """FS_GCS_ENABLE 3 / 4 (SmartRTL or RTL / Land): SMART_RTL when its path is usable, else
        ArduCopter's message and the fallback (``set_mode_SmartRTL_or_RTL`` / ``_or_land``)."""
        if ev.kind != FailsafeKind.GCS or ev.action not in (FailsafeAction.RTL, FailsafeAction.LAND):
            return False
        if self.params.get_int("FS_GCS_ENABLE") not in (GcsFailsafeAction.SMARTRTL_OR_RTL,
                                                         GcsFailsafeAction.SMARTRTL_OR_LAND):
            return False
        if self._enter_mode(CopterMode.SMART_RTL, from_gcs=False).ok:
            return True
        fallback = "RTL Mode" if ev.action == FailsafeAction.RTL else "Land Mode"
        verb = "Trying" if ev.action == FailsafeAction.RTL else "Using"
        self._announce(MavSeverity.WARNING, f"SmartRTL Unavailable, {verb} {fallback}")
        return False

    def _record_path(self, est: NavState) -> None:
        """SmartRTL's breadcrumbs: from arming while flying with a position estimate (disarmed:
        the path and a pending ALT_HOLD takeoff end)."""
        path = self.srtl_path
        if not self._armed:
            self._alt_hold_takeoff_z = None
            if path.active or path.deactivated_reason:
                path.stop()
                path.deactivated_reason = ""
            return
        if self.fc.landed or not self._position_ok():
            return
        if not path.active and not path.deactivated_reason:
            start = self._home if self._home is not None else est.position_enu_m
            path.start(start, self.params.get("SRTL_ACCURACY"), self.params.get_int("SRTL_POINTS"))
        message = path.add(est.position_enu_m)
        if message:
            self._announce(MavSeverity.WARNING, message)

    # --------------------------------------------------------------------------- control
    def _law_kind(self) -> LawKind | None:
        return getattr(self._law, "kind", None) if self._law is not None else None

    def _control(self, est: NavState, gyro: np.ndarray, dt: float) -> ControlOutput | None:
        if not self._armed:
            return None
        fc = self.fc
        mode = self._mode
        if self._vision_hold is None:
            pilot = self._pilot_control(est, gyro, dt)            # RC_CHANNELS_OVERRIDE etc.
            if pilot is not None:
                return pilot
        if mode == CopterMode.STABILIZE:
            frac = 0.0 if fc.landed else self.airframe.hover_thrust_fraction
            return fc.update_stabilize(est, gyro, 0.0, 0.0, 0.0, frac, dt)
        if mode == CopterMode.ALT_HOLD:
            return fc.update_alt_hold(est, gyro, 0.0, 0.0, 0.0, self._alt_hold_takeoff_climb(est), dt)
        if self._vision_hold is not None:
            return fc.update_position(est, gyro, self._vision_hold.update(est, dt), dt)
        if self._pause_hold is not None:                     # DO_PAUSE_CONTINUE
            return fc.update_position(est, gyro, self._pause_hold.update(est, dt), dt)
        if mode == CopterMode.GUIDED and self._guided is not None:
            return self._guided_control(est, gyro, dt)
        if self._law is None:
            self._law = Hold(est.position_enu_m, float(est.heading_rad))
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
            if mode == CopterMode.SMART_RTL and self._law.complete:
                # home reached (2 m above it): ArduCopter lands, or RTLs to RTL_ALT_FINAL
                final = CopterMode.RTL if self.params.get("RTL_ALT_FINAL") > 0 else CopterMode.LAND
                self._enter_mode(final, from_gcs=False)
                target = self._law.update(est, dt)
        if mode == CopterMode.GUIDED and self._guided_heading is not None:
            target = dataclasses.replace(target, heading_rad=self._guided_heading_now(dt))
        if mode in (CopterMode.AUTO, CopterMode.GUIDED):
            heading = self._commanded_heading(est)       # DO_SET_ROI, CONDITION_YAW
            if heading is not None:
                target = dataclasses.replace(target, heading_rad=heading)
        self._last_target = target
        return fc.update_position(est, gyro, target, dt)

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
        if mode == CopterMode.AUTO_RTL:
            # differs: ArduCopter 4.5 first tries a DO_RETURN_PATH_START return path
            return self._jump_to_landing_sequence(from_gcs)
        if mode == CopterMode.AUTO and self._auto_rtl and self._mode == CopterMode.AUTO:
            self._auto_rtl = False          # AUTO asked for again: the mission goes on as AUTO
            self._tel = None
            self._events.append(ModeChangedEvent(CopterMode.AUTO))
            return Outcome(True)
        if mode == self._mode and (from_gcs or mode in (CopterMode.RTL, CopterMode.LAND)):
            return Outcome(True)
        if mode in NEEDS_POSITION and not self._position_ok():
            return self._refuse(f"Mode change to {mode.name} failed: requires position")
        if mode == CopterMode.SMART_RTL and not self.srtl_path.usable:
            return self._refuse("Mode change to SMART_RTL failed: no SmartRTL path")
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
        self._auto_rtl = False
        self._tel = None
        self._guided = None
        self._guided_heading = None
        self._guided_yaw_rate = None
        self._alt_hold_takeoff_z = None
        self._roi_enu = None
        self._auto_heading = None
        self._pause_hold = None
        self._pilot_point = None
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
        if mode in (CopterMode.GUIDED, CopterMode.LOITER, CopterMode.POSHOLD):
            # POSHOLD without pilot input (there is no RC here) brakes and holds, as LOITER
            self._law = Hold(stop if not self.fc.landed else est.position_enu_m, heading)
        elif mode == CopterMode.BRAKE:
            brake = stopping_point(est.position_enu_m, est.velocity_enu_m_s, BRAKE_DECEL_M_S2)
            self._law = Hold(brake if not self.fc.landed else est.position_enu_m, heading)
        elif mode == CopterMode.AUTO:
            self._auto_enter(est)
        elif mode == CopterMode.RTL:
            self._law = self._make_rtl(est)
        elif mode == CopterMode.LAND:
            self._law = Land(self._gcfg, stop, self._home_z(), heading_rad=heading)
        elif mode == CopterMode.CIRCLE:
            settings = self._circle_settings()
            centre = centre_ahead(stop, heading, settings.radius_m)
            self._law = Circle(self._gcfg, centre, float(stop[2]), settings, stop, heading_rad=heading)
        elif mode == CopterMode.SMART_RTL:
            self._law = smart_rtl_law(self._gcfg, self.srtl_path, stop)
        else:
            self._law = None

    def _restart_mode_law(self, est: NavState) -> None:
        """After a vision-failsafe hold: continue the mode from where the vehicle now is."""
        if self._mode == CopterMode.AUTO and self._mission_state == MissionState.ACTIVE:
            self._auto_start(self._mission_index, est)
        elif self._mode == CopterMode.GUIDED and isinstance(self._law, Tracker):
            dest = self._law.destination
            self._law = self._new_tracker([Waypoint(tuple(dest))], est)
        elif self._mode not in (CopterMode.GUIDED,):
            self._start_mode_law(est)

    def _make_rtl(self, est: NavState) -> Rtl:
        cfg = self._gcfg
        rtl_speed = self.params.get("RTL_SPEED") / 100.0
        if rtl_speed > 0:
            cfg = dataclasses.replace(cfg, wp_speed_m_s=rtl_speed)
        if self.params.get_int("WP_YAW_BEHAVIOR") in (0, 2):
            cfg = dataclasses.replace(cfg, yaw_behaviour=YawBehaviour.NEVER_CHANGE)
        home = self._rtl_destination(est)      # home or a rally point (core_geofence)
        return Rtl(cfg, home, est, self.params.get("RTL_ALT_FINAL") / 100.0,
                    heading_rad=float(est.heading_rad))

    def _circle_settings(self) -> CircleSettings:
        return CircleSettings(self.params.get("CIRCLE_RADIUS") / 100.0, self.params.get("CIRCLE_RATE"))

    def _home_z(self) -> float:
        return float(self._home[2]) if self._home is not None else self.cfg.ground_z_m

    def _new_tracker(self, waypoints: Sequence[Waypoint], est: NavState,
                     start=None) -> Tracker:
        if start is None:
            start = stopping_point(est.position_enu_m, est.velocity_enu_m_s,
                                   self._gcfg.wp_accel_m_s2)
        return Tracker(self._gcfg, waypoints, start)

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

    # =========================================================================== Vehicle
    def drain_events(self) -> list[VehicleEvent]:
        events, self._events = self._events, []
        return events

    def set_mode(self, mode: CopterMode) -> Outcome:
        return self._enter_mode(mode, from_gcs=True)

    def land(self) -> Outcome:
        return self._enter_mode(CopterMode.LAND, from_gcs=True)

    def return_to_launch(self) -> Outcome:
        return self._enter_mode(CopterMode.RTL, from_gcs=True)
