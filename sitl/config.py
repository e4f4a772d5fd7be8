"""Configuration of the simulator's physics, wind, sensors and camera.

Every config is a frozen dataclass whose field names carry their unit; ``__post_init__`` range-checks
each value through ``scenenav.core.config.check`` (which raises ``ConfigError``). Load them with
``scenenav.core.config.load_config(SimConfig, mapping, source)``. Vehicle constants are not here: they are
``sitl.vehicle.VehicleParams`` (PX4 Iris model). See docs/simulator.md for the models behind each value.
``SimNodeConfig`` is the simulator node's whole configuration (SimConfig + clock + run settings), built
by the app layer from the scenario (``scenenav.app.nodes.sim_node_config``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from scenenav.core.clock import ClockConfig
from scenenav.core.config import check
from scenenav.core.config import is_finite_number as _finite


class CameraMount(str, Enum):
    """How the camera is attached to the vehicle."""

    # Nadir-stabilised: the optical axis points straight down whatever the roll/pitch; the image
    # rotates with the body heading only (image top = body forward projected on the ground).
    GIMBAL = "gimbal"
    # Rigid to the body: optical axis along body -z, image top along body +x, image right along body -y.
    FIXED = "fixed"


def _non_negative(value: float) -> bool:
    return _finite(value) and value >= 0.0


def _positive(value: float) -> bool:
    return _finite(value) and value > 0.0


@dataclass(frozen=True)
class WindConfig:
    """Mean wind plus first-order Gauss-Markov gusts (same statistics on every ENU axis)."""

    mean_velocity_enu_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std_m_s: float = 0.0             # stationary standard deviation of each gust component
    gust_time_constant_s: float = 2.0     # correlation time of the gusts

    def __post_init__(self) -> None:
        check(len(self.mean_velocity_enu_m_s) == 3 and all(_finite(v) for v in self.mean_velocity_enu_m_s),
              "mean_velocity_enu_m_s", self.mean_velocity_enu_m_s, "three finite numbers (m/s)")
        check(_non_negative(self.gust_std_m_s), "gust_std_m_s", self.gust_std_m_s, "a number >= 0")
        check(_positive(self.gust_time_constant_s), "gust_time_constant_s",
              self.gust_time_constant_s, "a number > 0")


@dataclass(frozen=True)
class ImuConfig:
    """Accelerometer and gyroscope errors: white noise per sample, constant turn-on bias, bias walk."""

    accel_noise_std_m_s2: float = 0.05
    gyro_noise_std_rad_s: float = 0.005
    accel_bias_std_m_s2: float = 0.05          # turn-on bias, drawn once per axis
    gyro_bias_std_rad_s: float = 0.002
    accel_bias_walk_m_s2_per_sqrt_s: float = 0.0   # bias random walk; 0 = constant bias
    gyro_bias_walk_rad_s_per_sqrt_s: float = 0.0
    # Motor vibration (ArduPilot SITL's SIM_ACC_RND / SIM_GYR_RND "motor noise", scaled with the
    # throttle): extra white noise of this std x throttle fraction (mean rotor speed / maximum).
    vibration_accel_m_s2: float = 0.0
    vibration_gyro_rad_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("accel_noise_std_m_s2", "gyro_noise_std_rad_s", "accel_bias_std_m_s2",
                     "gyro_bias_std_rad_s", "accel_bias_walk_m_s2_per_sqrt_s",
                     "gyro_bias_walk_rad_s_per_sqrt_s", "vibration_accel_m_s2",
                     "vibration_gyro_rad_s"):
            value = getattr(self, name)
            check(_non_negative(value), name, value, "a number >= 0")


@dataclass(frozen=True)
class BaroConfig:
    """Barometric altimeter: bias + white noise, optional Gauss-Markov drift and ground effect."""

    rate_hz: float = 20.0
    noise_std_m: float = 0.3
    bias_m: float = 0.0
    drift_std_m: float = 0.0                # slow first-order Gauss-Markov error, stationary std; 0 = off
    drift_time_constant_s: float = 300.0
    # Rotor-downwash ground effect (ArduPilot SITL SIM_BARO_GEFF_M): this error (m; negative = the
    # baro reads low) with the rotors turning on the surface, decaying linearly to zero at
    # ground_effect_height_m above the surface below (the DSM: a roof counts as ground); 0 = off.
    ground_effect_m: float = 0.0
    ground_effect_height_m: float = 2.0

    def __post_init__(self) -> None:
        check(_positive(self.rate_hz), "rate_hz", self.rate_hz, "a number > 0")
        check(_non_negative(self.noise_std_m), "noise_std_m", self.noise_std_m, "a number >= 0")
        check(_finite(self.bias_m), "bias_m", self.bias_m, "a finite number")
        check(_non_negative(self.drift_std_m), "drift_std_m", self.drift_std_m, "a number >= 0")
        check(_positive(self.drift_time_constant_s), "drift_time_constant_s",
              self.drift_time_constant_s, "a number > 0")
        check(_finite(self.ground_effect_m), "ground_effect_m", self.ground_effect_m,
              "a finite number (m)")
        check(_positive(self.ground_effect_height_m), "ground_effect_height_m",
              self.ground_effect_height_m, "a number > 0")


@dataclass(frozen=True)
class CompassConfig:
    """Compass heading (declination-corrected): white noise and bias, plus the magnetometer errors
    of ArduPilot SITL's SIM_MAG_* set, turned into the heading error they cause (sitl.sensors)."""

    rate_hz: float = 20.0
    noise_std_rad: float = 0.01   # about 0.6 degrees
    bias_rad: float = 0.0
    # Earth field (declination 0: the heading is declination-corrected); mid-latitude values
    # (NOAA/BGS World Magnetic Model, central Europe: ~48-50 uT total, ~64-66 deg inclination).
    earth_field_mgauss: float = 500.0
    inclination_deg: float = 65.0
    # Body-frame magnetometer errors (FLU axes), measured = S (field + motor + anomaly) + o:
    hard_iron_mgauss: tuple[float, float, float] = (0.0, 0.0, 0.0)       # o (SIM_MAG1_OFS)
    soft_iron_diag: tuple[float, float, float] = (1.0, 1.0, 1.0)         # S diagonal (SIM_MAG1_DIA)
    soft_iron_offdiag: tuple[float, float, float] = (0.0, 0.0, 0.0)      # S xy, xz, yz (SIM_MAG1_ODI)
    motor_mgauss_per_a: tuple[float, float, float] = (0.0, 0.0, 0.0)     # x battery current (SIM_MAG_MOT)
    # Local anomalies near buildings (SIM_MAG_ALY / SIM_MAG_ALY_HGT): a seeded field, std of each
    # component at the surface of a fully built-up cell, decaying as (h0 / (h0 + h))^3 with the
    # height h above the DSM (h0 = anomaly_height_m: the height where it has fallen to 1/8).
    anomaly_mgauss: float = 0.0
    anomaly_height_m: float = 1.0
    anomaly_cell_m: float = 20.0          # size of the anomaly field's cells

    def __post_init__(self) -> None:
        check(_positive(self.rate_hz), "rate_hz", self.rate_hz, "a number > 0")
        check(_non_negative(self.noise_std_rad), "noise_std_rad", self.noise_std_rad,
              "a number >= 0")
        check(_finite(self.bias_rad), "bias_rad", self.bias_rad, "a finite number")
        check(_positive(self.earth_field_mgauss), "earth_field_mgauss", self.earth_field_mgauss,
              "a number > 0 (mGauss)")
        check(_finite(self.inclination_deg) and -85.0 <= self.inclination_deg <= 85.0,
              "inclination_deg", self.inclination_deg, "a number in [-85, 85] degrees")
        for name in ("hard_iron_mgauss", "soft_iron_diag", "soft_iron_offdiag", "motor_mgauss_per_a"):
            value = getattr(self, name)
            check(len(value) == 3 and all(_finite(v) for v in value), name, value,
                  "three finite numbers")
        check(all(v > 0 for v in self.soft_iron_diag), "soft_iron_diag", self.soft_iron_diag,
              "three numbers > 0")
        check(_non_negative(self.anomaly_mgauss), "anomaly_mgauss", self.anomaly_mgauss,
              "a number >= 0")
        check(_positive(self.anomaly_height_m), "anomaly_height_m", self.anomaly_height_m,
              "a number > 0")
        check(_positive(self.anomaly_cell_m), "anomaly_cell_m", self.anomaly_cell_m, "a number > 0")

    @property
    def distorted(self) -> bool:
        """True when any magnetometer error beyond the heading noise and bias is on."""
        return (any(v != 0.0 for v in self.hard_iron_mgauss) or any(v != 1.0 for v in self.soft_iron_diag)
                or any(v != 0.0 for v in self.soft_iron_offdiag)
                or any(v != 0.0 for v in self.motor_mgauss_per_a) or self.anomaly_mgauss > 0.0)


