"""The compass heading's bias state of the navigation filter (``NavFilter.set_compass_bias_model``,
SN_MAG_BIAS_SD / SN_MAG_BIAS_TURN).

The truth: a level vehicle flying at 10 m/s, 100 m up, east for 90 s, then turning left at 0.3 rad/s
onto north for another 90 s. Its compass reads the heading plus a deviation that depends on the
heading (+5 deg heading east, -4 deg heading north: residual hard iron) and a little white noise.
Vision fixes (1.5 m, 5 Hz) and a downward flow (1 m/s at 100 m, 10 Hz) aid it, as in a GPS-denied
flight. The filter's heading should follow the truth, not the compass.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot_bridge.config import EkfConfig, PositionSource
from autopilot_bridge.ekf import NUM_ERROR_STATES, NavFilter
from scenenav.core.config import ConfigError
from scenenav.core.frames import wrap_pi
from scenenav.core.rotations import heading_from_quat, quat_from_euler_zyx, quat_to_rotation_matrix

G = 9.80665
DT = 0.01
SPEED_M_S = 10.0
HEIGHT_M = 100.0
LEG_S = 90.0
TURN_RATE_RAD_S = 0.3
BIAS_EAST_RAD = math.radians(5.0)
BIAS_NORTH_RAD = math.radians(-4.0)


def _deviation(yaw_rad: float) -> float:
    """The compass's error at a yaw (ENU, 0 = east): +5 deg east, -4 deg north, smooth between."""
    s = min(max(yaw_rad / (math.pi / 2), 0.0), 1.0)
    return BIAS_EAST_RAD + s * (BIAS_NORTH_RAD - BIAS_EAST_RAD)


def _fly(bias_sd_rad: float, seed: int = 4):
    """Fly both legs; returns the heading errors (deg) sampled per second and the filter, and the
    bias 1-sigma just before and just after the turn."""
    rng = np.random.default_rng(seed)
    nav = NavFilter(EkfConfig(position_source=PositionSource.EXTNAV))
    nav.set_compass_noise(0.1)
    nav.set_compass_bias_model(bias_sd_rad, 0.07)
    yaw = 0.0
    q = quat_from_euler_zyx(yaw, 0.0, 0.0)
    nav.initialise((0.0, 0.0, G), heading_from_quat(q) + _deviation(yaw), HEIGHT_M,
                   position_enu_m=(0.0, 0.0, HEIGHT_M), at_rest=False)
    p = np.array([0.0, 0.0, HEIGHT_M])
    # start moving: the filter is told the initial velocity by a few fixes' worth of prior
    nav._v = [SPEED_M_S, 0.0, 0.0]
    errors = []
    std_before = std_after = math.nan
    turn_s = math.pi / 2 / TURN_RATE_RAD_S
    total = 2 * LEG_S + turn_s
    n = int(round(total / DT))
    for k in range(n):
        t = k * DT
        w = TURN_RATE_RAD_S if LEG_S <= t < LEG_S + turn_s else 0.0
        yaw_mid = yaw + 0.5 * w * DT
        v_mid = SPEED_M_S * np.array([math.cos(yaw_mid), math.sin(yaw_mid), 0.0])
        accel_world = w * SPEED_M_S * np.array([-math.sin(yaw_mid), math.cos(yaw_mid), 0.0])
        rot_mid = quat_to_rotation_matrix(quat_from_euler_zyx(yaw_mid, 0.0, 0.0))
        f_body = rot_mid.T @ (accel_world + np.array([0.0, 0.0, G]))
        nav.predict(f_body + 0.02 * rng.standard_normal(3), (0.0, 0.0, w), DT)
        p = p + v_mid * DT
        yaw += w * DT
        q = quat_from_euler_zyx(yaw, 0.0, 0.0)
        step = k + 1
        if step % 10 == 0:      # 10 Hz: compass and flow
            nav.fuse_compass(heading_from_quat(q) + _deviation(yaw) + 0.005 * rng.standard_normal())
            vb = quat_to_rotation_matrix(q).T @ (SPEED_M_S * np.array([math.cos(yaw), math.sin(yaw), 0.0]))
            flow = np.array([-vb[1], vb[0]]) / HEIGHT_M + 0.01 * rng.standard_normal(2)
            nav.fuse_optical_flow(flow, HEIGHT_M, 0.01, 5.0)
        if step % 20 == 0:      # 5 Hz: vision fixes
            nav.fuse_vision_position(p[:2] + 1.5 * rng.standard_normal(2), np.eye(2) * 1.5 ** 2)
        if step % 100 == 0:
            errors.append(math.degrees(wrap_pi(nav.state().heading_rad - heading_from_quat(q))))
        if abs(t - (LEG_S - DT)) < DT / 2:
            std_before = math.sqrt(nav.covariance()[17, 17])
        if abs(t - (LEG_S + turn_s)) < DT / 2:
            std_after = math.sqrt(nav.covariance()[17, 17])
    return np.array(errors), nav, std_before, std_after


@pytest.fixture(scope="module")
def with_state():
    return _fly(0.1)


@pytest.fixture(scope="module")
def without_state():
    return _fly(0.0)


def test_without_the_bias_state_the_heading_follows_the_compass(without_state):
    errors, nav, _, _ = without_state
    leg1 = errors[60:89]                 # the last 30 s heading east
    assert np.mean(leg1) > 3.0           # taken for the heading: most of the +5 deg
    assert nav.state().compass_bias_rad == 0.0
    P = nav.covariance()
    assert P.shape == (NUM_ERROR_STATES, NUM_ERROR_STATES)
    assert not P[17].any() and not P[:, 17].any()     # the state is off: never corrected


def test_the_bias_state_learns_the_deviation_on_each_leg(with_state, without_state):
    errors, nav, _, _ = with_state
    leg1 = errors[60:89]
    leg2 = errors[-30:]
    assert abs(np.mean(leg1)) < 1.5
    assert abs(np.mean(leg2)) < 1.5
    # the learnt bias is the heading-north deviation after the second leg
    assert abs(math.degrees(nav.state().compass_bias_rad) - math.degrees(BIAS_NORTH_RAD)) < 1.5
    assert np.mean(np.abs(leg2)) < 0.5 * np.mean(np.abs(without_state[0][-30:]))


def test_the_bias_uncertainty_opens_with_the_turn_and_is_capped(with_state):
    _, nav, before, after = with_state
    assert after > 1.5 * before
    assert math.sqrt(nav.covariance()[17, 17]) <= 0.1 + 1e-9


def test_switching_the_state_on_in_flight_opens_it_and_off_clears_it():
    nav = NavFilter(EkfConfig())
    nav.initialise((0.0, 0.0, G), 0.3, 10.0, position_enu_m=(0.0, 0.0, 10.0))
    assert nav.covariance()[17, 17] == 0.0
    nav.set_compass_bias_model(0.1, 0.07)
    assert nav.covariance()[17, 17] == pytest.approx(0.01)
    for _ in range(50):
        nav.predict((0.0, 0.0, G), (0.0, 0.0, 0.0), DT)
        nav.fuse_compass(0.35)
    assert nav.state().compass_bias_rad != 0.0
    nav.set_compass_bias_model(0.0, 0.07)
    assert nav.state().compass_bias_rad == 0.0
    assert not nav.covariance()[17].any()


def test_a_negative_bias_prior_is_refused():
    with pytest.raises(ConfigError, match="compass_bias_std_rad"):
        EkfConfig(compass_bias_std_rad=-0.1)
