"""Configuration of the autopilot: its node section (``AutopilotNodeConfig``, the scenario's
``autopilot:``) and its pure algorithms (navigation filter, controllers, guidance).

Every config is a frozen dataclass whose field names carry their unit; range checks raise
``scenenav.core.config.ConfigError`` through ``scenenav.core.config.check``. Where a value mirrors an ArduPilot
parameter the comment names it, with the ArduPilot default converted to SI units (ArduPilot stores many
of these in cm, cm/s or centidegrees). The node maps ArduPilot parameter names onto these fields; the
full table is in ``docs/autopilot-control.md``.

Units used in names: ``_m``, ``_m_s`` (m/s), ``_m_s2`` (m/s^2), ``_rad``, ``_rad_s`` (rad/s), ``_deg``,
``_deg_s``, ``_s``, ``_hz``; ``_1_s`` and ``_1_s2`` are gains in 1/s and 1/s^2; ``_unitless`` is a
dimensionless gain; ``_per_rt_hz`` marks a continuous-time noise spectral density (unit per sqrt(Hz)).
"""

from __future__ import annotations

import ipaddress
import math
import socket
from dataclasses import dataclass, field
from enum import Enum, IntEnum

from autopilot_bridge.airframe import STANDARD_GRAVITY_M_S2
from autopilot_bridge.param_specs import PARAM_NAMES
from scenenav.core.config import check


class PositionSource(IntEnum):
    """Horizontal position source of the navigation filter; values are ArduPilot's EK3_SRC1_POSXY."""

    NONE = 0
    GPS = 3
    EXTNAV = 6


class YawBehaviour(IntEnum):
    """Heading during waypoint following; values are ArduPilot's WP_YAW_BEHAVIOR (subset)."""

    NEVER_CHANGE = 0
    FACE_NEXT_WAYPOINT = 1


def _positive(value: float) -> bool:
    return math.isfinite(value) and value > 0.0


def _non_negative(value: float) -> bool:
    return math.isfinite(value) and value >= 0.0