@dataclass(frozen=True)
class GpsConfig:
    """GPS receiver: white noise per fix plus an optional slow Gauss-Markov position error."""

    enabled: bool = True
    rate_hz: float = 5.0
    horizontal_noise_std_m: float = 0.5
    vertical_noise_std_m: float = 1.0
    velocity_noise_std_m_s: float = 0.1
    drift_std_m: float = 0.0              # slow horizontal/vertical error, stationary std; 0 = off
    drift_time_constant_s: float = 60.0
    satellites: int = 10
    # Urban multipath: an extra Gauss-Markov horizontal error whose std is this times the share of
    # the sky (above a 15 deg elevation mask) the DSM's buildings hide from the antenna; 0 = off.
    multipath_std_m: float = 0.0
    multipath_time_constant_s: float = 5.0

    def __post_init__(self) -> None:
        check(isinstance(self.enabled, bool), "enabled", self.enabled, "true or false")
        check(_positive(self.rate_hz), "rate_hz", self.rate_hz, "a number > 0")
        for name in ("horizontal_noise_std_m", "vertical_noise_std_m", "velocity_noise_std_m_s",
                     "drift_std_m", "multipath_std_m"):
            value = getattr(self, name)
            check(_non_negative(value), name, value, "a number >= 0")
        check(_positive(self.drift_time_constant_s), "drift_time_constant_s",
              self.drift_time_constant_s, "a number > 0")
        check(_positive(self.multipath_time_constant_s), "multipath_time_constant_s",
              self.multipath_time_constant_s, "a number > 0")
        check(isinstance(self.satellites, int) and 0 <= self.satellites <= 64, "satellites",
              self.satellites, "an integer in [0, 64]")


