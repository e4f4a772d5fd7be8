"""Realism profiles: one scenario key (``realism: ideal | paper | realistic``) selects a bundle of
settings; every single key of the scenario (and every ``--set``) still wins over the bundle.

A profile is typed data: an ordered mapping from dotted scenario keys to values, exactly what a
``--set KEY=VALUE`` would give. ``realistic`` is ``paper`` plus its own entries, so a key set in
both takes the ``realistic`` value. Adding a setting to a profile is one line in the tables below.
Every value, its magnitude and its literature or datasheet basis: docs/realism.md.

Layering (lowest first): the dataclass defaults, the profile, the scenario file, ``--set``.
"""

from __future__ import annotations

from enum import Enum
from types import MappingProxyType
from typing import Any, Mapping

from scenenav.core.config import set_dotted
from scenenav.core.errors import UserError
from sitl.camera_model import REALISTIC_CAMERA


class Realism(str, Enum):
    IDEAL = "ideal"             # today's world and sensors (old figures stay reproducible)
    PAPER = "paper"             # the paper's set-up as far as it is stated, ArduPilot-SITL-like sensors
    REALISTIC = "realistic"     # paper + the error sources of a real flight


#: ``paper``: section 6 of the seed paper (3-D city, reference from 500 m, an Iris flown by the
#: autopilot at 100 m and 10 m/s, camera looking down) and ArduPilot SITL's default sensor noise.
PAPER_SETTINGS: Mapping[str, Any] = MappingProxyType({
    # world and flight
    "sim.camera.relief": True,                   # the 3-D city (DSM rendered in perspective)
    "perception.reference": "perspective",       # the reference taken from 500 m (issue 11)
    "flight.mode": "autopilot",                  # the Iris flown by the autopilot ...
    "flight.altitude_m": 100.0,                  # ... at 100 m
    "flight.speed_m_s": 10.0,                    # ... and 10 m/s
    # camera looking down (seed paper section 5: "a down-looking camera"), an ideal lens
    "sim.camera.mount": "gimbal",
    # sensors: ArduPilot SITL defaults (libraries/SITL/SITL.cpp, SITL_Baro.cpp, SIM_GPS.cpp)
    "sim.baro.noise_std_m": 0.2,                 # SIM_BARO_RND default 0.2 m
    "sim.gps.rate_hz": 5.0,                      # SIM_GPS1_HZ default 5 Hz
    "sim.gps.horizontal_noise_std_m": 0.3,       # SIM_GPS1_ACC default 0.3 m (reported accuracy)
    "sim.gps.vertical_noise_std_m": 0.3,         # SIM_GPS1_ACC
    "sim.gps.satellites": 10,                    # SIM_GPS1_NUMSATS default 10
    # IMU white noise: AP_InertialSensor_SITL's base noise with SIM_ACC1_RND = SIM_GYR1_RND = 0 (the
    # defaults): uniform +-0.01 m/s^2 and +-0.04 deg/s per 1 kHz sample (std 0.0058 m/s^2, 4.0e-4
    # rad/s); our sample is the mean over a 10 ms tick, so / sqrt(10)
    "sim.imu.accel_noise_std_m_s2": 0.0018,
    "sim.imu.gyro_noise_std_rad_s": 1.3e-4,
    # the combined decision rule fitted on realistic autopilot flights over training worlds 101-110;
    # it serves paper's autopilot flights better than a fit on paper flights or the shipped model
    # fitted on ideal scripted flights (docs/perception.md, "Refit on `realistic`"); realistic inherits it
    "perception.decision_model": "realistic",     # perception.decision.REALISTIC_DECISION_MODEL
    # the match position from the gradient-magnitude NCC within 24 px of the intensity peak: the
    # reference is another day's (sun, shadows, exposure) and edges move less than shading
    # (docs/perception.md "Gradient refinement"); not the paper's, ours, like the decision model
    "perception.gradient_refine_radius_px": 24,
})

