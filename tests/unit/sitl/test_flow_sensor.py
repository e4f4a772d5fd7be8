"""The optical-flow module (``sitl.sensors.FlowModel``, ``FlowSample``): flow and range along body -z.

Sign convention (``scenenav.core.contracts.FlowSample``): the flow is the apparent angular velocity of
the surface point on the axis, (-vy / r - wx, vx / r - wy) in body FLU; the range reaches the first
roof or the ground; outside the range finder's limits the sample carries NaN and quality 0.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from scenenav.core.rotations import quat_from_euler_zyx
from sitl.config import FlowConfig
from sitl.core import SimulatorCore
from sitl.sensors import FlowModel
from sitl.surroundings import Surface

MPP = 0.5
LEVEL_NORTH = quat_from_euler_zyx(math.pi / 2, 0.0, 0.0)   # body x = north, body y = west
EXACT = FlowConfig(enabled=True, noise_std_rad_s=0.0, scale_error_std=0.0, gyro_noise_std_rad_s=0.0,
                   range_noise_fraction=0.0)


def _tower() -> Surface:
    """A 200 m x 200 m map, one 20 m building of 20 m x 20 m at its centre."""
    dsm = np.zeros((400, 400), np.float32)
    dsm[180:220, 180:220] = 20.0
    return Surface(dsm, dsm > 0, MPP)


def test_forward_flight_over_flat_ground_gives_plus_y_flow():
    m = FlowModel(EXACT, np.random.default_rng(0))
    f = m.sample((0.0, 0.0, 25.0), (0.0, 5.0, 0.0), LEVEL_NORTH, (0.0, 0.0, 0.0))   # 5 m/s north = forward
    assert f.distance_m == pytest.approx(25.0)
    assert f.flow_flu_rad_s == pytest.approx((0.0, 5.0 / 25.0))
    assert f.quality == 255


def test_sideways_motion_and_rotation():
    m = FlowModel(EXACT, np.random.default_rng(0))
    # moving east = body right (vy < 0 in FLU) and rolling right (wx > 0)
    f = m.sample((0.0, 0.0, 10.0), (2.0, 0.0, 0.0), LEVEL_NORTH, (0.3, 0.0, 0.0))
    assert f.flow_flu_rad_s[0] == pytest.approx(2.0 / 10.0 - 0.3)
    assert f.body_rate_flu_rad_s == pytest.approx((0.3, 0.0))
    comp = f.flow_flu_rad_s[0] + f.body_rate_flu_rad_s[0]
    assert comp == pytest.approx(0.2)          # the translation's part alone


def test_tilt_lengthens_the_range_on_flat_ground():
    m = FlowModel(EXACT, np.random.default_rng(0))
    tilted = quat_from_euler_zyx(math.pi / 2, math.radians(20.0), 0.0)
    assert m.true_range_m((0.0, 0.0, 20.0), tilted) == pytest.approx(20.0 / math.cos(math.radians(20.0)))


def test_the_range_finder_sees_the_roof_and_the_flow_scales_with_it():
    m = FlowModel(EXACT, np.random.default_rng(0), _tower())
    over_roof = m.sample((0.0, 0.0, 30.0), (0.0, 5.0, 0.0), LEVEL_NORTH, (0.0, 0.0, 0.0))
    beside = m.sample((60.0, 0.0, 30.0), (0.0, 5.0, 0.0), LEVEL_NORTH, (0.0, 0.0, 0.0))
    assert over_roof.distance_m == pytest.approx(10.0)
    assert beside.distance_m == pytest.approx(30.0)
    assert over_roof.flow_flu_rad_s[1] == pytest.approx(0.5)
    assert beside.flow_flu_rad_s[1] == pytest.approx(5.0 / 30.0)


@pytest.mark.parametrize("height_m", [0.0, 0.05, 31.0])
def test_out_of_range_gives_nan_and_no_quality(height_m):
    m = FlowModel(EXACT, np.random.default_rng(0))
    f = m.sample((0.0, 0.0, height_m), (1.0, 0.0, 0.0), LEVEL_NORTH, (0.0, 0.0, 0.0))
    assert math.isnan(f.distance_m) and all(math.isnan(v) for v in f.flow_flu_rad_s)
    assert f.quality == 0


def test_noise_and_scale_error_are_seeded_and_of_the_configured_size():
    cfg = FlowConfig(enabled=True)
    a = FlowModel(cfg, np.random.default_rng(7))
    b = FlowModel(cfg, np.random.default_rng(7))
    flows = np.array([a.sample((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), LEVEL_NORTH, (0.0, 0.0, 0.0)).flow_flu_rad_s
                      for _ in range(2000)])
    again = np.array([b.sample((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), LEVEL_NORTH, (0.0, 0.0, 0.0)).flow_flu_rad_s
                      for _ in range(2000)])
    assert np.array_equal(flows, again)
    assert np.std(flows, axis=0) == pytest.approx([cfg.noise_std_rad_s] * 2, rel=0.1)
    assert np.any(a.scale != 1.0)


def test_the_simulator_publishes_it_at_its_rate_only_when_enabled():
    from sitl.config import SimConfig
    on = dataclasses.replace(SimConfig(), flow=FlowConfig(enabled=True, rate_hz=10.0))
    core = SimulatorCore(on, 100.0, 1, 48.1, 11.5)
    off = SimulatorCore(SimConfig(), 100.0, 1, 48.1, 11.5)
    try:
        core.start_at(np.zeros(3), math.pi / 2)
        off.start_at(np.zeros(3), math.pi / 2)
        samples = []
        for _ in range(50):
            out = core.sense()
            assert off.sense().flow is None
            if out.flow is not None:
                samples.append(out.flow)
            core.advance(np.zeros(4))
            off.advance(np.zeros(4))
        assert len(samples) == 5
        assert all(s.integration_time_us == 100_000 for s in samples)
        assert all(math.isnan(s.distance_m) and s.quality == 0 for s in samples)   # on the ground
    finally:
        core.close()
        off.close()