@dataclass(frozen=True)
class FlowConfig:
    """Downward optical-flow module with a time-of-flight range finder on the same axis (``FlowSample``;
    sitl.sensors.FlowModel). Off by default: the paper's Iris carries none. The defaults describe an
    ARK Flow (PAW3902 flow sensor, Broadcom AFBR-S50LV85D range finder); docs/realism.md gives each
    value's basis."""

    enabled: bool = False                 # the module is fitted: FlowSample on sensors/flow
    rate_hz: float = 10.0                 # ArduPilot SITL SIM_FLOW_RATE default 10 Hz
    noise_std_rad_s: float = 0.05         # white noise per sample and axis
    scale_error_std: float = 0.03         # per-axis scale error drawn once per run, N(0, this)
    gyro_noise_std_rad_s: float = 0.005   # the module's own gyro (body_rate_flu_rad_s), per sample
    range_min_m: float = 0.1              # range finder's limits (AFBR-S50LV85D: 0.1..30 m)
    range_max_m: float = 30.0             # beyond it: distance NaN, quality 0, no flow
    range_noise_fraction: float = 0.01    # 1-sigma, of the range (AFBR-S50 accuracy ~1 %)

    def __post_init__(self) -> None:
        check(isinstance(self.enabled, bool), "enabled", self.enabled, "true or false")
        check(_positive(self.rate_hz), "rate_hz", self.rate_hz, "a number > 0")
        for name in ("noise_std_rad_s", "scale_error_std", "gyro_noise_std_rad_s", "range_noise_fraction"):
            value = getattr(self, name)
            check(_non_negative(value), name, value, "a number >= 0")
        check(_non_negative(self.range_min_m), "range_min_m", self.range_min_m, "a number >= 0 (m)")
        check(_finite(self.range_max_m) and self.range_max_m > self.range_min_m, "range_max_m",
              self.range_max_m, f"a number > range_min_m ({self.range_min_m} m)")