@dataclass(frozen=True)
class EkfConfig:
    """Navigation filter (18-state error-state EKF) noise, gates and limits."""

    # --- process noise: continuous-time spectral densities (variance added per predict = density^2 * dt)
    # Gyro white noise; ArduPilot EK3_GYRO_P_NSE is the per-step equivalent (0.015 rad/s).
    gyro_noise_rad_s_per_rt_hz: float = 0.001
    # Accelerometer white noise; set from EK3_ACC_P_NSE (per-step, default 0.2 m/s^2; ArduPilot's
    # 0.35) in a flight (param_binding.accel_noise_density).
    accel_noise_m_s2_per_rt_hz: float = 0.02
    # Gyro bias random walk; set from ArduPilot EK3_GBIAS_P_NSE (default 0.001 rad/s^2 per step:
    # param_binding.gyro_bias_noise_density) in a flight.
    gyro_bias_noise_rad_s2_per_rt_hz: float = 1.0e-4
    # Accelerometer bias random walk; ArduPilot EK3_ABIAS_P_NSE (0.02 m/s^3) per step.
    accel_bias_noise_m_s3_per_rt_hz: float = 2.0e-3

    # --- measurement noise (floors; the caller's own std/covariance is used when larger)
    baro_noise_m: float = 0.4               # EK3_ALT_M_NSE (ArduPilot default 2 m; our baro ~0.3 m)
    compass_noise_rad: float = 0.03         # EK3_YAW_M_NSE (set from the parameter in a flight; ArduPilot's default 0.5 rad)
    # The compass heading's bias state (NavFilter.set_compass_bias_model; SN_MAG_BIAS_SD, SN_MAG_BIAS_TURN):
    # the prior 1-sigma and cap of the bias (0 = no bias state, the heading fused as white noise), how
    # much it may change per radian turned (1-sigma over one radian; variance grows with the angle), and
    # a slow random walk in time (the motor-current term with throttle, anomalies with position: under
    # realism: realistic about 0.1 deg over a minute of level flight, docs/realism.md "The compass's bias").
    compass_bias_std_rad: float = 0.0
    compass_bias_turn_std_rad: float = 0.07
    compass_bias_noise_rad_per_rt_s: float = 1.0e-3
    gps_position_noise_min_m: float = 0.3   # EK3_POSNE_M_NSE (0.5 m) used as a floor
    gps_velocity_noise_min_m_s: float = 0.1  # EK3_VELNE_M_NSE (0.3 m/s) used as a floor
    vision_position_noise_min_m: float = 0.3  # floor on sqrt of each vision covariance diagonal

    # --- innovation gates, in standard deviations (ArduPilot *_I_GATE is in percent of an SD: 500 = 5 SD)
    position_gate_sd: float = 5.0   # EK3_POS_I_GATE 500 (set from the parameter in a flight)
    velocity_gate_sd: float = 5.0   # EK3_VEL_I_GATE 500
    height_gate_sd: float = 5.0     # EK3_HGT_I_GATE 500
    heading_gate_sd: float = 3.0    # EK3_YAW_I_GATE 300
    # When every fix of the selected position source has been rejected for this long, the position is
    # reset to the source (a reported jump); same for the barometer height.
    position_reject_timeout_s: float = 5.0
    # A reset onto vision (EXTNAV) fixes larger than this is refused: the fixes stay rejected and the
    # timeout restarts (SN_VIS_RST_MAX; 0 = no limit, ArduPilot's behaviour).
    vision_reset_max_m: float = 0.0
    height_reject_timeout_s: float = 5.0
    heading_reject_timeout_s: float = 5.0
    velocity_reject_timeout_s: float = 2.0

    # --- initial uncertainty (1 sigma)
    initial_position_std_m: float = 0.5       # when a position (home or GPS) is given at initialise
    unknown_position_std_m: float = 1000.0    # when none is given
    initial_velocity_std_m_s: float = 0.2
    # Tilt error of the levelling at rest beyond the horizontal accelerometer bias, which the levelling
    # absorbs (initialise correlates the two: the tilt 1-sigma is sqrt(this^2 + (accel bias std / g)^2)).
    initial_tilt_std_rad: float = 0.002
    initial_tilt_moving_std_rad: float = 0.02   # aligned in the air (initialise(at_rest=False))
    initial_heading_std_rad: float = 0.05
    initial_gyro_bias_std_rad_s: float = 0.01    # gyro bias unknown (no average rate at rest given)
    aligned_gyro_bias_std_rad_s: float = 0.001   # gyro bias seeded from the average rate at rest
    initial_accel_bias_std_m_s2: float = 0.2

    # --- limits and health
    max_gyro_bias_rad_s: float = 0.2
    max_accel_bias_m_s2: float = 2.0
    max_position_std_m: float = 1.0e4         # variance clamp: dead reckoning stops growing here
    max_velocity_std_m_s: float = 100.0
    velocity_ok_max_std_m_s: float = 2.0      # velocity_ok() threshold (horizontal 1-sigma)
    healthy_max_tilt_std_rad: float = 0.1     # is_healthy() threshold on the tilt 1-sigma
    position_ok_max_std_m: float = 10.0       # position_ok() threshold (horizontal 1-sigma)
    # gyro_bias_learned(): the body x, y gyro-bias 1-sigma within this factor of the steady state the
    # zero-rate update at rest converges to, sqrt(gyro noise density * gyro bias random walk) (3.2e-4
    # rad/s with the defaults); 1.2 is reached ~8 s after the 1 s alignment. The pre-arm check of a
    # dead-reckoned climb (issue 12): ArduPilot's EKF3 likewise waits for its delta-angle bias
    # variances before it uses GPS or beacons (checkGyroCalStatus / delAngBiasLearned).
    learned_gyro_bias_ratio: float = 1.2

    # --- drag fusion (ArduPilot EKF3 FuseDragForces, EK3_DRAG_*): the body x, y specific force of a
    # multicopter is the air's drag alone (thrust is along body z), a measurement of the velocity
    # relative to the air, hence of the wind (two more states). Off while both coefficients are 0.
    drag_ballistic_coef_x_kg_m2: float = 0.0   # EK3_DRAG_BCOEF_X: mass / (Cd A) along body x; 0 = no term
    drag_ballistic_coef_y_kg_m2: float = 0.0   # EK3_DRAG_BCOEF_Y
    drag_momentum_coef_per_s: float = 0.0      # EK3_DRAG_MCOEF: rotor drag acceleration per m/s of air
    drag_noise_m_s2: float = 0.5               # EK3_DRAG_M_NSE: noise of the averaged specific force
    # Wind random walk (ArduPilot EK3_WIND_P_NSE 0.2 m/s^2 per step: param_binding.process_noise_density)
    wind_noise_m_s2_per_rt_hz: float = 0.02
    initial_wind_std_m_s: float = 10.0         # wind unknown when drag fusion starts
    air_density_kg_m3: float = 1.225           # ISA sea level (ArduPilot scales with the baro's EAS2TAS)

    position_source: PositionSource = PositionSource.GPS   # EK3_SRC1_POSXY
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2

    @property
    def drag_fusion(self) -> bool:
        """Drag fusion is on: a ballistic or a momentum coefficient is set."""
        return (self.drag_ballistic_coef_x_kg_m2 > 0.0 or self.drag_ballistic_coef_y_kg_m2 > 0.0
                or self.drag_momentum_coef_per_s > 0.0)

    def __post_init__(self) -> None:
        for name in ("gyro_noise_rad_s_per_rt_hz", "accel_noise_m_s2_per_rt_hz",
                     "gyro_bias_noise_rad_s2_per_rt_hz", "accel_bias_noise_m_s3_per_rt_hz",
                     "baro_noise_m", "compass_noise_rad", "gps_position_noise_min_m",
                     "gps_velocity_noise_min_m_s", "vision_position_noise_min_m",
                     "initial_position_std_m", "unknown_position_std_m", "initial_velocity_std_m_s",
                     "initial_tilt_std_rad", "initial_tilt_moving_std_rad", "initial_heading_std_rad",
                     "initial_gyro_bias_std_rad_s", "aligned_gyro_bias_std_rad_s",
                     "initial_accel_bias_std_m_s2", "max_gyro_bias_rad_s", "max_accel_bias_m_s2",
                     "max_position_std_m", "max_velocity_std_m_s", "velocity_ok_max_std_m_s",
                     "healthy_max_tilt_std_rad", "position_ok_max_std_m", "gravity_m_s2",
                     "position_reject_timeout_s", "height_reject_timeout_s", "heading_reject_timeout_s",
                     "velocity_reject_timeout_s", "drag_noise_m_s2", "wind_noise_m_s2_per_rt_hz",
                     "initial_wind_std_m_s", "air_density_kg_m3"):
            value = getattr(self, name)
            check(_positive(value), name, value, "a positive number")
        for name in ("drag_ballistic_coef_x_kg_m2", "drag_ballistic_coef_y_kg_m2", "drag_momentum_coef_per_s",
                     "vision_reset_max_m", "compass_bias_std_rad", "compass_bias_turn_std_rad",
                     "compass_bias_noise_rad_per_rt_s"):
            value = getattr(self, name)
            check(_non_negative(value), name, value, "a number >= 0 (0 = off)")
        check(math.isfinite(self.learned_gyro_bias_ratio) and self.learned_gyro_bias_ratio > 1.0,
              "learned_gyro_bias_ratio", self.learned_gyro_bias_ratio, "a number > 1")
        for name in ("position_gate_sd", "velocity_gate_sd", "height_gate_sd", "heading_gate_sd"):
            value = getattr(self, name)
            check(math.isfinite(value) and 1.0 <= value <= 100.0, name, value,
                  "a gate between 1 and 100 standard deviations")
        check(self.position_source in (PositionSource.GPS, PositionSource.EXTNAV, PositionSource.NONE),
              "position_source", self.position_source, "0 (none), 3 (GPS) or 6 (EXTNAV)")


