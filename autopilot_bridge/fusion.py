"""Sensor inputs and their fusion into the navigation filter (part of ``FlightCore``).

``on_baro`` / ``on_compass`` / ``on_gps`` / ``on_vision_fix`` (bus) and ``vision_position_estimate``
/ ``odometry`` (MAVLink external navigation) check and buffer; ``_fuse_pending`` fuses the buffer
after each EKF predict. Vision fixes are fused only when valid and accepted by the perception node,
younger than ``vision_max_age_s`` and taken at least SN_VIS_MIN_ALT above home; one wider than
SN_VIS_MAX_SD at most once per ``wide_vision_fix_interval_s`` (an ambiguous match repeats its error
from frame to frame; the skipped ones still count as fixes for the vision failsafe); on the ground without
a position source the last landed position is fused as a pseudo-measurement (as ArduPilot's EKF does
when it is not aiding); disarmed on the ground the averaged body x, y rates are fused as the gyro
biases (zero-rate update: a dead-reckoned climb drifts by g eps t^3 / 6 for a residual bias eps).
``on_flow`` takes the optical-flow module's samples: in the air, with FLOW_TYPE > 0 and the active
EK3_SRCn_VELXY = 5 (OpticalFlow), a sample with a valid range within RNGFND1_MIN_CM .. RNGFND1_MAX_CM, quality > 0, a tilt under 45 deg and a
rate under EK3_MAX_FLOW is fused as body velocity (``NavFilter.fuse_optical_flow``, EK3_FLOW_M_NSE,
EK3_FLOW_I_GATE). ``on_camera_flow`` takes the followed perception node's camera flow (VisionFix
version 3): with SN_CAM_FLOW 1 it is fused the same way, its body rotation removed with this
autopilot's own gyro over the frame interval (``_camera_flow_fusion``). ``on_power`` feeds the
battery monitor.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from autopilot_bridge.config import PositionSource
from autopilot_bridge.external_vision import (
    JitterCorrection,
    ResetCounter,
    VisoSettings,
    angle_error_rad,
    attitude_matrix,
    body_origin_ned,
    heading_of,
    position_error_m,
)
from autopilot_bridge.geo_frame import ned_to_enu
from autopilot_bridge.vehicle_interface import (
    MavSeverity,
    Odometry,
)
from scenenav.core.contracts import FlowSample, GpsFixType
from scenenav.core.numeric import all_finite, largest_sd_2x2
from scenenav.core.rotations import quat_to_rotation_matrix

logger = logging.getLogger(__name__)

EXTNAV_SOURCE = 6            # EK3_SRCn_* value ExternalNav
OPTFLOW_SOURCE = 5           # EK3_SRCn_VELXY value OpticalFlow
#: ArduPilot EKF3 fuses flow only while the body z axis is within 45 deg of vertical (prevTnb.c.z > 0.7071)
FLOW_MAX_TILT_COS = math.cos(math.radians(45.0))
#: the flow module's range accuracy (FlowSample.distance_m), 1 % of the range: the EKF's range variance
FLOW_RANGE_STD_FRACTION = 0.01
#: the camera flow's range 1-sigma as a fraction: the image holds roofs 10-30 m above the street at a
#: 100 m survey height (worlds.city_config), which move 10-40 % faster than the street; the range
#: finder's recent mean (CAMERA_FLOW_RANGE_WINDOW_S) follows how much of the scene is roof, but along
#: the track only, and height above home / cos(tilt) not at all
CAMERA_FLOW_RANGE_STD_FRACTION = 0.1
#: the range finder's ranges of this many seconds are averaged (harmonically: the flow scales with
#: 1 / range) into the camera flow's range; at 10 m/s, 30 m of track. Measured on realistic flights
#: (docs/perception.md "The camera as a flow sensor"): the camera flow's forward bias against the
#: truth fell from +0.27-0.36 m/s (height above home) to -0.03-+0.08 m/s
CAMERA_FLOW_RANGE_WINDOW_S = 3.0
#: a camera flow over a longer interval is not one (VisionFix.flow_interval_us: consecutive frames)
CAMERA_FLOW_MAX_INTERVAL_S = 1.0
#: fewer valid ranges than this in the window: height above home / cos(tilt) instead
CAMERA_FLOW_RANGE_MIN_SAMPLES = 5
#: body rates kept for the camera flow's rotation (s): the frame interval plus the fix's delivery lag
GYRO_HISTORY_S = 2.0
_TWO_PI = 2.0 * math.pi


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
class VisionReading:
    t_s: float                                    # capture time
    xy_enu_m: tuple[float, float]
    cov_m2: np.ndarray                            # (2, 2)
    source: str
    heading_rad: float = math.nan                 # the heading the fix measured (NaN: none)
    heading_std_rad: float = math.nan


@dataclass(frozen=True)
class FlowReading:
    t_s: float
    flow_flu_rad_s: tuple[float, float]
    body_rate_flu_rad_s: tuple[float, float]
    distance_m: float
    quality: int

    @property
    def translation_rate_flu_rad_s(self) -> tuple[float, float]:
        """The flow with the body rotation removed (flow + the module's gyro): the translation's part."""
        return (self.flow_flu_rad_s[0] + self.body_rate_flu_rad_s[0],
                self.flow_flu_rad_s[1] + self.body_rate_flu_rad_s[1])


def flow_reading(msg: FlowSample) -> FlowReading:
    """The autopilot's view of a bus ``FlowSample``."""
    return FlowReading(msg.timestamp_us * 1e-6, tuple(msg.flow_flu_rad_s), tuple(msg.body_rate_flu_rad_s),
                       msg.distance_m, msg.quality)


@dataclass(frozen=True)
class CameraFlowReading:
    """A perception node's camera flow (VisionFix version 3): ``t_s`` the frame's capture time,
    ``flow_flu_rad_s`` the image motion as a flow rate, body rotation not removed, over
    ``interval_s`` before it; ``quality`` 0..1."""

    t_s: float
    flow_flu_rad_s: tuple[float, float]
    interval_s: float
    quality: float


class SensorFusionMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_fusion(self) -> None:
        """Measurements buffered until the next step (fused after the predict) and their ages."""
        self._baro: list[float] = []
        self._compass: list[float] = []
        self._gps: list[GpsReading] = []
        self._flow: list[FlowReading] = []
        self._camera_flow: list[CameraFlowReading] = []
        self._ranges: deque[tuple[float, float]] = deque()   # (t s, valid range finder range m)
        self._gyro_history: deque[tuple[float, np.ndarray]] = deque()   # (t s, raw gyro FLU rad/s)
        self._last_flow: FlowReading | None = None     # telemetry (OPTICAL_FLOW, DISTANCE_SENSOR)
        self._vision: list[VisionReading] = []
        self._last_gps: GpsReading | None = None
        self._last_gps_fused_s: float | None = None
        self._last_usable_vision_s: float | None = None
        self._last_wide_vision_fused_s: float | None = None    # SN_VIS_MAX_SD
        self._last_ext_nav_s: float | None = None
        self._viso_clock = JitterCorrection()   # MAVLink external nav: sender time -> ours
        self._viso_reset = ResetCounter()
        # (value, std, time it was measured: VISO_DELAY_MS before its jitter-corrected arrival)
        self._ext_height: list[tuple[float, float, float]] = []   # ENU z m, m: EK3_SRCn_POSZ 6
        self._ext_yaw: list[tuple[float, float, float]] = []      # heading rad, rad: EK3_SRCn_YAW 6
        self._last_ext_height_s: float | None = None
        self._last_ext_yaw_s: float | None = None
        self._last_vision_yaw_s: float | None = None    # a VisionFix heading fused (SN_VIS_YAW_HOLD)
        self._rest_gyro_sum = np.zeros(3)      # body rates summed at rest (disarmed on the ground)
        self._drag_accel_sum = np.zeros(3)     # specific force summed in flight (drag fusion)
        self._drag_s = 0.0
        self._rest_n = 0
        self._rest_s = 0.0
        self._inflight_yaw_aligned = False     # this flight's in-flight yaw alignment is done

    def on_baro(self, t_s: float, altitude_m: float) -> None:
        if not all_finite(altitude_m):
            self.stats["baro_nan"] += 1
            return
        if self.nav.aligned:
            self._baro.append(float(altitude_m))
        else:
            self.alignment.add_baro(altitude_m)

    def on_compass(self, t_s: float, heading_rad: float) -> None:
        if not all_finite(heading_rad):
            self.stats["compass_nan"] += 1
            return
        h = float(heading_rad) % _TWO_PI
        if self.nav.aligned:
            self._compass.append(h)
        else:
            self.alignment.add_heading(h)

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
            self.alignment.add_gps(self.geo.to_enu(reading.lat_deg, reading.lon_deg))

    def on_flow(self, reading: FlowReading) -> None:
        """An optical-flow module sample (buffered; fused after the next predict, see the module
        docstring). A non-finite rate is counted only when the range is valid (out of range, the
        module reports NaN by design)."""
        if not all_finite(*reading.body_rate_flu_rad_s) or (
                all_finite(reading.distance_m) and not all_finite(*reading.flow_flu_rad_s)):
            self.stats["flow_nan"] += 1
            return
        self._last_flow = reading
        if self.nav.aligned:
            self._flow.append(reading)
        self._record_range(reading)

    def _record_range(self, reading: FlowReading) -> None:
        """Keep the range finder's valid ranges of the last CAMERA_FLOW_RANGE_WINDOW_S (camera flow)."""
        r_min, r_max = self._rangefinder_limits_m()
        h = self._ranges
        if all_finite(reading.distance_m) and r_min <= reading.distance_m <= r_max:
            h.append((reading.t_s, float(reading.distance_m)))
        while h and h[0][0] < reading.t_s - CAMERA_FLOW_RANGE_WINDOW_S:
            h.popleft()

    def _camera_flow_range(self, tilt_cos: float, height_m: float) -> float:
        """The range the camera flow is scaled by: the harmonic mean of the range finder's recent
        ranges when it has enough of them (FLOW_TYPE > 0), else height above home / cos(tilt)."""
        h = self._ranges
        if (self.params.get_int("FLOW_TYPE") != 0 and len(h) >= CAMERA_FLOW_RANGE_MIN_SAMPLES
                and self._now_s - h[-1][0] <= 1.0):
            return len(h) / sum(1.0 / r for _, r in h)
        return height_m / tilt_cos

    def on_camera_flow(self, reading: CameraFlowReading) -> None:
        """The followed perception node's camera flow for one frame (buffered; fused after the next
        predict with SN_CAM_FLOW 1, ``_camera_flow_fusion``)."""
        if not (all_finite(reading.t_s, reading.interval_s, reading.quality, *reading.flow_flu_rad_s)
                and 0.0 < reading.interval_s <= CAMERA_FLOW_MAX_INTERVAL_S and 0.0 <= reading.quality <= 1.0):
            self.stats["camera_flow_nan"] += 1       # not finite, or an interval or quality out of range
            return
        if self.nav.aligned:
            self._camera_flow.append(reading)

    def _record_gyro(self, t_s: float, gyro_flu_rad_s: np.ndarray) -> None:
        """A control tick's raw body rates (averaged over the tick ending at ``t_s``)."""
        h = self._gyro_history
        h.append((t_s, gyro_flu_rad_s))
        while h and h[0][0] < t_s - GYRO_HISTORY_S:
            h.popleft()

    def _mean_gyro(self, t0_s: float, t1_s: float) -> np.ndarray | None:
        """The mean raw body rate over (t0, t1] from the ticks in it (None when there are none)."""
        rates = [g for t, g in self._gyro_history if t0_s + 1e-6 < t <= t1_s + 1e-6]
        return np.mean(rates, axis=0) if rates else None

    def on_power(self, t_s: float, voltage_v: float, current_a: float) -> None:
        """A power-module measurement (battery voltage and current), reported over MAVLink."""
        self.battery.on_sample(t_s, voltage_v, current_a)

    def on_vision_fix(self, capture_t_s: float, xy_enu_m, cov_2x2_m2, valid: bool, accepted: bool,
                      source: str = "", heading_rad: float = math.nan,
                      heading_std_rad: float = math.nan) -> None:
        """A scene-matching fix from the followed perception node; fused at the next step when
        usable (valid, accepted, finite, recent, taken above SN_VIS_MIN_ALT). Its heading (when
        finite, with a positive 1-sigma) is fused as external-navigation yaw when EK3_SRCn_YAW is 6
        and the EKF accepted the fix's position (``_fuse_vision``)."""
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
        hdg, hdg_std = float(heading_rad), float(heading_std_rad)
        if not (all_finite(hdg, hdg_std) and hdg_std > 0.0):
            hdg = hdg_std = math.nan
        self._vision.append(VisionReading(float(capture_t_s), (xy[0], xy[1]), cov, source, hdg, hdg_std))

    def _ext_nav_source(self, kind: str) -> bool:
        """EK3_SRC<active set>_<kind> is 6 (ExternalNav)."""
        return self.params.get_int(f"EK3_SRC{self._source_set}_{kind}") == EXTNAV_SOURCE

    def _vision_yaw_held(self) -> bool:
        """A vision fix's heading was fused within SN_VIS_YAW_HOLD seconds."""
        t_s = self._last_vision_yaw_s
        return t_s is not None and self._now_s - t_s <= self.params.get("SN_VIS_YAW_HOLD")

    def _fresh(self, t_s: float | None) -> bool:
        return t_s is not None and self._now_s - t_s <= self.cfg.ext_nav_fresh_s

    def _fuse_pending(self) -> None:
        nav = self.nav
        ext_height = self._ext_nav_source("POSZ")
        ext_yaw = self._ext_nav_source("YAW")
        for z, std, t_s in self._ext_height:
            nav.fuse_ext_nav_height(z, std, age_s=max(0.0, self._now_s - t_s))
            self.stats["ext_nav_height_fused"] += 1
        self._ext_height.clear()
        for hdg, std, t_s in self._ext_yaw:
            nav.fuse_ext_nav_yaw(hdg, std, age_s=max(0.0, self._now_s - t_s))
            self.stats["ext_nav_yaw_fused"] += 1
        self._ext_yaw.clear()
        # the barometer / compass while external navigation gives no height / yaw (the fallback)
        baro = not (ext_height and self._fresh(self._last_ext_height_s))
        for alt in self._baro:
            if baro:
                nav.fuse_baro(alt)
        self._baro.clear()
        compass = not (ext_yaw and (self._fresh(self._last_ext_yaw_s) or self._vision_yaw_held()))
        if compass and self._compass:
            self._inflight_yaw_alignment(self._compass[-1])
        for hdg in self._compass:
            if compass:
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
        self._flow_fusion()
        self._camera_flow_fusion()
        self._ground_fusion()
        self._rest_fusion()
        self._drag_fusion()

    def _inflight_yaw_alignment(self, heading_rad: float) -> None:
        """ArduPilot EKF3's final in-flight yaw alignment (``controlMagYawReset``): once per flight,
        when the estimate first climbs ``inflight_yaw_reset_height_m`` (EKF3_MAG_FINAL_RESET_ALT,
        2.5 m) above home, the heading is reset to the compass. On the ground the compass reads the
        magnetic field of what is around (steel, cables, rebar: sim.compass.anomaly_*); the heading
        the filter aligned with there is wrong by that much, and once the reading clears with height
        the filter would reject it until its rejection timeout. 0 m: off."""
        if not self._armed or self.fc.landed:
            if not self._armed:
                self._inflight_yaw_aligned = False
            return
        limit = self.cfg.inflight_yaw_reset_height_m
        if self._inflight_yaw_aligned or limit <= 0.0 or self._height_above_home() < limit:
            return
        self._inflight_yaw_aligned = True
        jump = self.nav.reset_heading_to_compass(heading_rad)
        self.stats["inflight_yaw_alignments"] += 1
        text = f"EKF3 IMU0 MAG0 in-flight yaw alignment complete ({math.degrees(jump):+.1f} deg)"
        logger.info(text)
        self._bus_text(MavSeverity.INFO, text)

    def _height_above_home(self) -> float:
        home_z = self._home[2] if self._home is not None else self.cfg.ground_z_m
        return float(self.nav.state().position_enu_m[2]) - float(home_z)

    def _fuse_vision(self, v: VisionReading) -> None:
        age = self._now_s - v.t_s
        if age > self.cfg.vision_max_age_s or age < -0.5:
            self.stats["vision_stale"] += 1
            return
        if v.source != "mavlink" and self._height_above_home() < self.params.get("SN_VIS_MIN_ALT"):
            self.stats["vision_below_min_alt"] += 1
            return
        self._last_usable_vision_s = self._now_s
        max_sd = self.params.get("SN_VIS_MAX_SD")
        cov = v.cov_m2
        if max_sd > 0.0 and largest_sd_2x2(v.cov_m2) > max_sd:
            narrowed = self._narrowed(v, age)
            if narrowed is not None:
                cov = narrowed
                self.stats["vision_wide_narrowed"] += 1
            else:
                last = self._last_wide_vision_fused_s
                if last is not None and self._now_s - last < self.cfg.wide_vision_fix_interval_s:
                    self.stats["vision_wide_skipped"] += 1
                    return
                self._last_wide_vision_fused_s = self._now_s
                self.stats["vision_wide_fused"] += 1
        # SN_VIS_TILT 1: the node aligned the image with this EKF's roll and pitch (a fixed camera)
        tilt_h = (max(self._height_above_home(), 0.0)
                  if v.source != "mavlink" and self.params.get_int("SN_VIS_TILT") == 1 else 0.0)
        r = self.nav.fuse_vision_position(v.xy_enu_m, cov, age_s=max(age, 0.0), camera_height_m=tilt_h)
        if self.nav.position_source != PositionSource.EXTNAV:
            self.stats["vision_monitored"] += 1
        elif r.accepted:
            self.stats["vision_fused"] += 1
            if math.isfinite(v.heading_rad) and self._ext_nav_source("YAW"):
                self.nav.fuse_ext_nav_yaw(v.heading_rad, v.heading_std_rad, age_s=max(age, 0.0))
                self._last_vision_yaw_s = self._now_s
                self.stats["vision_yaw_fused"] += 1
        else:
            self.stats["vision_rejected"] += 1

    def _narrowed(self, v: VisionReading, age_s: float) -> np.ndarray | None:
        """SN_VIS_WIDE_SD: the covariance a wide fix (an ambiguous match, published as wide as its
        search area) is fused with when it lies where the estimate is, within
        ``wide_vision_narrow_gate_sd`` of the EKF's uncertainty combined with SN_VIS_WIDE_SD (taken
        as the true peak: that 1-sigma); None otherwise, or with 0."""
        narrow_sd = self.params.get("SN_VIS_WIDE_SD")
        if narrow_sd <= 0.0 or self.nav.position_source != PositionSource.EXTNAV:
            return None
        narrow = np.eye(2) * narrow_sd * narrow_sd
        ratio = self.nav.vision_test_ratio(v.xy_enu_m, narrow, self.cfg.wide_vision_narrow_gate_sd,
                                           age_s=max(age_s, 0.0))
        return narrow if ratio <= 1.0 else None

    def _rangefinder_limits_m(self) -> tuple[float, float]:
        """RNGFND1_MIN_CM and RNGFND1_MAX_CM in metres: readings outside are out of range."""
        p = self.params
        return p.get("RNGFND1_MIN_CM") / 100.0, p.get("RNGFND1_MAX_CM") / 100.0

    def _flow_fitted(self) -> bool:
        """FLOW_TYPE is set and the module has sent a sample (telemetry and SYS_STATUS)."""
        return self._last_flow is not None and self.params.get_int("FLOW_TYPE") != 0

    def _flow_fusion(self) -> None:
        """The buffered flow samples (module docstring), each as two scalar measurements."""
        flows, self._flow = self._flow, []
        if not flows:
            return
        p = self.params
        if (p.get_int("FLOW_TYPE") == 0 or not self._armed or self.fc.landed
                or p.get_int(f"EK3_SRC{self._source_set}_VELXY") != OPTFLOW_SOURCE):
            return
        noise = p.get("EK3_FLOW_M_NSE")
        gate = p.get("EK3_FLOW_I_GATE") / 100.0
        max_rate = p.get("EK3_MAX_FLOW")
        tilt_cos = float(quat_to_rotation_matrix(self.nav.state().q_wxyz)[2, 2])
        r_min, r_max = self._rangefinder_limits_m()
        for f in flows:
            r = f.distance_m
            if f.quality <= 0 or not (all_finite(r) and r > 0.0) or tilt_cos < FLOW_MAX_TILT_COS:
                self.stats["flow_unusable"] += 1
                continue
            if not r_min <= r <= r_max:
                self.stats["flow_out_of_range"] += 1
                continue
            rate = f.translation_rate_flu_rad_s
            if max(abs(rate[0]), abs(rate[1])) > max_rate:
                self.stats["flow_too_fast"] += 1
                continue
            rx, ry = self.nav.fuse_optical_flow(rate, r, noise, gate, FLOW_RANGE_STD_FRACTION * r)
            self.stats["flow_fused"] += int(rx.accepted) + int(ry.accepted)
            self.stats["flow_rejected"] += int(not rx.accepted) + int(not ry.accepted)

    def _camera_flow_fusion(self) -> None:
        """The buffered camera flows (SN_CAM_FLOW 1): each with the body rotation over its frame
        interval removed (this autopilot's gyro minus the EKF's bias), over ``_camera_flow_range``,
        as two scalar flow measurements (``NavFilter.fuse_optical_flow``)."""
        flows, self._camera_flow = self._camera_flow, []
        p = self.params
        if not flows or p.get_int("SN_CAM_FLOW") == 0 or not self._armed or self.fc.landed:
            return
        st = self.nav.state()
        tilt_cos = float(quat_to_rotation_matrix(st.q_wxyz)[2, 2])
        height = self._height_above_home()
        if tilt_cos < FLOW_MAX_TILT_COS or height < max(p.get("SN_VIS_MIN_ALT"), 1.0):
            self.stats["camera_flow_unusable"] += len(flows)
            return
        r = self._camera_flow_range(tilt_cos, height)
        noise = p.get("SN_CAM_FLOW_NSE")
        gate = p.get("EK3_FLOW_I_GATE") / 100.0
        max_rate = p.get("EK3_MAX_FLOW")
        q_min = p.get("SN_CAM_FLOW_QMIN")
        for f in flows:
            if f.quality < q_min:
                self.stats["camera_flow_low_quality"] += 1
                continue
            gyro = self._mean_gyro(f.t_s - f.interval_s, f.t_s)
            if gyro is None:
                self.stats["camera_flow_no_gyro"] += 1
                continue
            rate = (f.flow_flu_rad_s[0] + float(gyro[0] - st.gyro_bias[0]),
                    f.flow_flu_rad_s[1] + float(gyro[1] - st.gyro_bias[1]))
            if max(abs(rate[0]), abs(rate[1])) > max_rate:
                self.stats["camera_flow_too_fast"] += 1
                continue
            # a weaker correlation peak, a less sure shift: 1 / quality^2 (measured, docs/perception.md)
            rx, ry = self.nav.fuse_optical_flow(rate, r, noise / (f.quality * f.quality), gate,
                                                CAMERA_FLOW_RANGE_STD_FRACTION * r)
            self.stats["camera_flow_fused"] += int(rx.accepted) + int(ry.accepted)
            self.stats["camera_flow_rejected"] += int(not rx.accepted) + int(not ry.accepted)

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

    def _rest_fusion(self) -> None:
        """Disarmed on the ground (no motor test): the body rates averaged over each
        ``ground_fusion_period_s`` are fused as the gyro biases (``NavFilter.fuse_zero_rate``), so
        that a dead-reckoned climb starts with the bias learnt over the whole time at rest, not over
        the 1 s alignment only (issue 12)."""
        if self._armed or not self.fc.landed or self.motor_test_state.running:
            self._rest_n = 0
            self._rest_s = 0.0
            self._rest_gyro_sum[:] = 0.0
            return
        self._rest_gyro_sum += self._gyro
        self._rest_n += 1
        self._rest_s += self._imu_dt_s
        if self._rest_s < self.cfg.ground_fusion_period_s:
            return
        r = self.nav.fuse_zero_rate(self._rest_gyro_sum / self._rest_n, self._rest_s)
        self.stats["rest_rate_fused" if r.accepted else "rest_rate_rejected"] += 1
        self._rest_n = 0
        self._rest_s = 0.0
        self._rest_gyro_sum[:] = 0.0

    def _drag_fusion(self) -> None:
        """Armed and in the air with a drag model set (EK3_DRAG_BCOEF_X/Y or EK3_DRAG_MCOEF > 0): the
        specific force averaged over each ``drag_fusion_period_s`` is fused as drag
        (``NavFilter.fuse_drag``); on the ground the rotors' thrust is not all there is."""
        if not (self._armed and not self.fc.landed and self.nav.config.drag_fusion):
            self._drag_accel_sum[:] = 0.0
            self._drag_s = 0.0
            return
        self._drag_accel_sum += self._accel * self._imu_dt_s
        self._drag_s += self._imu_dt_s
        if self._drag_s < self.cfg.drag_fusion_period_s - 1e-9:
            return
        rx, ry = self.nav.fuse_drag(self._drag_accel_sum / self._drag_s)
        self.stats["drag_fused"] += int(rx.accepted) + int(ry.accepted)
        self.stats["drag_rejected"] += int(not rx.accepted) + int(not ry.accepted)
        self._drag_accel_sum[:] = 0.0
        self._drag_s = 0.0

    def _handle_refused_reset(self, delta_xy) -> None:
        """A vision position reset larger than SN_VIS_RST_MAX was refused (``NavFilter``)."""
        self.stats["vision_resets_refused"] += 1
        text = (f"EKF vision reset by ({float(delta_xy[0]):.0f}, {float(delta_xy[1]):.0f}) m refused: "
                f"over SN_VIS_RST_MAX {self.params.get('SN_VIS_RST_MAX'):.0f} m")
        logger.warning(text)
        self._bus_text(MavSeverity.WARNING, text)

    def _handle_position_reset(self, delta_xy) -> None:
        logger.warning("EKF position reset by (%.1f, %.1f) m", float(delta_xy[0]), float(delta_xy[1]))
        self._bus_text(MavSeverity.WARNING, f"EKF position reset by ({float(delta_xy[0]):.1f}, "
                                            f"{float(delta_xy[1]):.1f}) m")
        for law in (self._law, self._vision_hold):
            if law is not None:
                law.handle_position_reset(delta_xy)

    def vision_position_estimate(self, usec: int, x_ned_m: float, y_ned_m: float,
                                 z_ned_m: float, roll_rad: float, pitch_rad: float,
                                 yaw_rad: float, covariance: tuple[float, ...],
                                 reset_counter: int) -> None:
        self._ext_nav((x_ned_m, y_ned_m, z_ned_m), covariance, usec,
                      attitude_matrix(roll_rad, pitch_rad, yaw_rad), reset_counter)

    def odometry(self, odom: Odometry) -> None:
        if odom.quality_pct < self.params.get_int("VISO_QUAL_MIN"):
            self.stats["ext_nav_low_quality"] += 1
            return
        self._ext_nav(odom.position_m, odom.pose_covariance, odom.time_usec,
                      quat_to_rotation_matrix(odom.q_wxyz), odom.reset_counter)

    def _viso_settings(self) -> VisoSettings:
        p = self.params
        return VisoSettings(delay_s=p.get("VISO_DELAY_MS") / 1000.0,
                            lever_arm_frd_m=(p.get("VISO_POS_X"), p.get("VISO_POS_Y"), p.get("VISO_POS_Z")),
                            pos_noise_m=p.get("VISO_POS_M_NSE"), quality_min=p.get_int("VISO_QUAL_MIN"),
                            yaw_noise_rad=p.get("VISO_YAW_M_NSE"))

    def _ext_nav(self, pos_ned, cov21, usec: int, body_to_ned: np.ndarray, reset_counter: int) -> None:
        """MAVLink external navigation (``external_vision``): NED metres from the EKF origin, the
        sender's timestamp, the sensor's attitude, the 21-element pose covariance. Height and yaw
        are buffered too when the active source set takes them from external navigation."""
        if not self.nav.aligned:
            return
        s = self._viso_settings()
        t_s = self._viso_clock.local_time_s(usec * 1e-6, self._now_s) - s.delay_s
        origin_ned = body_origin_ned(pos_ned, body_to_ned, s.lever_arm_frd_m)
        enu = self._origin_enu() + ned_to_enu(origin_ned)
        err = position_error_m(cov21, s.pos_noise_m)
        cov = np.eye(2) * err * err
        self._last_ext_nav_s = self._now_s
        self.stats["ext_nav_mavlink"] += 1
        if self._ext_nav_source("POSZ") and math.isfinite(float(enu[2])):
            self._ext_height.append((float(enu[2]), err, t_s))
            self._last_ext_height_s = self._now_s
        if self._ext_nav_source("YAW"):
            self._ext_yaw.append((heading_of(body_to_ned), angle_error_rad(cov21, s.yaw_noise_rad), t_s))
            self._last_ext_yaw_s = self._now_s
        if self._viso_reset.changed(int(reset_counter)):
            self.nav.reset_horizontal_position(enu[:2], err * err)
            self.stats["ext_nav_resets"] += 1
            return
        self._vision.append(VisionReading(t_s, (float(enu[0]), float(enu[1])), cov, "mavlink"))
