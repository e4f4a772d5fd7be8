"""Sensor models: noise statistics, wrap-around, geodetic consistency, ISA, camera effects, configs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scenenav.core.config import ConfigError, load_config
from scenenav.core.contracts import GpsFixType
from scenenav.core.frames import enu_to_geodetic, geodetic_to_enu
from sitl.config import (
    BaroConfig,
    CameraConfig,
    CameraMount,
    CompassConfig,
    GpsConfig,
    ImuConfig,
    SimConfig,
    WindConfig,
)
from sitl.sensors import (
    BaroModel,
    CameraEffects,
    CompassModel,
    GpsModel,
    ImuModel,
    gaussian_blur,
    isa_altitude_m,
    isa_pressure_pa,
)

N = 20000


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def test_imu_noise_statistics_without_bias():
    cfg = ImuConfig(accel_noise_std_m_s2=0.05, gyro_noise_std_rad_s=0.005, accel_bias_std_m_s2=0.0,
                    gyro_bias_std_rad_s=0.0)
    imu = ImuModel(cfg, _rng())
    f = np.array([0.1, -0.2, 9.8])
    w = np.array([0.01, 0.0, -0.3])
    samples = [imu.sample(f, w) for _ in range(N)]
    accel = np.array([s[0] for s in samples])
    gyro = np.array([s[1] for s in samples])
    assert accel.mean(axis=0) == pytest.approx(f, abs=4 * 0.05 / math.sqrt(N))
    assert gyro.mean(axis=0) == pytest.approx(w, abs=4 * 0.005 / math.sqrt(N))
    assert accel.std(axis=0) == pytest.approx([0.05] * 3, rel=0.05)
    assert gyro.std(axis=0) == pytest.approx([0.005] * 3, rel=0.05)


def test_imu_bias_is_constant_per_instance_and_drawn_with_its_std():
    cfg = ImuConfig(accel_noise_std_m_s2=0.0, gyro_noise_std_rad_s=0.0)
    imu = ImuModel(cfg, _rng(1))
    a1, g1 = imu.sample(np.zeros(3), np.zeros(3))
    a2, g2 = imu.sample(np.zeros(3), np.zeros(3))
    assert np.array_equal(a1, a2) and np.array_equal(g1, g2)
    assert np.array_equal(a1, imu.accel_bias_flu_m_s2)
    biases = np.array([ImuModel(cfg, _rng(s)).accel_bias_flu_m_s2 for s in range(2000)])
    assert biases.std() == pytest.approx(cfg.accel_bias_std_m_s2, rel=0.1)


def test_imu_bias_random_walk_grows_with_time():
    cfg = ImuConfig(accel_noise_std_m_s2=0.0, gyro_noise_std_rad_s=0.0, accel_bias_std_m_s2=0.0,
                    gyro_bias_std_rad_s=0.0, accel_bias_walk_m_s2_per_sqrt_s=0.01)
    finals = []
    for seed in range(400):
        imu = ImuModel(cfg, _rng(seed))
        for _ in range(100):
            accel, gyro = imu.sample(np.zeros(3), np.zeros(3), dt_s=1.0)
        finals.append(accel)
        assert np.array_equal(gyro, np.zeros(3))
    # After 100 s, std = 0.01 * sqrt(100).
    assert np.array(finals).std() == pytest.approx(0.1, rel=0.1)


def test_isa_pressure():
    assert isa_pressure_pa(0.0) == pytest.approx(101325.0, abs=1e-9)
    assert isa_pressure_pa(1000.0) == pytest.approx(89874.6, abs=5.0)      # ISA table: 89 875 Pa
    assert isa_pressure_pa(5000.0) == pytest.approx(54019.9, abs=20.0)     # ISA table: 54 020 Pa
    for h in (-100.0, 0.0, 123.4, 2500.0):
        assert isa_altitude_m(isa_pressure_pa(h)) == pytest.approx(h, abs=1e-6)


def test_baro_noise_statistics_and_bias():
    baro = BaroModel(BaroConfig(noise_std_m=0.3, bias_m=1.5), _rng())
    samples = np.array([baro.sample(100.0) for _ in range(N)])
    assert samples[:, 0].mean() == pytest.approx(101.5, abs=4 * 0.3 / math.sqrt(N))
    assert samples[:, 0].std() == pytest.approx(0.3, rel=0.05)
    # The pressure is the ISA pressure of the reported altitude.
    assert samples[0, 1] == pytest.approx(isa_pressure_pa(samples[0, 0]))
    assert samples[:, 1].mean() < isa_pressure_pa(0.0)


def test_compass_wraps_to_zero_two_pi():
    compass = CompassModel(CompassConfig(noise_std_rad=0.0), _rng())
    assert compass.sample(-0.1) == pytest.approx(2.0 * math.pi - 0.1)
    assert compass.sample(2.0 * math.pi + 0.2) == pytest.approx(0.2)
    assert compass.sample(-1e-18) < 2.0 * math.pi
    noisy = CompassModel(CompassConfig(noise_std_rad=0.01), _rng())
    samples = np.array([noisy.sample(0.0) for _ in range(N)])
    assert np.all((samples >= 0.0) & (samples < 2.0 * math.pi))
    assert np.any(samples > math.pi) and np.any(samples < math.pi)      # both sides of north
    error = (samples + math.pi) % (2.0 * math.pi) - math.pi
    assert error.mean() == pytest.approx(0.0, abs=4 * 0.01 / math.sqrt(N))
    assert error.std() == pytest.approx(0.01, rel=0.05)


def test_compass_bias():
    compass = CompassModel(CompassConfig(noise_std_rad=0.0, bias_rad=0.05), _rng())
    assert compass.sample(1.0) == pytest.approx(1.05)


ORIGIN = (47.3977, 8.5456)


def test_gps_without_noise_matches_the_frames():
    cfg = GpsConfig(horizontal_noise_std_m=0.0, vertical_noise_std_m=0.0, velocity_noise_std_m_s=0.0)
    gps = GpsModel(cfg, _rng())
    pos = np.array([350.0, -120.0, 80.0])
    vel = np.array([10.0, 2.0, -1.0])
    fix = gps.sample(pos, vel, *ORIGIN, origin_alt_m=400.0)
    lat, lon = enu_to_geodetic(pos[0], pos[1], *ORIGIN)
    assert (fix.lat_deg, fix.lon_deg) == (lat, lon)
    assert fix.alt_m == pytest.approx(480.0)
    assert fix.velocity_enu_m_s == pytest.approx(vel)
    assert fix.fix_type is GpsFixType.FIX_3D and fix.satellites == cfg.satellites
    # North of the origin is a higher latitude, east a higher longitude.
    north = gps.sample(np.array([0.0, 100.0, 0.0]), vel, *ORIGIN)
    east = gps.sample(np.array([100.0, 0.0, 0.0]), vel, *ORIGIN)
    assert north.lat_deg > ORIGIN[0] and north.lon_deg == pytest.approx(ORIGIN[1])
    assert east.lon_deg > ORIGIN[1] and east.lat_deg == pytest.approx(ORIGIN[0])


def test_gps_noise_statistics():
    cfg = GpsConfig(horizontal_noise_std_m=0.5, vertical_noise_std_m=1.0, velocity_noise_std_m_s=0.1)
    gps = GpsModel(cfg, _rng())
    pos = np.array([100.0, 200.0, 50.0])
    fixes = [gps.sample(pos, np.zeros(3), *ORIGIN) for _ in range(5000)]
    east, north = geodetic_to_enu(np.array([f.lat_deg for f in fixes]), np.array([f.lon_deg for f in fixes]),
                                  *ORIGIN)
    alt = np.array([f.alt_m for f in fixes])
    vel = np.array([f.velocity_enu_m_s for f in fixes])
    assert east.mean() == pytest.approx(100.0, abs=0.05) and north.mean() == pytest.approx(200.0, abs=0.05)
    assert east.std() == pytest.approx(0.5, rel=0.06) and north.std() == pytest.approx(0.5, rel=0.06)
    assert alt.std() == pytest.approx(1.0, rel=0.06)
    assert vel.std(axis=0) == pytest.approx([0.1] * 3, rel=0.06)
    assert fixes[0].eph_m == pytest.approx(0.5) and fixes[0].epv_m == pytest.approx(1.0)


def test_gps_drift_is_slow_and_bounded():
    cfg = GpsConfig(horizontal_noise_std_m=0.0, vertical_noise_std_m=0.0, drift_std_m=2.0,
                    drift_time_constant_s=30.0, rate_hz=5.0)
    gps = GpsModel(cfg, _rng(3))
    east = []
    for _ in range(30000):
        fix = gps.sample(np.zeros(3), np.zeros(3), *ORIGIN)
        east.append(geodetic_to_enu(fix.lat_deg, fix.lon_deg, *ORIGIN)[0])
    east = np.array(east)
    assert east.std() == pytest.approx(2.0, rel=0.25)
    # Consecutive fixes 0.2 s apart differ by sigma sqrt(1 - a^2), a = exp(-0.2 s / 30 s): ~0.23 m.
    a = math.exp(-0.2 / 30.0)
    assert np.diff(east).std() == pytest.approx(2.0 * math.sqrt(1.0 - a * a), rel=0.1)
    assert fix.eph_m == pytest.approx(2.0)


def test_gps_disabled_gives_no_fix():
    fix = GpsModel(GpsConfig(enabled=False), _rng()).sample(np.zeros(3), np.zeros(3), *ORIGIN)
    assert fix.fix_type is GpsFixType.NO_FIX and fix.satellites == 0
    assert math.isnan(fix.lat_deg) and math.isnan(fix.lon_deg)


def _image() -> np.ndarray:
    return _rng(5).integers(40, 200, (64, 80, 3), dtype=np.uint8)


def test_camera_effects_identity_when_off():
    image = _image()
    assert CameraEffects(CameraConfig(), _rng()).apply(image) is image


def test_camera_effects_noise_gain_and_blur():
    image = _image()
    noisy = CameraEffects(CameraConfig(noise_std=4.0), _rng()).apply(image)
    diff = noisy.astype(float) - image
    assert noisy.dtype == np.uint8 and noisy.shape == image.shape
    assert diff.mean() == pytest.approx(0.0, abs=0.2) and diff.std() == pytest.approx(4.0, rel=0.05)

    bright = CameraEffects(CameraConfig(exposure_gain_range=(1.2, 1.2)), _rng()).apply(image)
    assert bright.astype(float) == pytest.approx(np.clip(np.rint(image * 1.2), 0, 255), abs=0)
    gains = CameraEffects(CameraConfig(exposure_gain_range=(0.8, 1.2)), _rng())
    means = [gains.apply(image).mean() / image.mean() for _ in range(200)]
    assert min(means) > 0.79 and max(means) < 1.21 and np.std(means) > 0.05

    blurred = CameraEffects(CameraConfig(blur_sigma_px=1.5), _rng()).apply(image)
    assert blurred.mean() == pytest.approx(image.mean(), abs=1.0)
    assert blurred.astype(float).std() < 0.5 * image.astype(float).std()


def test_gaussian_blur_keeps_constants_and_matches_a_point_spread():
    flat = np.full((20, 30), 7.0)
    assert gaussian_blur(flat, 2.0) == pytest.approx(flat)
    impulse = np.zeros((41, 41))
    impulse[20, 20] = 1.0
    psf = gaussian_blur(impulse, 2.0)
    y, x = np.mgrid[-20:21, -20:21]
    assert psf.sum() == pytest.approx(1.0)
    assert math.sqrt((psf * x * x).sum()) == pytest.approx(2.0, rel=0.02)


def test_camera_effects_are_deterministic_with_a_seed():
    cfg = CameraConfig(noise_std=3.0, exposure_gain_range=(0.9, 1.1), blur_sigma_px=0.7)
    a = CameraEffects(cfg, _rng(9)).apply(_image())
    b = CameraEffects(cfg, _rng(9)).apply(_image())
    assert np.array_equal(a, b)


def test_configs_load_and_reject_bad_values():
    cfg = load_config(SimConfig, {"physics_rate_hz": 500, "camera": {"mount": "fixed", "fov_deg": 45},
                                  "wind": {"mean_velocity_enu_m_s": [1, 2, 0]}}, "scenario.yaml")
    assert cfg.camera.mount is CameraMount.FIXED and cfg.camera.fov_deg == 45.0
    assert cfg.wind.mean_velocity_enu_m_s == (1.0, 2.0, 0.0)
    assert SimConfig().camera.mount is CameraMount.GIMBAL
    with pytest.raises(ConfigError, match="camera.noise_std"):
        load_config(SimConfig, {"camera": {"noise_std": -1.0}}, "scenario.yaml")
    with pytest.raises(ConfigError, match="mount"):
        load_config(SimConfig, {"camera": {"mount": "sideways"}}, "scenario.yaml")
    for bad in (lambda: WindConfig(gust_time_constant_s=0.0), lambda: ImuConfig(gyro_noise_std_rad_s=-1.0),
                lambda: BaroConfig(rate_hz=0.0), lambda: GpsConfig(satellites=-1),
                lambda: CameraConfig(exposure_gain_range=(1.2, 1.0)), lambda: CameraConfig(ground_window_px=10),
                lambda: SimConfig(physics_rate_hz=10.0)):
        with pytest.raises(ConfigError):
            bad()