@dataclass(frozen=True)
class CameraConfig:
    """Downward camera rendering the world's orthophoto and DSM (see sitl.camera.GroundCamera)."""

    width_px: int = 200
    height_px: int = 200
    fov_deg: float = 60.0          # field of view across the width (= the vertical one for a square image)
    rate_hz: float = 10.0
    mount: CameraMount = CameraMount.GIMBAL
    noise_std: float = 0.0         # additive Gaussian noise, grey levels (0..255 scale)
    blur_sigma_px: float = 0.0     # Gaussian blur, image pixels; 0 = off
    exposure_gain_range: tuple[float, float] = (1.0, 1.0)   # per-frame gain drawn uniformly in [lo, hi]
    ground_window_px: int = 2048   # side of the textured ground window, in texels
    outside_grey_level: int = 128  # grey level of the ground outside the map
    latency_s: float = 0.05        # capture-to-publication delay; rendering overlaps the physics meanwhile
    render_in_worker: bool = True  # render in a separate process (pipelined with the simulation loop)
    relief: bool = True            # render the world's DSM (buildings, trees) when it has one; False = flat
    # Camera and mount realism (sitl.camera_model; docs/realism.md "Camera and mount" gives each
    # magnitude and its source). Every one is off at its default: the image is then the ideal one.
    distortion_k1_k2_p1_p2: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # Brown-Conrady, OpenCV order
    exposure_time_s: float = 0.0   # shutter open time: motion blur from the true motion; 0 = no blur
    auto_exposure_time_constant_s: float = 0.0   # auto-exposure lag (first order); 0 = no auto-exposure
    auto_exposure_target_grey: float = 118.0     # mean grey level the auto-exposure steers to (0..255)
    auto_exposure_gain_noise_std: float = 0.0    # relative gain noise per frame (0.01 = 1 %)
    jpeg_quality: int = 0          # JPEG compression at this quality (1..100); 0 = raw pixels
    capture_jitter_std_s: float = 0.0   # true exposure instant minus the nominal capture tick, std
    clock_offset_s: float = 0.0    # camera clock minus simulator (IMU) clock: added to timestamp_us
    gimbal_time_constant_s: float = 0.0   # GIMBAL: stabiliser lag (first order); 0 = ideal gimbal
    gimbal_bias_roll_pitch_deg: tuple[float, float] = (0.0, 0.0)   # GIMBAL: constant pointing error
    gimbal_noise_std_deg: float = 0.0     # GIMBAL: pointing noise per frame, each of roll and pitch

    def __post_init__(self) -> None:
        check(isinstance(self.width_px, int) and 8 <= self.width_px <= 4096, "width_px",
              self.width_px, "an integer in [8, 4096]")
        check(isinstance(self.height_px, int) and 8 <= self.height_px <= 4096, "height_px",
              self.height_px, "an integer in [8, 4096]")
        check(_finite(self.fov_deg) and 1.0 <= self.fov_deg <= 150.0, "fov_deg", self.fov_deg,
              "a number in [1, 150] degrees")
        check(_positive(self.rate_hz), "rate_hz", self.rate_hz, "a number > 0")
        check(isinstance(self.mount, CameraMount), "mount", self.mount,
              "one of " + ", ".join(m.value for m in CameraMount))
        check(_non_negative(self.noise_std), "noise_std", self.noise_std, "a number >= 0")
        check(_non_negative(self.blur_sigma_px) and self.blur_sigma_px <= 20.0, "blur_sigma_px",
              self.blur_sigma_px, "a number in [0, 20]")
        lo_hi = self.exposure_gain_range
        check(len(lo_hi) == 2 and all(_positive(g) for g in lo_hi) and lo_hi[0] <= lo_hi[1],
              "exposure_gain_range", lo_hi, "two numbers 0 < lo <= hi")
        check(isinstance(self.ground_window_px, int) and 64 <= self.ground_window_px <= 8192,
              "ground_window_px", self.ground_window_px, "an integer in [64, 8192]")
        check(isinstance(self.outside_grey_level, int) and 0 <= self.outside_grey_level <= 255,
              "outside_grey_level", self.outside_grey_level, "an integer in [0, 255]")
        check(_non_negative(self.latency_s) and self.latency_s <= 1.0, "latency_s", self.latency_s,
              "a number in [0, 1] seconds")
        check(isinstance(self.relief, bool), "relief", self.relief, "true or false")
        k = self.distortion_k1_k2_p1_p2
        check(len(k) == 4 and all(_finite(c) and abs(c) <= 1.0 for c in k), "distortion_k1_k2_p1_p2", k,
              "four numbers in [-1, 1] (Brown-Conrady k1, k2, p1, p2)")
        for name, hi in (("exposure_time_s", 0.1), ("auto_exposure_time_constant_s", 10.0),
                         ("auto_exposure_gain_noise_std", 0.5), ("capture_jitter_std_s", 0.05),
                         ("gimbal_time_constant_s", 2.0), ("gimbal_noise_std_deg", 10.0)):
            value = getattr(self, name)
            check(_non_negative(value) and value <= hi, name, value, f"a number in [0, {hi}]")
        check(_finite(self.auto_exposure_target_grey) and 1.0 <= self.auto_exposure_target_grey <= 254.0,
              "auto_exposure_target_grey", self.auto_exposure_target_grey, "a number in [1, 254]")
        check(isinstance(self.jpeg_quality, int) and 0 <= self.jpeg_quality <= 100, "jpeg_quality",
              self.jpeg_quality, "an integer in [0, 100] (0 = no compression)")
        check(_finite(self.clock_offset_s) and abs(self.clock_offset_s) <= 1.0, "clock_offset_s",
              self.clock_offset_s, "a number in [-1, 1] seconds")
        bias = self.gimbal_bias_roll_pitch_deg
        check(len(bias) == 2 and all(_finite(b) and abs(b) <= 10.0 for b in bias),
              "gimbal_bias_roll_pitch_deg", bias, "two numbers in [-10, 10] degrees")

    @property
    def optics_enabled(self) -> bool:
        """Any effect of ``sitl.camera_model`` on (the render worker applies them)."""
        return (any(c != 0.0 for c in self.distortion_k1_k2_p1_p2) or self.exposure_time_s > 0.0
                or self.auto_exposure_time_constant_s > 0.0 or self.capture_jitter_std_s > 0.0
                or (self.mount is CameraMount.GIMBAL and self.gimbal_enabled))

    @property
    def gimbal_enabled(self) -> bool:
        """The gimbal model is on (lag, bias or noise set)."""
        return (self.gimbal_time_constant_s > 0.0 or self.gimbal_noise_std_deg > 0.0
                or any(b != 0.0 for b in self.gimbal_bias_roll_pitch_deg))


