"""Optical-flow fusion of the navigation filter (``NavFilter.fuse_optical_flow``, ArduPilot EKF3's
FuseOptFlow with the range finder's range).

The truth: a level vehicle hovering 20 m above flat ground, heading north, with no position aiding. Its
accelerometer has a horizontal bias the filter does not know (0.08 m/s^2 east, -0.05 m/s^2 north in
the world: a vibration offset, a temperature step), plus white noise. Dead reckoning turns the bias
into a velocity that grows without end; the flow module (10 Hz: the body-frame translation over the
range plus 0.05 rad/s of noise, already compensated for the zero body rate) shows it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot_bridge.config import EkfConfig
from autopilot_bridge.ekf import NavFilter
from scenenav.core.rotations import quat_from_euler_zyx, quat_to_rotation_matrix

G = 9.80665
DT = 0.01
HEIGHT_M = 20.0
VELOCITY = np.zeros(3)
ACCEL_BIAS_WORLD = np.array([0.08, -0.05, 0.0])
Q_NORTH = quat_from_euler_zyx(math.pi / 2, 0.0, 0.0)


def _flow(rng, noise=0.05, velocity=VELOCITY, height=HEIGHT_M):
    vb = quat_to_rotation_matrix(Q_NORTH).T @ velocity
    return np.array([-vb[1] / height, vb[0] / height]) + noise * rng.standard_normal(2)


def _fly(flow: bool, seconds: float = 20.0, seed: int = 1):
    rng = np.random.default_rng(seed)
    nav = NavFilter(EkfConfig())
    nav.initialise((0.0, 0.0, G), 0.0, HEIGHT_M, position_enu_m=(0.0, 0.0, HEIGHT_M), at_rest=False)
    accepted = rejected = 0
    late_velocities = []
    for k in range(int(seconds / DT)):
        accel = quat_to_rotation_matrix(Q_NORTH).T @ (np.array([0.0, 0.0, G]) + ACCEL_BIAS_WORLD)
        nav.predict(accel + 0.02 * rng.standard_normal(3), 0.001 * rng.standard_normal(3), DT)
        if k % 10 == 0:
            nav.fuse_baro(HEIGHT_M + 0.3 * rng.standard_normal())
            nav.fuse_compass(0.0)
            if flow:
                rx, ry = nav.fuse_optical_flow(_flow(rng), HEIGHT_M, 0.1, 3.0, 0.01 * HEIGHT_M)
                accepted += rx.accepted + ry.accepted
                rejected += (not rx.accepted) + (not ry.accepted)
            if k * DT >= seconds / 2:
                late_velocities.append(nav.state().velocity_enu_m_s[:2])
    truth = VELOCITY * seconds
    est = nav.state()
    mean_late = np.mean(late_velocities, axis=0)
    return mean_late, est, float(np.linalg.norm(est.position_enu_m[:2] - truth[:2])), accepted, rejected


def test_flow_teaches_the_filter_its_drift():
    """Each sample is a 2 m/s-wide look at the velocity (0.1 rad/s x 20 m) and the velocity random-walks
    with the accelerometer noise between samples, so the estimate wanders by a few tenths of a m/s;
    its mean over the second half of the flight is the truth, zero."""
    mean_late, _, err, accepted, rejected = _fly(True, seconds=40.0)
    assert accepted > 700 and rejected < 40
    assert np.allclose(mean_late, VELOCITY[:2], atol=0.4), mean_late       # 0.3 at worst over seeds 1-6
    assert err < 10.0, err


def test_without_flow_the_bias_runs_away():
    mean_late, _, err, _, _ = _fly(False, seconds=40.0)
    assert np.linalg.norm(mean_late) > 1.5                 # 0.094 m/s^2 x 20..40 s
    assert err > 40.0, err                                 # 0.5 x 0.094 x 40^2 = 75 m


def test_a_flow_far_off_the_prediction_is_gated_out():
    nav = NavFilter(EkfConfig())
    nav.initialise((0.0, 0.0, G), 0.0, HEIGHT_M, position_enu_m=(0.0, 0.0, HEIGHT_M), at_rest=False)
    rx, ry = nav.fuse_optical_flow((2.0, -2.0), HEIGHT_M, 0.1, 3.0)     # 40 m/s at 20 m
    assert not rx.accepted and not ry.accepted
    assert rx.test_ratio > 1.0
    assert np.allclose(nav.state().velocity_enu_m_s, 0.0)


@pytest.mark.parametrize("rate, range_m", [((math.nan, 0.1), 20.0), ((0.1, 0.1), math.nan), ((0.1, 0.1), 0.0)])
def test_unusable_samples_change_nothing(rate, range_m):
    nav = NavFilter(EkfConfig())
    nav.initialise((0.0, 0.0, G), 0.0, HEIGHT_M, position_enu_m=(0.0, 0.0, HEIGHT_M), at_rest=False)
    before = nav.covariance().copy()
    rx, ry = nav.fuse_optical_flow(rate, range_m, 0.1, 3.0)
    assert not rx.accepted and not ry.accepted
    assert np.array_equal(nav.covariance(), before)
