"""Horizontal acceleration limit with cross-track priority (control.limit_accel_xy) and the
along-track-only integrator freeze that goes with it: a vehicle at its lean limit across the wind
slows down along the track instead of drifting downwind (the known 1.9 m offset of a 150 m
crosswind leg at 10 m/s in 5 m/s wind; `scenenav bench autopilot`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.nav import nav_state as _nav

from autopilot_bridge.config import ControlConfig
from autopilot_bridge.control import FlightController, PositionTarget, limit_accel_xy


def test_within_the_limit_nothing_changes():
    assert limit_accel_xy(3.0, -2.0, 10.0, 0.0, 5.0) == (3.0, -2.0)


def test_cross_track_part_is_kept_and_along_track_gives_way():
    # track east; 4 m/s^2 along, 4 m/s^2 across (north), limit 5: across stays, along -> 3
    ax, ay = limit_accel_xy(4.0, 4.0, 10.0, 0.0, 5.0)
    assert ay == pytest.approx(4.0) and ax == pytest.approx(3.0)
    assert math.hypot(ax, ay) == pytest.approx(5.0)
    # braking keeps its sign
    ax, ay = limit_accel_xy(-4.0, -4.0, 10.0, 0.0, 5.0)
    assert ay == pytest.approx(-4.0) and ax == pytest.approx(-3.0)
    # the cross part alone is over the limit: it is cut, nothing left along
    ax, ay = limit_accel_xy(2.0, 7.0, 10.0, 0.0, 5.0)
    assert (ax, ay) == pytest.approx((0.0, 5.0))
    # diagonal track: same, rotated
    c = math.sqrt(0.5)
    ax, ay = limit_accel_xy(c * 4.0 - c * 4.0, c * 4.0 + c * 4.0, 7.0, 7.0, 5.0)
    assert (-ax * c + ay * c) == pytest.approx(4.0) and (ax * c + ay * c) == pytest.approx(3.0)


def test_hover_has_no_track_uniform_cut():
    ax, ay = limit_accel_xy(6.0, 8.0, 0.1, 0.0, 5.0)
    assert (ax, ay) == pytest.approx((3.0, 4.0))


def test_lean_limited_controller_keeps_the_cross_track_command():
    """At cruise with a large along-track demand, the crosswind accel survives the limit and its
    integrator keeps integrating while the along-track part is frozen."""
    cfg = ControlConfig()
    fc = FlightController(cfg)
    nav = _nav(position=(0.0, -1.0, 10.0), velocity=(5.0, 0.0, 0.0))   # 1 m south of an east track
    fc.reset(nav, landed=False)
    target = PositionTarget((0.0, 0.0, 10.0), velocity_enu_m_s=(10.0, 0.0, 0.0))
    i_before = None
    for _ in range(20):
        out = fc.update_position(nav, np.zeros(3), target, 0.01)
        if i_before is None:
            i_before = list(fc._vel_xy_i)
    a = out.accel_target_enu_m_s2
    assert out.lean_limited
    assert math.hypot(a[0], a[1]) == pytest.approx(cfg.max_accel_xy_m_s2, rel=1e-6)
    # cross-track: P on 1 m of position error through the velocity loop, undiminished
    assert a[1] > 1.5
    assert fc._vel_xy_i[1] > i_before[1]                 # across: still integrating
    assert fc._vel_xy_i[0] <= i_before[0] + 1e-9          # along: frozen (no growth)