@dataclass(frozen=True)
class BatteryConfig:
    """LiPo pack and power module (sitl.battery; constants and their sources in docs/simulator.md).

    Defaults: a 3S 3300 mAh pack (ArduPilot's default ``BATT_CAPACITY``), 0.01 ohm pack resistance
    (ArduPilot SITL ``SIM_Frame`` default model ``refBatRes``), current = idle + max * mean rotor
    speed fraction squared (about 21 A in an Iris hover; ArduPilot's default model: 22.7 A).
    """

    cells: int = 3                          # cells in series
    capacity_mah: float = 3300.0            # rated capacity
    initial_charge_fraction: float = 1.0    # state of charge at the start, 0..1
    internal_resistance_ohm: float = 0.01   # whole pack: terminal voltage = OCV - I R
    idle_current_a: float = 0.5             # avionics, rotors stopped
    max_current_a: float = 40.0             # extra current with every rotor at its maximum speed
    rate_hz: float = 10.0                   # PowerSample rate
    voltage_noise_std_v: float = 0.0        # power-module voltage noise per sample
    current_noise_std_a: float = 0.0        # power-module current noise per sample

    def __post_init__(self) -> None:
        check(isinstance(self.cells, int) and 1 <= self.cells <= 14, "cells", self.cells,
              "an integer in [1, 14]")
        check(_positive(self.capacity_mah), "capacity_mah", self.capacity_mah, "a number > 0")
        check(_finite(self.initial_charge_fraction) and 0.0 <= self.initial_charge_fraction <= 1.0,
              "initial_charge_fraction", self.initial_charge_fraction, "a number in [0, 1]")
        for name in ("internal_resistance_ohm", "idle_current_a", "max_current_a",
                     "voltage_noise_std_v", "current_noise_std_a"):
            value = getattr(self, name)
            check(_non_negative(value), name, value, "a number >= 0")
        check(_positive(self.rate_hz), "rate_hz", self.rate_hz, "a number > 0")