#: ``realistic``: everything of ``paper`` plus these (docs/realism.md gives each basis).
REALISTIC_SETTINGS: Mapping[str, Any] = MappingProxyType({
    # compass: residuals after an onboard calibration, motor current, anomalies near buildings
    "sim.compass.hard_iron_mgauss": [12.0, -8.0, 6.0],        # SIM_MAG1_OFS; |o| ~ COMPASS_CAL_FIT 16
    "sim.compass.soft_iron_diag": [1.02, 0.98, 1.01],         # SIM_MAG1_DIA
    "sim.compass.soft_iron_offdiag": [0.01, -0.01, 0.005],    # SIM_MAG1_ODI
    "sim.compass.motor_mgauss_per_a": [0.2, 0.1, 1.0],        # SIM_MAG_MOT
    "sim.compass.anomaly_mgauss": 100.0,                      # SIM_MAG_ALY (per building cell)
    "sim.compass.anomaly_height_m": 5.0,                      # SIM_MAG_ALY_HGT (1/8 of ground value)
    # barometer: Gauss-Markov drift and rotor-downwash ground effect
    "sim.baro.drift_std_m": 0.5,                              # BMP388 relative accuracy ~0.66 m
    "sim.baro.drift_time_constant_s": 300.0,
    "sim.baro.ground_effect_m": -1.0,                         # SIM_BARO_GEFF_M style
    "sim.baro.ground_effect_height_m": 2.0,                   # SIM_BARO_GEFF_M: zero at 2 m AGL
    # IMU: white noise of a flight controller's MEMS IMU (the project's values: about 2x / 3x the
    # BMI088 datasheet densities of 0.014 deg/s/rt-Hz and 175 ug/rt-Hz over a 10 ms tick), bias
    # random walk and motor vibration scaled with throttle
    "sim.imu.accel_noise_std_m_s2": 0.05,
    "sim.imu.gyro_noise_std_rad_s": 0.005,
    "sim.imu.accel_bias_walk_m_s2_per_sqrt_s": 2.0e-4,
    "sim.imu.gyro_bias_walk_rad_s_per_sqrt_s": 5.0e-6,
    "sim.imu.vibration_accel_m_s2": 1.7,                      # SIM_ACC_RND style, x throttle
    "sim.imu.vibration_gyro_rad_s": 0.02,                     # SIM_GYR_RND style, x throttle
    # GPS (u-blox M8 class): slow random error and urban multipath from the DSM
    "sim.gps.horizontal_noise_std_m": 0.5,
    "sim.gps.vertical_noise_std_m": 1.0,
    "sim.gps.drift_std_m": 1.5,                               # u-blox M8: 2.5 m CEP
    "sim.gps.drift_time_constant_s": 60.0,
    "sim.gps.multipath_std_m": 3.0,                           # fully obstructed sky
    # wind: 5 m/s mean with gusts (SIM_WIND_SPD / SIM_WIND_TURB; Dryden low-altitude scales)
    "sim.wind.mean_velocity_enu_m_s": [5.0, 0.0, 0.0],        # 5 m/s from the west
    "sim.wind.gust_std_m_s": 0.7,
    "sim.wind.gust_time_constant_s": 20.0,
    # camera and mount: a fixed camera (the vehicle pitches 10-20 deg at 10 m/s), aligned with the
    # homography of the autopilot's estimated attitude; lens, exposure, blur, JPEG, jitter, clock
    # offset as sitl.camera_model.REALISTIC_CAMERA (docs/realism.md "Camera and mount")
    **{f"sim.camera.{key}": (list(value) if isinstance(value, tuple) else value)
       for key, value in REALISTIC_CAMERA.items()},
    "perception.alignment": "homography",
    # the compass is 4-9 deg off at some headings with the errors above (docs/realism.md "What breaks
    # matching on `realistic`"): learn that error from the matches (perception.heading_offset)
    "perception.heading_learning": True,
    # what the alignment's inputs are still off by, added to each fix's covariance (docs/realism.md
    # "Fix covariance on `realistic`"): the estimated roll / pitch, 0.80-0.88 / 0.45-0.51 deg RMS on
    # these flights (the ablation table), and the heading after the learning (about a third of the
    # compass's 6.2 deg RMS, on a fixed mount 27 m from the nadir at 15 deg of pitch)
    "perception.pointing_attitude_std_deg": 0.7,
    "perception.pointing_heading_std_deg": 2.0,
})

PROFILES: Mapping[Realism, Mapping[str, Any]] = MappingProxyType({
    Realism.IDEAL: MappingProxyType({}),
    Realism.PAPER: PAPER_SETTINGS,
    Realism.REALISTIC: MappingProxyType({**PAPER_SETTINGS, **REALISTIC_SETTINGS}),
})


def parse_realism(value: Any, where: str = "scenario") -> Realism:
    """A profile name -> ``Realism``; anything else is a one-line ``UserError``."""
    try:
        return Realism(value)
    except ValueError:
        raise UserError(f"{where}: realism: {value!r}: expected one of "
                        f"{', '.join(r.value for r in Realism)}") from None


def profile_settings(realism: Realism) -> Mapping[str, Any]:
    """The dotted-key settings of a profile (``ideal``: none)."""
    return PROFILES[realism]


def _merged(base: dict, top: Mapping[str, Any]) -> dict:
    out = dict(base)
    for key, value in top.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = _merged(out[key], value)
        else:
            out[key] = value
    return out


def apply_realism(data: Mapping[str, Any], where: str = "scenario") -> dict:
    """The scenario mapping with its profile's settings under it: a key the mapping sets (from the
    file or ``--set``) keeps its value; a key it leaves out takes the profile's."""
    realism = parse_realism(data.get("realism", Realism.IDEAL.value), where)
    layer: dict[str, Any] = {}
    for dotted, value in profile_settings(realism).items():
        set_dotted(layer, dotted, list(value) if isinstance(value, (list, tuple)) else value)
    return _merged(layer, data)