@dataclass(frozen=True)
class ControlConfig:
    """Cascaded position / velocity / attitude / rate controller gains and limits.

    The rate loop outputs an angular-acceleration demand that is multiplied by the vehicle inertia, so the
    gains are physical (1/s) rather than ArduPilot's throttle-normalised ATC_RAT_* values.
    """

    # --- horizontal position and velocity (PSC_*)
    pos_xy_p_1_s: float = 1.0            # PSC_POSXY_P: velocity (m/s) per metre of error
    vel_xy_p_1_s: float = 2.0            # PSC_VELXY_P: acceleration (m/s^2) per m/s of error
    vel_xy_i_1_s2: float = 1.0           # PSC_VELXY_I: acceleration per (m/s * s) of integrated error
    vel_xy_d_unitless: float = 0.25      # PSC_VELXY_D (0.5): acceleration per (m/s^2) of error rate
    vel_xy_imax_m_s2: float = 4.0        # PSC_VELXY_IMAX (1000 cm/s^2, reduced)
    vel_xy_d_filter_hz: float = 5.0      # PSC_VELXY_FLTD
    max_speed_xy_m_s: float = 10.0       # WPNAV_SPEED (1000 cm/s); also LOIT_SPEED cap of corrections
    max_accel_xy_m_s2: float = 5.0       # horizontal acceleration cap (further limited by the lean angle)
    # --- vertical position and velocity
    pos_z_p_1_s: float = 1.0             # PSC_POSZ_P
    vel_z_p_1_s: float = 5.0             # PSC_VELZ_P
    vel_z_i_1_s2: float = 2.0            # integral on vertical velocity (ArduPilot: PSC_ACCZ_I on accel)
    vel_z_imax_m_s2: float = 5.0         # vertical integrator limit
    max_climb_m_s: float = 2.5           # PILOT_SPEED_UP / WPNAV_SPEED_UP (250 cm/s)
    max_descent_m_s: float = 1.5         # PILOT_SPEED_DN / WPNAV_SPEED_DN (150 cm/s)
    max_accel_z_m_s2: float = 2.5        # PSC_ACCZ limit used by the vertical sqrt controller
    # --- attitude (ATC_*)
    max_lean_angle_deg: float = 30.0     # ANGLE_MAX (3000 cdeg)
    ang_rp_p_1_s: float = 4.5            # ATC_ANG_RLL_P / ATC_ANG_PIT_P: rad/s per rad of error
    ang_yaw_p_1_s: float = 4.5           # ATC_ANG_YAW_P
    max_rate_rp_deg_s: float = 200.0     # ATC_RATE_R_MAX / ATC_RATE_P_MAX
    max_rate_yaw_deg_s: float = 60.0     # ATC_RATE_Y_MAX; also the heading-target slew (ATC_SLEW_YAW)
    # --- body rate PID: output is angular acceleration (rad/s^2), multiplied by the inertia
    rate_rp_p_1_s: float = 14.0          # (rad/s^2) per (rad/s)
    rate_rp_i_1_s2: float = 10.0         # (rad/s^2) per rad of integrated rate error
    rate_rp_d_unitless: float = 0.1      # (rad/s^2) per (rad/s^2)
    rate_rp_imax_rad_s2: float = 10.0
    rate_yaw_p_1_s: float = 6.0
    rate_yaw_i_1_s2: float = 2.0
    rate_yaw_imax_rad_s2: float = 3.0
    rate_d_filter_hz: float = 20.0       # ATC_RAT_*_FLTD
    # --- thrust
    thrust_max_fraction: float = 0.95    # collective thrust cap as a fraction of the vehicle's max thrust
    thrust_min_fraction: float = 0.05    # collective thrust floor in flight (MOT_SPIN_MIN-like)
    max_tilt_compensation_deg: float = 60.0  # 1/cos(tilt) thrust boost stops growing past this tilt
    # --- landing / takeoff detection (ArduCopter land detector)
    land_detect_thrust_fraction: float = 0.8     # thrust demand below this fraction of hover thrust...
    land_detect_max_speed_z_m_s: float = 0.25    # ...and vertical speed below this...
    land_detect_max_speed_xy_m_s: float = 1.0    # ...and horizontal speed below this...
    land_detect_time_s: float = 1.0              # ...for this long (LAND_DETECTOR_TRIGGER_SEC)
    takeoff_min_climb_m_s: float = 0.5           # a climb target above this leaves the landed state

    def __post_init__(self) -> None:
        for name in ("pos_xy_p_1_s", "vel_xy_p_1_s", "max_speed_xy_m_s", "max_accel_xy_m_s2",
                     "pos_z_p_1_s", "vel_z_p_1_s", "max_climb_m_s", "max_descent_m_s",
                     "max_accel_z_m_s2", "ang_rp_p_1_s", "ang_yaw_p_1_s", "max_rate_rp_deg_s",
                     "max_rate_yaw_deg_s", "rate_rp_p_1_s", "rate_yaw_p_1_s", "rate_d_filter_hz",
                     "vel_xy_d_filter_hz", "land_detect_max_speed_z_m_s", "land_detect_max_speed_xy_m_s",
                     "land_detect_time_s", "takeoff_min_climb_m_s"):
            value = getattr(self, name)
            check(_positive(value), name, value, "a positive number")
        for name in ("vel_xy_i_1_s2", "vel_xy_d_unitless", "vel_xy_imax_m_s2", "vel_z_i_1_s2",
                     "vel_z_imax_m_s2", "rate_rp_i_1_s2", "rate_rp_d_unitless", "rate_rp_imax_rad_s2",
                     "rate_yaw_i_1_s2", "rate_yaw_imax_rad_s2"):
            value = getattr(self, name)
            check(_non_negative(value), name, value, "a number >= 0")
        check(math.isfinite(self.max_lean_angle_deg) and 5.0 <= self.max_lean_angle_deg <= 70.0,
              "max_lean_angle_deg", self.max_lean_angle_deg, "an angle between 5 and 70 degrees")
        check(math.isfinite(self.max_tilt_compensation_deg) and 0.0 <= self.max_tilt_compensation_deg < 80.0,
              "max_tilt_compensation_deg", self.max_tilt_compensation_deg, "an angle in [0, 80) degrees")
        check(0.0 < self.thrust_max_fraction <= 1.0, "thrust_max_fraction", self.thrust_max_fraction,
              "a fraction in (0, 1]")
        check(0.0 <= self.thrust_min_fraction < self.thrust_max_fraction, "thrust_min_fraction",
              self.thrust_min_fraction, "a fraction in [0, thrust_max_fraction)")
        check(0.0 < self.land_detect_thrust_fraction < 1.0, "land_detect_thrust_fraction",
              self.land_detect_thrust_fraction, "a fraction in (0, 1)")

    @property
    def max_lean_angle_rad(self) -> float:
        return math.radians(self.max_lean_angle_deg)


