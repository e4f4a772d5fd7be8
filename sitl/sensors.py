"""Sensor models (pure numpy): each takes the truth and returns a measurement.

Every model draws its randomness from the ``numpy.random.Generator`` it is given, so a seeded
generator gives a reproducible sequence. Units are in the names. Noise standard deviations are per
sample (discrete-time), so they do not depend on the sampling rate.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from scenenav.core.contracts import GpsFixType
from scenenav.core.frames import enu_to_geodetic
from scenenav.core.rotations import quat_to_rotation_matrix
from sitl.config import BaroConfig, CameraConfig, CompassConfig, FlowConfig, GpsConfig, ImuConfig
from sitl.surroundings import MagneticAnomalyField, Surface

logger = logging.getLogger(__name__)

# International Standard Atmosphere, troposphere (ISO 2533:1975; U.S. Standard Atmosphere 1976).
ISA_SEA_LEVEL_PRESSURE_PA = 101325.0
ISA_SEA_LEVEL_TEMPERATURE_K = 288.15
ISA_LAPSE_RATE_K_PER_M = 0.0065
ISA_GRAVITY_M_S2 = 9.80665
ISA_MOLAR_MASS_KG_PER_MOL = 0.0289644
ISA_GAS_CONSTANT_J_PER_MOL_K = 8.3144598
_ISA_EXPONENT = ISA_GRAVITY_M_S2 * ISA_MOLAR_MASS_KG_PER_MOL / (
    ISA_GAS_CONSTANT_J_PER_MOL_K * ISA_LAPSE_RATE_K_PER_M)      # about 5.2559


def isa_pressure_pa(altitude_m: float) -> float:
    """ISA static pressure (Pa) at a geopotential altitude above mean sea level (troposphere, < 11 km)."""
    ratio = 1.0 - ISA_LAPSE_RATE_K_PER_M * altitude_m / ISA_SEA_LEVEL_TEMPERATURE_K
    return ISA_SEA_LEVEL_PRESSURE_PA * ratio ** _ISA_EXPONENT


def isa_altitude_m(pressure_pa: float) -> float:
    """Inverse of ``isa_pressure_pa``: pressure altitude (m) for a static pressure (Pa)."""
    ratio = (pressure_pa / ISA_SEA_LEVEL_PRESSURE_PA) ** (1.0 / _ISA_EXPONENT)
    return ISA_SEA_LEVEL_TEMPERATURE_K * (1.0 - ratio) / ISA_LAPSE_RATE_K_PER_M


class ImuModel:
    """Accelerometer + gyroscope: truth + turn-on bias (+ optional bias random walk) + white noise.

    Inputs and outputs are in the body FLU frame: specific force in m/s^2 (what an ideal
    accelerometer reads: +g on body z when level at rest), angular velocity in rad/s.
    """

    def __init__(self, cfg: ImuConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self._rng = rng
        self.accel_bias_flu_m_s2 = cfg.accel_bias_std_m_s2 * rng.standard_normal(3)
        self.gyro_bias_flu_rad_s = cfg.gyro_bias_std_rad_s * rng.standard_normal(3)

    def sample(self, specific_force_flu_m_s2: np.ndarray, angular_velocity_flu_rad_s: np.ndarray,
               dt_s: float = 0.0, throttle: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(accel_flu_m_s2, gyro_flu_rad_s). ``dt_s`` (time since the previous sample) drives the
        bias random walk; with the default 0 the biases stay constant. ``throttle`` (0..1, mean rotor
        speed over its maximum) scales the motor vibration (``vibration_*``)."""
        cfg = self.cfg
        if dt_s > 0.0:
            root_dt = math.sqrt(dt_s)
            if cfg.accel_bias_walk_m_s2_per_sqrt_s > 0.0:
                self.accel_bias_flu_m_s2 = self.accel_bias_flu_m_s2 + (
                    cfg.accel_bias_walk_m_s2_per_sqrt_s * root_dt * self._rng.standard_normal(3))
            if cfg.gyro_bias_walk_rad_s_per_sqrt_s > 0.0:
                self.gyro_bias_flu_rad_s = self.gyro_bias_flu_rad_s + (
                    cfg.gyro_bias_walk_rad_s_per_sqrt_s * root_dt * self._rng.standard_normal(3))
        noise = self._rng.standard_normal(6)
        accel = (np.asarray(specific_force_flu_m_s2, dtype=float) + self.accel_bias_flu_m_s2
                 + cfg.accel_noise_std_m_s2 * noise[:3])
        gyro = (np.asarray(angular_velocity_flu_rad_s, dtype=float) + self.gyro_bias_flu_rad_s
                + cfg.gyro_noise_std_rad_s * noise[3:])
        if (cfg.vibration_accel_m_s2 > 0.0 or cfg.vibration_gyro_rad_s > 0.0) and throttle > 0.0:
            vib = self._rng.standard_normal(6) * throttle
            accel = accel + cfg.vibration_accel_m_s2 * vib[:3]
            gyro = gyro + cfg.vibration_gyro_rad_s * vib[3:]
        return accel, gyro


