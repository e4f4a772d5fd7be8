"""Error sources of the realism profiles: compass hard/soft iron, motor current and building
anomalies, baro Gauss-Markov drift and ground effect, IMU vibration, GPS urban multipath."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scenenav.core.frames import geodetic_to_enu
from scenenav.core.rotations import quat_from_aviation_euler
from sitl.config import BaroConfig, CompassConfig, GpsConfig, ImuConfig
from sitl.sensors import BaroModel, CompassModel, GaussMarkov, GpsModel, ImuModel
from sitl.surroundings import MagneticAnomalyField, Surface

MPP = 1.0


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def _level(heading_rad: float):
    return quat_from_aviation_euler(0.0, 0.0, heading_rad)


def _quiet_compass(**kw) -> CompassModel:
    return CompassModel(CompassConfig(noise_std_rad=0.0, **kw), _rng())


def _tower_surface(height_m: float = 40.0, size_px: int = 200) -> Surface:
    """A flat 200 m map with one 20 m x 20 m tower of ``height_m`` 40 m east of the centre."""
    dsm = np.zeros((size_px, size_px), dtype=np.float32)
    c = size_px // 2
    dsm[c - 10:c + 10, c + 30:c + 50] = height_m
    return Surface(dsm, dsm > 0, MPP)


def test_an_undistorted_compass_is_exactly_the_old_model():
    cfg = CompassConfig()
    assert not cfg.distorted
    a, b = CompassModel(cfg, _rng(3)), CompassModel(cfg, _rng(3))
    for h in np.linspace(0.0, 6.2, 50):
        assert a.sample(h) == b.sample(h, _level(h), 20.0, np.zeros(3))


def test_hard_iron_gives_a_one_cycle_heading_error_of_the_expected_size():
    offset = 20.0                                   # mGauss along body +y (left)
    model = _quiet_compass(hard_iron_mgauss=(0.0, offset, 0.0))
    horizontal = 500.0 * math.cos(math.radians(65.0))
    err0 = model.heading_error_rad(_level(0.0))
    assert err0 == pytest.approx(math.atan2(offset, horizontal), rel=1e-9)
    assert model.heading_error_rad(_level(math.pi)) == pytest.approx(-err0, rel=1e-9)
    errs = [model.heading_error_rad(_level(h)) for h in np.linspace(0, 2 * math.pi, 72, endpoint=False)]
    assert abs(np.mean(errs)) < 1e-3 * abs(err0)     # one cycle per turn: no mean bias
    assert max(errs) == pytest.approx(err0, rel=0.02)


def test_soft_iron_gives_a_two_cycle_heading_error():
    model = _quiet_compass(soft_iron_diag=(1.05, 0.95, 1.0))
    hs = np.linspace(0, 2 * math.pi, 72, endpoint=False)
    errs = np.array([model.heading_error_rad(_level(h)) for h in hs])
    assert np.max(np.abs(errs)) > math.radians(2.0)
    # two cycles per turn: the error repeats after half a turn
    assert np.allclose(errs[:36], errs[36:], atol=1e-9)


def test_motor_interference_grows_with_the_current():
    model = _quiet_compass(motor_mgauss_per_a=(0.0, 0.5, 1.0))
    small = [abs(model.heading_error_rad(_level(0.3), current_a=i)) for i in (5.0, 10.0, 20.0)]
    assert small[0] < small[1] < small[2]
    assert small[1] == pytest.approx(2 * small[0], rel=0.05)          # linear for small angles
    assert model.heading_error_rad(_level(0.3), current_a=0.0) == pytest.approx(0.0, abs=1e-12)


def test_compass_sample_adds_the_distortion_to_the_heading():
    model = _quiet_compass(hard_iron_mgauss=(0.0, 20.0, 0.0))
    h = 1.0
    assert model.sample(h, _level(h)) == pytest.approx(h + model.heading_error_rad(_level(h)), abs=1e-12)


def test_anomaly_decays_as_a_cube_with_height_above_the_dsm():
    surface = _tower_surface()
    field = MagneticAnomalyField(surface, 300.0, 5.0, 20.0, _rng(1))
    assert field.decay(0.0) == 1.0
    assert field.decay(5.0) == pytest.approx(1.0 / 8.0)
    assert field.decay(95.0) == pytest.approx((5.0 / 100.0) ** 3)
    on_roof = np.array([40.0, 0.0, 40.0])            # standing on the tower's roof
    above = np.array([40.0, 0.0, 140.0])             # 100 m above the roof
    a0, a1 = np.linalg.norm(field.at(on_roof)), np.linalg.norm(field.at(above))
    assert a0 > 10.0
    assert a1 == pytest.approx(a0 * field.decay(100.0), rel=1e-9)
    # far from any building there is no anomaly
    assert np.linalg.norm(field.at(np.array([-80.0, -80.0, 0.0]))) == 0.0


def test_anomaly_field_is_seeded():
    s = _tower_surface()
    a = MagneticAnomalyField(s, 300.0, 5.0, 20.0, _rng(7)).at(np.array([40.0, 0.0, 41.0]))
    b = MagneticAnomalyField(s, 300.0, 5.0, 20.0, _rng(7)).at(np.array([40.0, 0.0, 41.0]))
    c = MagneticAnomalyField(s, 300.0, 5.0, 20.0, _rng(8)).at(np.array([40.0, 0.0, 41.0]))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_anomaly_disturbs_the_heading_near_a_roof_not_at_100_m():
    surface = _tower_surface()
    field = MagneticAnomalyField(surface, 300.0, 5.0, 20.0, _rng(1))
    model = CompassModel(CompassConfig(noise_std_rad=0.0, anomaly_mgauss=300.0), _rng(), field)
    low = abs(model.heading_error_rad(_level(0.0), position_enu_m=np.array([40.0, 0.0, 42.0])))
    high = abs(model.heading_error_rad(_level(0.0), position_enu_m=np.array([40.0, 0.0, 140.0])))
    assert low > math.radians(1.0)
    assert high < math.radians(0.01)


def test_gauss_markov_std_and_correlation_time():
    dt, tau, sigma = 0.05, 2.0, 0.5
    gm = GaussMarkov(sigma, tau, dt, _rng(2))
    x = np.array([gm.step()[0] for _ in range(40000)])
    assert np.std(x) == pytest.approx(sigma, rel=0.1)
    lag = int(tau / dt)
    rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert rho == pytest.approx(math.exp(-1.0), abs=0.08)


def test_baro_drift_is_slow_and_off_by_default():
    drift = BaroModel(BaroConfig(noise_std_m=0.0, drift_std_m=0.5, drift_time_constant_s=300.0), _rng(4))
    x = np.array([drift.sample(100.0)[0] - 100.0 for _ in range(2000)])   # 100 s at 20 Hz
    assert np.std(np.diff(x)) < 0.05 * 0.5            # consecutive samples nearly equal
    assert np.max(np.abs(x)) > 0.0
    plain = BaroModel(BaroConfig(noise_std_m=0.0), _rng(4))
    assert all(plain.sample(100.0)[0] == 100.0 for _ in range(10))


def test_baro_ground_effect_only_near_the_surface_with_rotors_on():
    model = BaroModel(BaroConfig(noise_std_m=0.0, ground_effect_m=-1.0, ground_effect_height_m=2.0), _rng())
    assert model.sample(0.0, 0.0, rotors_on=True)[0] == pytest.approx(-1.0)
    assert model.sample(1.0, 1.0, rotors_on=True)[0] == pytest.approx(1.0 - 0.5)
    assert model.sample(5.0, 5.0, rotors_on=True)[0] == pytest.approx(5.0)
    assert model.sample(0.0, 0.0, rotors_on=False)[0] == pytest.approx(0.0)


def test_imu_vibration_scales_with_throttle():
    cfg = ImuConfig(accel_noise_std_m_s2=0.05, accel_bias_std_m_s2=0.0, gyro_bias_std_rad_s=0.0,
                    vibration_accel_m_s2=1.0, vibration_gyro_rad_s=0.1)
    zero = np.zeros(3)

    def accel_std(throttle):
        imu = ImuModel(cfg, _rng(5))
        return np.std([imu.sample(zero, zero, 0.0, throttle)[0][0] for _ in range(8000)])

    assert accel_std(0.0) == pytest.approx(0.05, rel=0.1)
    assert accel_std(0.5) == pytest.approx(math.hypot(0.05, 0.5), rel=0.1)
    assert accel_std(1.0) == pytest.approx(math.hypot(0.05, 1.0), rel=0.1)


def test_sky_obstruction_near_a_tower_and_none_high_above():
    surface = _tower_surface(height_m=40.0)
    assert surface.sky_obstruction(np.array([25.0, 0.0, 2.0])) > 0.0
    assert surface.sky_obstruction(np.array([25.0, 0.0, 100.0])) == 0.0
    assert surface.height_at(40.0, 0.0) == 40.0 and surface.height_at(500.0, 0.0) == 0.0


def test_gps_multipath_grows_near_tall_buildings():
    surface = _tower_surface(height_m=40.0)
    cfg = GpsConfig(horizontal_noise_std_m=0.0, vertical_noise_std_m=0.0, velocity_noise_std_m_s=0.0,
                    multipath_std_m=3.0, multipath_time_constant_s=1.0)

    def horizontal_rms(pos):
        gps = GpsModel(cfg, _rng(6), surface)
        errs = []
        for _ in range(1500):
            f = gps.sample(pos, np.zeros(3), 0.0, 0.0)
            x, y = geodetic_to_enu(f.lat_deg, f.lon_deg, 0.0, 0.0)
            errs.append(math.hypot(float(x) - pos[0], float(y) - pos[1]) / math.sqrt(2.0))
        return float(np.sqrt(np.mean(np.square(errs))))

    near = np.array([25.0, 0.0, 2.0])
    high = np.array([25.0, 0.0, 100.0])
    expected = 3.0 * surface.sky_obstruction(near)
    assert horizontal_rms(near) == pytest.approx(expected, rel=0.2)
    assert horizontal_rms(high) == pytest.approx(0.0, abs=1e-6)   # open sky high above