@dataclass(frozen=True)
class GuidanceConfig:
    """Waypoint following, takeoff, RTL and LAND (WPNAV_*, RTL_*, LAND_*)."""

    wp_speed_m_s: float = 10.0          # WPNAV_SPEED (1000 cm/s)
    wp_speed_up_m_s: float = 2.5        # WPNAV_SPEED_UP (250 cm/s)
    wp_speed_down_m_s: float = 1.5      # WPNAV_SPEED_DN (150 cm/s)
    wp_accel_m_s2: float = 2.5          # WPNAV_ACCEL (250 cm/s^2)
    wp_accel_z_m_s2: float = 1.0        # WPNAV_ACCEL_Z (100 cm/s^2)
    wp_radius_m: float = 2.0            # WPNAV_RADIUS (200 cm)
    wp_leash_m: float = 5.0             # how far the target may run ahead of the vehicle along the track
    yaw_behaviour: YawBehaviour = YawBehaviour.FACE_NEXT_WAYPOINT   # WP_YAW_BEHAVIOR
    min_yaw_leg_m: float = 5.0          # legs shorter than this (horizontally) keep the current heading
    takeoff_speed_m_s: float = 2.5      # PILOT_SPEED_UP / WPNAV_SPEED_UP for takeoff climbs
    takeoff_radius_m: float = 0.5       # takeoff complete within this distance of the target altitude
    rtl_alt_m: float = 15.0             # RTL_ALT (1500 cm), above home
    rtl_loiter_s: float = 5.0           # RTL_LOIT_TIME (5000 ms)
    rtl_climb_min_m: float = 0.0        # RTL_CLIMB_MIN (0 cm): RTL climbs at least this much
    rtl_cone_slope: float = 3.0         # RTL_CONE_SLOPE (3.0): climb limited to slope x distance home
    land_speed_m_s: float = 0.5         # LAND_SPEED (50 cm/s), final descent
    land_speed_high_m_s: float = 0.0    # LAND_SPEED_HIGH (0: use wp_speed_down_m_s)
    land_alt_low_m: float = 10.0        # LAND_ALT_LOW (1000 cm): switch to land_speed_m_s below this

    def __post_init__(self) -> None:
        for name in ("wp_speed_m_s", "wp_speed_up_m_s", "wp_speed_down_m_s", "wp_accel_m_s2",
                     "wp_accel_z_m_s2", "wp_radius_m", "wp_leash_m", "takeoff_speed_m_s",
                     "takeoff_radius_m", "land_speed_m_s"):
            value = getattr(self, name)
            check(_positive(value), name, value, "a positive number")
        for name in ("min_yaw_leg_m", "rtl_alt_m", "rtl_loiter_s", "land_speed_high_m_s", "land_alt_low_m",
                     "rtl_climb_min_m", "rtl_cone_slope"):
            value = getattr(self, name)
            check(_non_negative(value), name, value, "a number >= 0")
        check(self.wp_speed_m_s <= 50.0, "wp_speed_m_s", self.wp_speed_m_s, "at most 50 m/s")