@dataclass(frozen=True)
class SimConfig:
    physics_rate_hz: float = 400.0
    wind: WindConfig = field(default_factory=WindConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    baro: BaroConfig = field(default_factory=BaroConfig)
    compass: CompassConfig = field(default_factory=CompassConfig)
    gps: GpsConfig = field(default_factory=GpsConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    battery: BatteryConfig = field(default_factory=BatteryConfig)

    def __post_init__(self) -> None:
        check(_finite(self.physics_rate_hz) and 50.0 <= self.physics_rate_hz <= 10000.0,
              "physics_rate_hz", self.physics_rate_hz, "a number in [50, 10000] Hz")


@dataclass(frozen=True)
class ScriptedFlight:
    """A kinematic flight (no autopilot) along a resolved route (sitl.scripted.ScriptedTrajectory)."""

    route_enu_m: tuple[tuple[float, float], ...]   # [x, y] waypoints, m (at least two)
    altitude_m: float = 100.0
    speed_m_s: float = 10.0
    turn_radius_m: float = 30.0

    def __post_init__(self) -> None:
        check(len(self.route_enu_m) >= 2, "route_enu_m", self.route_enu_m,
              "at least two [x, y] waypoints in metres")
        check(_positive(self.altitude_m), "altitude_m", self.altitude_m, "a number > 0")
        check(_positive(self.speed_m_s), "speed_m_s", self.speed_m_s, "a number > 0")
        check(_non_negative(self.turn_radius_m), "turn_radius_m", self.turn_radius_m, "a number >= 0")


@dataclass(frozen=True)
class SimNodeConfig:
    """Everything the simulator node needs, resolved by the app layer (scenenav.app.nodes.run_sim)."""

    sim: SimConfig = field(default_factory=SimConfig)
    clock: ClockConfig = field(default_factory=ClockConfig)
    duration_s: float = 90.0               # simulated seconds at most
    seed: int = 0
    scripted: ScriptedFlight | None = None   # None: the vehicle flies on the motor commands
    start_enu_m: tuple[float, float] = (0.0, 0.0)   # not scripted: start on the ground here
    start_heading_deg: float = 0.0         # compass, clockwise from north
    end_with_mission: bool = False         # stop once the autopilot reports its mission done and landed
    expected_tick_members: int = 0         # lockstep members to wait for at the start
    expected_camera_members: int = 0

    def __post_init__(self) -> None:
        check(_positive(self.duration_s), "duration_s", self.duration_s, "a number of seconds > 0")
        check(isinstance(self.seed, int) and self.seed >= 0, "seed", self.seed,
              "a non-negative integer")
        check(self.expected_tick_members >= 0 and self.expected_camera_members >= 0,
              "expected_tick_members", (self.expected_tick_members, self.expected_camera_members),
              "counts >= 0")
        check_camera_answer_ticks(self.clock, self.sim.camera)


def check_camera_answer_ticks(clock: ClockConfig, camera: CameraConfig) -> None:
    """``clock.camera_answer_ticks`` must be fewer than the control ticks between two camera frames
    (a frame's answer is waited for before the next frame goes out); ConfigError otherwise."""
    frame_ticks = max(1, round(clock.tick_rate_hz / camera.rate_hz))
    check(clock.camera_answer_ticks < frame_ticks, "clock.camera_answer_ticks", clock.camera_answer_ticks,
          f"fewer than the {frame_ticks} control ticks between two camera frames")