class GaussMarkov:
    """First-order Gauss-Markov process of stationary std ``sigma`` and correlation time ``tau_s``,
    advanced by a fixed step ``dt_s`` (exact discretisation: x <- a x + sigma sqrt(1 - a^2) n,
    a = exp(-dt / tau)); starts in its stationary distribution. ``size`` independent components."""

    def __init__(self, sigma: float, tau_s: float, dt_s: float, rng: np.random.Generator,
                 size: int = 1) -> None:
        self._rng = rng
        self._size = size
        self.sigma = float(sigma)
        self._a = math.exp(-dt_s / tau_s)
        self._b = self.sigma * math.sqrt(-math.expm1(-2.0 * dt_s / tau_s))
        self.value = self.sigma * rng.standard_normal(size)

    def step(self) -> np.ndarray:
        self.value = self._a * self.value + self._b * self._rng.standard_normal(self._size)
        return self.value


class BaroModel:
    """Barometric altimeter: altitude + bias + Gauss-Markov drift + ground effect + white noise,
    and the ISA static pressure of that reading. The drift is advanced by 1/rate_hz per sample."""

    def __init__(self, cfg: BaroConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self._rng = rng
        self._drift = (GaussMarkov(cfg.drift_std_m, cfg.drift_time_constant_s, 1.0 / cfg.rate_hz, rng)
                       if cfg.drift_std_m > 0.0 else None)

    def ground_effect_m(self, height_above_surface_m: float, rotors_on: bool) -> float:
        """The downwash error: ``ground_effect_m`` on the surface, zero from
        ``ground_effect_height_m`` up, linear between (only with the rotors turning)."""
        cfg = self.cfg
        if not rotors_on or cfg.ground_effect_m == 0.0:
            return 0.0
        share = 1.0 - max(0.0, float(height_above_surface_m)) / cfg.ground_effect_height_m
        return cfg.ground_effect_m * max(0.0, share)

    def sample(self, altitude_m: float, height_above_surface_m: float = math.inf,
               rotors_on: bool = False) -> tuple[float, float]:
        """(altitude_m, pressure_pa) for a true altitude above mean sea level (m); the height above
        the surface below and whether the rotors turn drive the ground effect.

        The pressure is the ISA pressure of the measured (noisy) altitude, so the pair is consistent.
        """
        measured = float(altitude_m) + self.cfg.bias_m + self.cfg.noise_std_m * float(
            self._rng.standard_normal())
        if self._drift is not None:
            measured += float(self._drift.step()[0])
        measured += self.ground_effect_m(height_above_surface_m, rotors_on)
        return measured, isa_pressure_pa(measured)


class CompassModel:
    """Magnetic compass already corrected for declination: heading + bias + white noise, plus
    (``cfg.distorted``) the heading error of a distorted magnetometer reading.

    The magnetometer model (body FLU axes, mGauss): ``m = S (R^T (B + A) + k I) + o`` with ``B``
    the earth field (ENU, declination 0), ``A`` the local anomaly of the buildings
    (``sitl.surroundings.MagneticAnomalyField``), ``R`` the body-to-world rotation, ``k`` the
    motor-current coefficients (SIM_MAG_MOT) times the battery current ``I``, ``S`` the soft-iron
    matrix and ``o`` the hard-iron offset. The autopilot tilt-compensates the reading with its
    roll and pitch; the heading it gets is the true heading minus the angle of ``R m`` from north
    (here with the true roll and pitch, so the error is the magnetometer's alone).
    """

    def __init__(self, cfg: CompassConfig, rng: np.random.Generator,
                 anomalies: MagneticAnomalyField | None = None) -> None:
        self.cfg = cfg
        self._rng = rng
        self.anomalies = anomalies
        inc = math.radians(cfg.inclination_deg)
        self.earth_enu_mgauss = cfg.earth_field_mgauss * np.array([0.0, math.cos(inc), -math.sin(inc)])
        d, o = cfg.soft_iron_diag, cfg.soft_iron_offdiag
        self.soft_iron = np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]])
        self.hard_iron = np.array(cfg.hard_iron_mgauss, dtype=float)
        self.motor = np.array(cfg.motor_mgauss_per_a, dtype=float)

    def field_body_mgauss(self, q_wxyz, current_a: float = 0.0, position_enu_m=None) -> np.ndarray:
        """The distorted magnetometer reading (body FLU, mGauss)."""
        rot = quat_to_rotation_matrix(q_wxyz)
        world = self.earth_enu_mgauss
        if self.anomalies is not None and position_enu_m is not None:
            world = world + self.anomalies.at(position_enu_m)
        current = float(current_a) if math.isfinite(current_a) else 0.0
        return self.soft_iron @ (rot.T @ world + self.motor * current) + self.hard_iron

    def heading_error_rad(self, q_wxyz, current_a: float = 0.0, position_enu_m=None) -> float:
        """Measured minus true heading caused by the magnetometer errors (rad, in (-pi, pi])."""
        seen = quat_to_rotation_matrix(q_wxyz) @ self.field_body_mgauss(q_wxyz, current_a, position_enu_m)
        return -math.atan2(float(seen[0]), float(seen[1]))

    def sample(self, heading_rad: float, q_wxyz=None, current_a: float = 0.0,
               position_enu_m=None) -> float:
        """Heading (rad, clockwise from north) -> measured heading wrapped to [0, 2*pi). The
        attitude ``q_wxyz`` (and the battery current and position) drive the magnetometer errors
        when ``cfg.distorted``."""
        value = float(heading_rad) + self.cfg.bias_rad + self.cfg.noise_std_rad * float(
            self._rng.standard_normal())
        if self.cfg.distorted and q_wxyz is not None:
            value += self.heading_error_rad(q_wxyz, current_a, position_enu_m)
        wrapped = value % (2.0 * math.pi)
        # float modulo can return exactly 2*pi for tiny negative inputs.
        return 0.0 if wrapped >= 2.0 * math.pi else wrapped