@dataclass(frozen=True)
class AutopilotAlgorithmsConfig:
    """Everything the pure autopilot algorithms need, for the node to embed in its own config."""

    ekf: EkfConfig = field(default_factory=EkfConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    guidance: GuidanceConfig = field(default_factory=GuidanceConfig)
    control_rate_hz: float = 100.0      # controller / IMU tick rate

    def __post_init__(self) -> None:
        check(_positive(self.control_rate_hz) and self.control_rate_hz <= 2000.0, "control_rate_hz",
              self.control_rate_hz, "a rate in (0, 2000] Hz")


@dataclass(frozen=True)
class FlightCoreConfig:
    """Where the vehicle is and how the core treats its inputs (not ArduPilot parameters)."""

    origin_lat_deg: float = 0.0           # geodetic position of the world origin (ENU 0, 0)
    origin_lon_deg: float = 0.0
    origin_alt_amsl_m: float = 0.0        # AMSL altitude of the ground plane (ENU z = 0)
    start_enu_m: tuple[float, float] = (0.0, 0.0)   # known take-off point (home without GPS)
    ground_z_m: float = 0.0               # ENU height of the ground under the take-off point
    align_time_s: float = 1.0             # samples averaged at rest before the EKF is aligned
    gps_wait_s: float = 5.0               # with GPS as source: wait this long for fixes to align
    gps_velocity_std_m_s: float = 0.2     # GPS velocity accuracy (GpsSample carries none)
    ground_position_std_m: float = 0.3    # on-ground pseudo position fix without a source
    ground_fusion_period_s: float = 0.2
    # Drag fusion (EK3_DRAG_*): the specific force averaged over this window of flight per fusion (ArduPilot
    # EKF3 likewise averages the drag between fusions, at most one per EKF step of ~10 ms: its rate here)
    drag_fusion_period_s: float = 0.1
    ext_nav_std_m: float = 0.5            # MAVLink external nav without a covariance
    ext_nav_fresh_s: float = 1.0          # MAVLink external nav counts as a source this long
    vision_max_age_s: float = 1.0         # older vision fixes are dropped
    # A vision fix wider than SN_VIS_MAX_SD is fused at most once per this interval (the others count
    # as fixes for the vision failsafe only): an ambiguous match's error repeats from frame to frame
    # (scene-matching fix errors stay correlated 0.2-0.35 over 10 s, docs/realism.md), so ten a second
    # carry hardly more than one; 5 s, the order of that correlation time
    wide_vision_fix_interval_s: float = 5.0
    # SN_VIS_WIDE_SD: a wide fix is fused with that 1-sigma when it lies within this many of the
    # combined sigmas (estimate and SN_VIS_WIDE_SD) of the estimate: 3, tighter than the EKF's own
    # 5-sigma position gate (EK3_POS_I_GATE 500), because the fix's own width is set aside
    wide_vision_narrow_gate_sd: float = 3.0
    # ArduPilot EKF3's final in-flight yaw alignment: the heading is reset to the compass once per
    # flight at this height above home (EKF3_MAG_FINAL_RESET_ALT 2.5 m, AP_NavEKF3_core.h); 0 = off
    inflight_yaw_reset_height_m: float = 2.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.inflight_yaw_reset_height_m) and self.inflight_yaw_reset_height_m >= 0):
            raise ValueError(f"FlightCoreConfig.inflight_yaw_reset_height_m = "
                             f"{self.inflight_yaw_reset_height_m!r}: expected >= 0 (0 = off)")
        for name in ("align_time_s", "gps_wait_s", "gps_velocity_std_m_s", "ground_position_std_m",
                     "ground_fusion_period_s", "drag_fusion_period_s", "ext_nav_std_m", "ext_nav_fresh_s",
                     "vision_max_age_s", "wide_vision_fix_interval_s", "wide_vision_narrow_gate_sd"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"FlightCoreConfig.{name} = {value!r}: expected > 0")



