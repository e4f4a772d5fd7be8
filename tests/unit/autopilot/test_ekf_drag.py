"""Drag fusion of the navigation filter (``NavFilter.fuse_drag``, EK3_DRAG_*) on a steady flight in wind.

The truth: a multicopter flying east at 10 m/s in a 4 m/s wind from the south-west, tilted so that its
thrust balances the drag of the model the filter assumes (momentum and bluff-body terms). The IMU reads
that specific force plus white noise, the gyro zero plus white noise; GPS positions at 5 Hz for the
first minute, then none. After the GPS stops, the accelerometer's x bias jumps by 0.1 m/s^2 (a
vibration-induced offset, a temperature step): the filter knows nothing of it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot_bridge.config import EkfConfig
from autopilot_bridge.ekf import NUM_ERROR_STATES, NavFilter
from scenenav.core.config import ConfigError
from scenenav.core.rotations import heading_from_quat, quat_from_euler_zyx, quat_to_rotation_matrix

G = 9.80665
DT = 0.01
MCOEF = 0.17          # the Iris's rotor drag: c_D sum(omega) / m (sitl.vehicle), 1/s
BCOEF = 29.0          # the Iris's body: m / (Cd A), kg/m^2
RHO = 1.225
GROUND_VELOCITY = np.array([10.0, 0.0, 0.0])
WIND = np.array([3.0, 2.5, 0.0])
DRAG_PERIOD_S = 0.1
DRAG_ON_S = 10.0


def _drag(va: np.ndarray) -> np.ndarray:
    speed = float(np.linalg.norm(va))
    return -(MCOEF + 0.5 * RHO * speed / BCOEF) * va


def _steady_attitude(heading_rad: float = math.pi / 2):
    """Attitude and body specific force of unaccelerated flight: R f = (0, 0, g), f_xy = drag(R^T air)."""
    f = np.array([0.0, 0.0, G])
    air = GROUND_VELOCITY - WIND
    for _ in range(50):
        roll = math.atan2(f[1], f[2])
        pitch = math.atan2(-f[0], math.hypot(f[1], f[2]))
        q = quat_from_euler_zyx(math.pi / 2 - heading_rad, pitch, roll)
        rot = quat_to_rotation_matrix(q)
        d = _drag(rot.T @ air)
        f = rot.T @ np.array([0.0, 0.0, G])
        f = np.array([d[0], d[1], math.sqrt(max(G * G - d[0] ** 2 - d[1] ** 2, 1.0))])
    return q, f


def _fly(drag: bool, seconds_gps: float = 60.0, seconds_dark: float = 60.0, seed: int = 3):
    """Return (position error at the end m, wind estimate, filter)."""
    rng = np.random.default_rng(seed)
    q, f = _steady_attitude()
    nav = NavFilter(EkfConfig())
    nav.initialise(f, heading_from_quat(q), 100.0, position_enu_m=(0.0, 0.0, 100.0), at_rest=False)
    p = np.array([0.0, 0.0, 100.0])
    bias = np.zeros(3)
    acc_sum, acc_t = np.zeros(3), 0.0
    steps = int(round((seconds_gps + seconds_dark) / DT))
    for k in range(steps):
        t = k * DT
        if drag and k == int(round(DRAG_ON_S / DT)):
            # the filter starts at rest (v = 0) in the air: drag fusion is switched on (EK3_DRAG_*
            # set) once GPS has taught it the velocity, as it would start at a take-off from rest
            nav.set_drag_model(ballistic_x_kg_m2=BCOEF, ballistic_y_kg_m2=BCOEF, momentum_per_s=MCOEF,
                               noise_m_s2=0.5, wind_noise_m_s2_per_rt_hz=0.05)
        if t >= seconds_gps:
            bias = np.array([0.1, 0.0, 0.0])
        accel = f + bias + rng.normal(0.0, 0.05, 3)
        gyro = rng.normal(0.0, 0.001, 3)
        p = p + GROUND_VELOCITY * DT
        nav.predict(accel, gyro, DT)
        if k % 5 == 0:
            nav.fuse_baro(float(p[2]) + rng.normal(0.0, 0.3))
            nav.fuse_compass(heading_from_quat(q) + rng.normal(0.0, 0.01))
        if t < seconds_gps and k % 20 == 0:
            nav.fuse_gps_position(p + np.append(rng.normal(0.0, 0.5, 2), 0.0), 0.5)
            nav.fuse_gps_velocity(GROUND_VELOCITY + rng.normal(0.0, 0.1, 3), 0.1)
        acc_sum += accel * DT
        acc_t += DT
        if acc_t >= DRAG_PERIOD_S - 1e-9:  # fusion.SensorFusionMixin._drag_fusion's averaging
            nav.fuse_drag(acc_sum / acc_t)
            acc_sum, acc_t = np.zeros(3), 0.0
    s = nav.state()
    return float(np.hypot(*(s.position_enu_m[:2] - p[:2]))), s.wind_enu_m_s, nav


def test_drag_fusion_learns_the_wind_while_fixes_come_in():
    _, wind, nav = _fly(drag=True, seconds_dark=0.0)
    assert np.allclose(wind, WIND[:2], atol=0.5), wind
    assert nav.covariance().shape == (NUM_ERROR_STATES, NUM_ERROR_STATES)
    assert math.sqrt(nav.covariance()[15, 15]) < 1.0


def test_drag_fusion_bounds_dead_reckoning_after_an_accelerometer_bias_step():
    err_drag, _, _ = _fly(drag=True)
    err_plain, wind_plain, _ = _fly(drag=False)
    # without drag the 0.1 m/s^2 step integrates to ~180 m in 60 s; with it the velocity stays tied
    # to the air (an error of about step / drag slope, ~0.2 m/s)
    assert err_plain > 100.0
    assert err_drag < 0.2 * err_plain, (err_drag, err_plain)
    assert np.all(wind_plain == 0.0)


def test_drag_off_leaves_the_wind_states_untouched():
    nav = NavFilter(EkfConfig())
    q, f = _steady_attitude()
    nav.initialise(f, heading_from_quat(q), 100.0, position_enu_m=(0.0, 0.0, 100.0))
    for _ in range(100):
        nav.predict(f, np.zeros(3), DT)
    rx, ry = nav.fuse_drag(f)
    assert not rx.accepted and not ry.accepted
    P = nav.covariance()
    assert np.all(P[15:, :15] == 0.0) and np.all(P[15:, 15:] <= 1e-12)


def test_switching_drag_fusion_on_opens_the_wind():
    nav = NavFilter(EkfConfig())
    q, f = _steady_attitude()
    nav.initialise(f, heading_from_quat(q), 100.0, position_enu_m=(0.0, 0.0, 100.0))
    nav.set_drag_model(ballistic_x_kg_m2=BCOEF, ballistic_y_kg_m2=BCOEF, momentum_per_s=MCOEF,
                       noise_m_s2=0.5, wind_noise_m_s2_per_rt_hz=0.02)
    assert nav.config.drag_fusion
    assert nav.covariance()[15, 15] == pytest.approx(nav.config.initial_wind_std_m_s ** 2)
    with pytest.raises(ConfigError, match="drag_momentum_coef_per_s"):
        nav.set_drag_model(ballistic_x_kg_m2=0.0, ballistic_y_kg_m2=0.0, momentum_per_s=-1.0,
                           noise_m_s2=0.5, wind_noise_m_s2_per_rt_hz=0.02)