@dataclass(frozen=True, eq=False)   # numpy fields: compare fields explicitly, not with ==
class GpsFix:
    """One receiver fix (the node publishes it as ``scenenav.core.contracts.GpsSample``)."""

    lat_deg: float
    lon_deg: float
    alt_m: float                    # altitude of the fix (origin altitude + ENU z + error), m
    velocity_enu_m_s: np.ndarray    # (3,)
    eph_m: float                    # horizontal 1-sigma accuracy, m
    epv_m: float                    # vertical 1-sigma accuracy, m
    fix_type: GpsFixType
    satellites: int


class GpsModel:
    """GPS receiver: position + slow Gauss-Markov drift + white noise, velocity + white noise.

    The drift (``drift_std_m``, ``drift_time_constant_s``) is advanced by 1/rate_hz at every
    sample, i.e. the model assumes it is sampled at ``rate_hz``. With ``enabled`` false every sample
    is a NO_FIX sample whose numeric fields are NaN.
    """

    def __init__(self, cfg: GpsConfig, rng: np.random.Generator, surface: Surface | None = None) -> None:
        self.cfg = cfg
        self._rng = rng
        self.surface = surface
        self._multipath = (GaussMarkov(1.0, cfg.multipath_time_constant_s, 1.0 / cfg.rate_hz, rng, size=2)
                           if cfg.multipath_std_m > 0.0 else None)
        self._sigma = np.array([cfg.horizontal_noise_std_m, cfg.horizontal_noise_std_m,
                                cfg.vertical_noise_std_m])
        self._drift = cfg.drift_std_m * rng.standard_normal(3) if cfg.drift_std_m > 0.0 else np.zeros(3)
        a = math.exp(-1.0 / (cfg.rate_hz * cfg.drift_time_constant_s))
        self._drift_a = a
        self._drift_b = cfg.drift_std_m * math.sqrt(1.0 - a * a)
        self.eph_m = math.hypot(cfg.horizontal_noise_std_m, cfg.drift_std_m)
        self.epv_m = math.hypot(cfg.vertical_noise_std_m, cfg.drift_std_m)

    def sample(self, position_enu_m: np.ndarray, velocity_enu_m_s: np.ndarray, origin_lat_deg: float,
               origin_lon_deg: float, origin_alt_m: float = 0.0) -> GpsFix:
        """Fix for a true ENU position (m) and velocity (m/s) around the world origin (map centre)."""
        if not self.cfg.enabled:
            nan = float("nan")
            return GpsFix(nan, nan, nan, np.full(3, nan), nan, nan, GpsFixType.NO_FIX, 0)
        if self.cfg.drift_std_m > 0.0:
            self._drift = self._drift_a * self._drift + self._drift_b * self._rng.standard_normal(3)
        noise = self._rng.standard_normal(6)
        pos = np.asarray(position_enu_m, dtype=float) + self._drift + self._sigma * noise[:3]
        if self._multipath is not None:
            unit = self._multipath.step()
            pos[:2] += self.multipath_std_m(position_enu_m) * unit
        vel = np.asarray(velocity_enu_m_s, dtype=float) + self.cfg.velocity_noise_std_m_s * noise[3:]
        lat, lon = enu_to_geodetic(pos[0], pos[1], origin_lat_deg, origin_lon_deg)
        return GpsFix(lat_deg=float(lat), lon_deg=float(lon), alt_m=float(origin_alt_m + pos[2]),
                      velocity_enu_m_s=vel, eph_m=self.eph_m, epv_m=self.epv_m,
                      fix_type=GpsFixType.FIX_3D, satellites=self.cfg.satellites)


    def multipath_std_m(self, position_enu_m) -> float:
        """Std of the multipath error at a position: ``multipath_std_m`` x the share of the sky
        the buildings hide (0 without a surface model)."""
        if self.surface is None or self.cfg.multipath_std_m <= 0.0:
            return 0.0
        return self.cfg.multipath_std_m * self.surface.sky_obstruction(position_enu_m)


