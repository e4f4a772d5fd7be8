"""Alignment at rest: enough samples for long enough, then the means (circular for the heading)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot_bridge.alignment import Alignment


def _fill(a: Alignment, seconds: float, gps: bool) -> None:
    for k in range(int(seconds * 100) + 1):
        t = k * 0.01
        a.add_imu(t, np.array([0.0, 0.0, 9.8]), np.array([0.001, 0.0, 0.0]))
        if k % 10 == 0:
            a.add_baro(2.0)
            a.add_heading(0.1 if k % 20 else 2.0 * math.pi - 0.1)   # either side of north
            if gps:
                a.add_gps((10.0, -4.0))


def test_alignment_waits_then_gives_the_means():
    a = Alignment()
    _fill(a, 0.5, gps=False)
    assert a.result(0.5, 1.0, 5.0, gps_source=False) is None         # too short
    _fill(a, 1.0, gps=False)
    r = a.result(1.0, 1.0, 5.0, gps_source=False)
    assert r is not None and r.gps_xy_enu_m is None and r.baro_alt_m == 2.0
    assert np.allclose(r.accel_flu_m_s2, [0.0, 0.0, 9.8]) and r.gyro_flu_rad_s[0] == pytest.approx(0.001)
    assert min(r.heading_rad, 2.0 * math.pi - r.heading_rad) < 0.05  # circular mean: north
    # GPS as the source: waits for fixes up to gps_wait_s, then aligns without them
    assert a.result(1.0, 1.0, 5.0, gps_source=True) is None
    assert a.result(1.0, 1.0, 0.5, gps_source=True).gps_xy_enu_m is None
    a.reset()
    _fill(a, 1.0, gps=True)
    assert a.result(1.0, 1.0, 5.0, gps_source=True).gps_xy_enu_m == (10.0, -4.0)