# ------------------------------------------------------------------------------- node section


class MissionEndMode(str, Enum):
    """What an autopilot flight does after the last route waypoint."""

    LAND = "land"    # land at the last waypoint
    RTL = "rtl"      # return to the take-off point and land there


UDP_OUT_OFF = ("none", "off", "0", "")


def parse_udp_out(text: str) -> tuple[str, int] | None:
    """``HOST:PORT`` -> (host, port); None for off (``UDP_OUT_OFF``). ValueError when malformed."""
    if text.lower() in UDP_OUT_OFF:
        return None
    host, sep, port = text.rpartition(":")
    if not (sep and host and port.isdigit() and 0 < int(port) <= 65535):
        raise ValueError(f"not HOST:PORT: {text!r}")
    return host, int(port)


def udp_bind_host_for(target_host: str) -> str:
    """Where the UDP socket binds to reach ``target_host``: 127.0.0.1 for a loopback target, else
    0.0.0.0 (a socket bound to 127.0.0.1 cannot send to another machine: the kernel refuses with
    EINVAL). A name that does not resolve binds 0.0.0.0 too."""
    try:
        address = socket.gethostbyname(target_host)
    except OSError:
        return "0.0.0.0"
    return "127.0.0.1" if ipaddress.IPv4Address(address).is_loopback else "0.0.0.0"