@dataclass(frozen=True)
class FlowReading:
    """One optical-flow sample (published as ``scenenav.core.contracts.FlowSample``)."""

    flow_flu_rad_s: tuple[float, float]
    body_rate_flu_rad_s: tuple[float, float]
    distance_m: float               # NaN outside the range finder's limits
    quality: int                    # 0..255


class FlowModel:
    """Downward optical flow and range finder on the body's -z axis (``FlowConfig``).

    The range is the ray from the vehicle along body -z to the first surface (the world's DSM through
    ``Surface.range_m``; the plane z = 0 without one). The flow is the apparent angular velocity of
    that surface point, (-vy / r - wx, vx / r - wy) with the true body velocity v, range r and body
    rate w, times (1 + a per-run scale error per axis), plus white noise; the module's gyro reads w
    plus white noise. The range reads r (1 + noise fraction), NaN outside [range_min_m, range_max_m]
    (also on the ground, below the minimum). Quality is 255 while the range is valid, 0 otherwise
    (too close to focus, or too far for a usable texture at 10 Hz). Not modelled: the flow sensor's
    field of view averaging surfaces at different ranges (a roof edge), low light, and the interval
    averaging (the sample is instantaneous, as ArduPilot SITL's flow).
    """

    def __init__(self, cfg: FlowConfig, rng: np.random.Generator, surface: Surface | None = None) -> None:
        self.cfg = cfg
        self._rng = rng
        self.surface = surface
        self.scale = 1.0 + cfg.scale_error_std * rng.standard_normal(2)

    def true_range_m(self, position_enu_m, q_wxyz) -> float:
        """Distance along body -z from the vehicle to the first surface (inf: the axis points up)."""
        return self._range_m(position_enu_m, quat_to_rotation_matrix(q_wxyz))

    def _range_m(self, position_enu_m, rot: np.ndarray) -> float:
        down = -rot[:, 2]
        pos = np.asarray(position_enu_m, dtype=float)
        if self.surface is not None:
            return self.surface.range_m(pos, down)
        if down[2] >= 0.0:
            return math.inf
        return float(max(pos[2], 0.0) / -down[2])

    def sample(self, position_enu_m, velocity_enu_m_s, q_wxyz, angular_velocity_flu_rad_s) -> FlowReading:
        cfg = self.cfg
        rot = quat_to_rotation_matrix(q_wxyz)
        r = self._range_m(position_enu_m, rot)
        vb = rot.T @ np.asarray(velocity_enu_m_s, dtype=float)
        w = np.asarray(angular_velocity_flu_rad_s, dtype=float)
        noise = self._rng.standard_normal(5)
        gyro = (float(w[0] + cfg.gyro_noise_std_rad_s * noise[2]),
                float(w[1] + cfg.gyro_noise_std_rad_s * noise[3]))
        if not (cfg.range_min_m <= r <= cfg.range_max_m):
            return FlowReading((math.nan, math.nan), gyro, math.nan, 0)
        fx = -vb[1] / r * self.scale[0] - w[0] + cfg.noise_std_rad_s * noise[0]
        fy = vb[0] / r * self.scale[1] - w[1] + cfg.noise_std_rad_s * noise[1]
        distance = r * (1.0 + cfg.range_noise_fraction * noise[4])
        return FlowReading((float(fx), float(fy)), gyro, float(distance), 255)


