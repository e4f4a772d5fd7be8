"""Scripted (kinematic) trajectories: constant speed, continuous velocity, right headings."""

import math

import numpy as np
import pytest

from sitl.scripted import ScriptedTrajectory


def test_square_loop_speed_and_heading():
    tr = ScriptedTrajectory([(0, 0), (100, 0), (100, 100)], 50.0, 10.0, 20.0)
    s0 = tr.state(0.0)
    assert np.allclose(s0.position_enu_m, [0, 0, 50])
    assert math.isclose(s0.heading_rad, math.pi / 2, abs_tol=1e-9)      # east
    assert tr.length_m < 200.0                                           # corner cut by the arc
    prev = None
    for t in np.arange(0, tr.duration_s, 0.05):
        s = tr.state(t)
        assert math.isclose(np.linalg.norm(s.velocity_enu_m_s), 10.0, rel_tol=1e-6)
        if prev is not None:   # continuity: no jumps in position
            assert np.linalg.norm(s.position_enu_m - prev.position_enu_m) < 0.6
        prev = s
    end = tr.state(tr.duration_s - 1e-6)
    assert np.allclose(end.position_enu_m[:2], [100, 100], atol=0.01)
    assert math.isclose(end.heading_rad, 0.0, abs_tol=1e-6) or math.isclose(end.heading_rad, 2 * math.pi, abs_tol=1e-6)


def test_left_turn_has_centripetal_acceleration_and_negative_heading_rate():
    tr = ScriptedTrajectory([(0, 0), (100, 0), (100, 100)], 50.0, 10.0, 20.0)
    # mid-arc: the turn from east to north is a left (counter-clockwise) turn
    t_mid = (100 - 20) / 10 + (math.pi / 2 * 20 / 10) / 2
    s = tr.state(t_mid)
    assert math.isclose(np.linalg.norm(s.acceleration_enu_m_s2), 100 / 20, rel_tol=1e-6)
    assert s.yaw_rate_rad_s < 0


def test_bad_input():
    with pytest.raises(ValueError):
        ScriptedTrajectory([(0, 0)], 50, 10, 10)
    with pytest.raises(ValueError):
        ScriptedTrajectory([(0, 0), (1, 1)], 50, 0, 10)