def _ipv4_ok(text: str) -> bool:
    try:
        ipaddress.IPv4Address(text)
    except ValueError:
        return False
    return True


def _udp_out_ok(text: str) -> bool:
    try:
        parse_udp_out(text)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class AutopilotNodeConfig:
    """The scenario's ``autopilot:`` section (the autopilot node)."""

    mavlink_tcp_port: int = 5760       # MAVLink TCP server port (0 = off)
    # the address the MAVLink TCP server binds: 127.0.0.1 (this machine only); 0.0.0.0 or an
    # interface's address lets a ground station on another machine connect (docs/mavlink.md)
    mavlink_tcp_host: str = "127.0.0.1"
    mavlink_udp_out: str = "127.0.0.1:14550"   # MAVLink UDP output HOST:PORT, or none
    auto_start: bool = True            # autopilot flights: arm and start AUTO once the EKF is aligned
    mission_end: MissionEndMode = MissionEndMode.LAND   # autopilot flights: after the last waypoint
    params_file: str = ""              # JSON {"NAME": value} of ArduPilot parameters set at start
    vision_wait_s: float = 5.0         # lockstep: wall seconds to wait for the fix of an acked frame
    estimate_rate_hz: float = 20.0     # autopilot/estimate rate (simulated time)
    params: dict[str, float] = field(default_factory=dict)   # ArduPilot parameters {NAME: value}, after params_file
    params_store: str = ""             # parameter file kept between runs, like ArduPilot's eeprom.bin: the set parameters, over the defaults ("" = none; scenenav sitl sets it)

    def __post_init__(self) -> None:
        check(0 <= self.mavlink_tcp_port <= 65535, "mavlink_tcp_port", self.mavlink_tcp_port,
              "a TCP port 1..65535, or 0 for off")
        check(_ipv4_ok(self.mavlink_tcp_host), "mavlink_tcp_host", self.mavlink_tcp_host,
              "an IPv4 address: 127.0.0.1 (this machine only), 0.0.0.0 (every interface) or one "
              "interface's address")
        check(_udp_out_ok(self.mavlink_udp_out), "mavlink_udp_out", self.mavlink_udp_out,
              "HOST:PORT (e.g. 127.0.0.1:14550), or none")
        check(self.vision_wait_s >= 0, "vision_wait_s", self.vision_wait_s, ">= 0 s")
        check(0 < self.estimate_rate_hz <= 1000, "estimate_rate_hz", self.estimate_rate_hz,
              "0 to 1000 Hz")
        unknown = sorted(set(self.params) - PARAM_NAMES)
        check(not unknown, "params", unknown, "ArduCopter parameter names the autopilot knows "
              "(docs/mavlink.md lists them)")

    @property
    def udp_target(self) -> tuple[str, int] | None:
        """``mavlink_udp_out`` as (host, port), or None when off."""
        return parse_udp_out(self.mavlink_udp_out)


@dataclass(frozen=True)
class RouteMission:
    """A route the autopilot flies by itself as an AUTO mission once its EKF is aligned."""

    route_enu_m: tuple[tuple[float, float], ...]
    altitude_m: float                  # above home

    def __post_init__(self) -> None:
        check(len(self.route_enu_m) > 0, "route_enu_m", self.route_enu_m, "at least one waypoint")
        check(_positive(self.altitude_m), "altitude_m", self.altitude_m, "> 0 m")


@dataclass(frozen=True)
class AutopilotSetup:
    """Everything the autopilot node needs for one run. The app layer derives it from the scenario
    (``scenenav.app.nodes.autopilot_setup``); the node never reads the scenario itself."""

    node: AutopilotNodeConfig = field(default_factory=AutopilotNodeConfig)
    core: FlightCoreConfig = field(default_factory=FlightCoreConfig)   # world origin, take-off point
    position_source: PositionSource = PositionSource.GPS   # EXTNAV when the vehicle has no GPS
    mission: RouteMission | None = None    # None: a ground station or the guidance node flies
    mission_ends_run: bool = False         # AutopilotStatus.mission_complete reports the mission