def gaussian_kernel(sigma_px: float) -> np.ndarray:
    """Normalised 1-D Gaussian kernel with radius ceil(3 sigma)."""
    radius = max(1, int(math.ceil(3.0 * sigma_px)))
    x = np.arange(-radius, radius + 1, dtype=float)
    k = np.exp(-0.5 * (x / sigma_px) ** 2)
    return k / k.sum()


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Separable Gaussian blur of an (h, w) or (h, w, c) float image, mirrored borders."""
    kernel = gaussian_kernel(sigma_px)
    radius = len(kernel) // 2
    out = np.asarray(image, dtype=float)
    for axis in (0, 1):
        moved = np.moveaxis(out, axis, 0)
        n = moved.shape[0]
        pad = [(radius, radius)] + [(0, 0)] * (moved.ndim - 1)
        padded = np.pad(moved, pad, mode="reflect" if n > radius else "edge")
        acc = kernel[0] * padded[0:n]
        for i in range(1, len(kernel)):
            acc += kernel[i] * padded[i:i + n]
        out = np.moveaxis(acc, 0, axis)
    return out


class CameraEffects:
    """Exposure gain, optical blur and sensor noise applied to a rendered RGB image.

    Order: gain (drawn uniformly in ``exposure_gain_range`` for each frame), Gaussian blur of
    ``blur_sigma_px``, additive Gaussian noise of ``noise_std`` grey levels, round and clip to uint8.
    With everything off (gain range (1, 1), blur 0, noise 0) ``apply`` returns its input unchanged.
    """

    def __init__(self, cfg: CameraConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self._rng = rng
        lo, hi = cfg.exposure_gain_range
        self.enabled = not (lo == 1.0 and hi == 1.0 and cfg.blur_sigma_px == 0.0 and cfg.noise_std == 0.0)

    def apply(self, image_rgb_uint8: np.ndarray) -> np.ndarray:
        if not self.enabled:
            return image_rgb_uint8
        cfg = self.cfg
        lo, hi = cfg.exposure_gain_range
        img = np.asarray(image_rgb_uint8, dtype=float)
        if hi > lo:
            img = img * float(self._rng.uniform(lo, hi))
        elif lo != 1.0:
            img = img * lo
        if cfg.blur_sigma_px > 0.0:
            img = gaussian_blur(img, cfg.blur_sigma_px)
        if cfg.noise_std > 0.0:
            img = img + cfg.noise_std * self._rng.standard_normal(img.shape)
        return np.clip(np.rint(img), 0.0, 255.0).astype(np.uint8)
