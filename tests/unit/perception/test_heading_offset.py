"""Learning the compass heading error from the matches (perception.heading_offset, the pipeline's
``heading_offset`` config): hand-checked pieces, then a biased compass over the synthetic world."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_pipeline import ALT, render

from perception.config import PerceptionConfig, PerceptionNodeConfig
from perception.heading_offset import (
    HeadingDeviation,
    HeadingOffsetConfig,
    parabola_vertex,
    rotation_peaks,
)
from perception.pipeline import PerceptionPipeline
from scenenav.core.config import ConfigError

RAD = math.radians


def test_parabola_vertex_hand_checked():
    # f(x) = -(x - 1)^2 sampled at -2, 0, 2: vertex at 1
    assert parabola_vertex(-9.0, -1.0, -1.0, 2.0) == pytest.approx(1.0)
    assert parabola_vertex(0.5, 1.0, 0.5, 4.0) == pytest.approx(0.0)          # symmetric
    # the maximum lies beyond the probes: clipped to the probe on that side
    assert parabola_vertex(0.1, 0.5, 0.9, 4.0) == pytest.approx(4.0)
    assert parabola_vertex(0.9, 0.5, 0.1, 4.0) == pytest.approx(-4.0)
    # a minimum in the middle is no measurement
    assert parabola_vertex(0.9, 0.1, 0.9, 4.0) is None
    assert parabola_vertex(math.nan, 0.5, 0.4, 4.0) is None


def test_deviation_card_sectors_and_weights():
    dev = HeadingDeviation(HeadingOffsetConfig(enabled=True, sector_deg=30.0, gain=0.25))
    assert not dev.known(RAD(100)) and dev.correction_rad(RAD(100)) == 0.0
    dev.update(RAD(105), RAD(7.0))                  # first measurement of a sector: taken as it is
    assert dev.correction_rad(RAD(105)) == pytest.approx(RAD(7.0))
    # a neighbouring sector without an estimate does not pull the correction towards 0
    assert dev.correction_rad(RAD(92)) == pytest.approx(RAD(7.0))
    assert dev.known(RAD(130)) and not dev.known(RAD(140)) and dev.correction_rad(RAD(285)) == 0.0
    dev.update(RAD(75), RAD(3.0))
    # half-way between the two sector centres (75 and 105): the mean of the two estimates
    assert dev.correction_rad(RAD(90)) == pytest.approx(RAD(5.0))
    # later measurements are averaged with gain max(1 / (n + 1), 0.25): 1/2, 1/3, then 0.25
    dev.update(RAD(105), RAD(9.0))
    assert dev.offset_rad[3] == pytest.approx(RAD(8.0))
    dev.update(RAD(105), RAD(12.0))
    dev.update(RAD(105), RAD(12.0))
    assert dev.offset_rad[3] == pytest.approx(RAD(12.0 - 4.0 * (2.0 / 3.0) * 0.75))
    # across north: 355 and 5 degrees are neighbours
    dev.update(RAD(350), RAD(-4.0))
    assert dev.correction_rad(RAD(5)) == pytest.approx(RAD(-4.0))
    dev.reset()
    assert dev.correction_rad(RAD(105)) == 0.0 and dev.measurements == 0


def test_every_n_th_qualifying_frame_is_measured():
    dev = HeadingDeviation(HeadingOffsetConfig(enabled=True, learn_every_n=3, warmup_measurements=2))
    h = RAD(50.0)
    assert [dev.due(h) for _ in range(3)] == [True, True, True]       # the sector is still warming up
    dev.update(h, 0.01)
    dev.update(h, 0.01)
    assert [dev.due(h) for _ in range(6)] == [True, False, False, True, False, False]
    assert dev.due(RAD(200.0))                                           # another sector: warm-up


def test_learned_correction_is_clipped():
    dev = HeadingDeviation(HeadingOffsetConfig(enabled=True, max_offset_deg=10.0))
    dev.update(RAD(45), RAD(30.0))
    assert dev.correction_rad(RAD(45)) == pytest.approx(RAD(10.0))


def test_config_checks():
    with pytest.raises(ConfigError):
        HeadingOffsetConfig(sector_deg=25.0)             # does not divide 360
    with pytest.raises(ConfigError):
        HeadingOffsetConfig(seed_offsets_deg=(-30.0, 30.0))
    with pytest.raises(ConfigError):
        HeadingOffsetConfig(gain=0.0)


def test_rotation_peaks_prefer_the_right_rotation(world):
    ref_rgb, day = world
    reference = ref_rgb[:, :, 0].astype(np.float32) / 255.0
    u, v, heading = 330.0, 210.0, RAD(30.0)
    pipe = PerceptionPipeline(ref_rgb, 0.5, "none")
    image = render(day, u, v, heading)
    peaks = []
    for d in (-4.0, 0.0, 4.0):
        from perception.alignment import align_capture
        a = align_capture(image, heading + RAD(d), ALT, 60.0, 0.5)
        peaks.append(a.template)
    vals = rotation_peaks(reference, peaks, [(u, v)] * 3, 6)
    assert vals[1] > vals[0] and vals[1] > vals[2]
    assert abs(parabola_vertex(*vals, 4.0)) < 1.0
    # a window that leaves the map gives NaN, not an exception
    assert all(math.isnan(x) for x in rotation_peaks(reference, peaks, [(5.0, 5.0)] * 3, 6))
    del pipe


def _fly_biased(world, learning: bool, bias_deg: float, n: int = 60):
    ref_rgb, day = world
    cfg = PerceptionConfig(heading_offset=HeadingOffsetConfig(enabled=learning, min_template_px=48,
                                                              min_run=3, learn_every_n=2,
                                                              warmup_measurements=5))
    pipe = PerceptionPipeline(ref_rgb, 0.5, "none", cfg)
    heading = RAD(20.0)
    errors = []
    for k in range(n):
        u, v = 300.0 + 2.0 * k, 150.0 + 0.5 * k
        res = pipe.process(render(day, u, v, heading), heading + RAD(bias_deg), ALT, 0.1 * k,
                           prior_enu_m=pipe.matcher.pixel_to_world(u, v))
        errors.append(math.hypot(res.position_px[0] - u, res.position_px[1] - v) * 0.5)
    return pipe, np.array(errors)


def test_a_biased_compass_is_learned_and_the_fixes_improve(world):
    bias = 6.0
    pipe, err_on = _fly_biased(world, True, bias)
    dev = pipe.heading_deviation
    assert dev is not None and dev.measurements > 10
    assert dev.measurements <= 35                 # every second qualifying frame after 5
    # the correction undoes the compass error (the learned value is minus the bias)
    assert math.degrees(dev.correction_rad(RAD(20.0 + bias))) == pytest.approx(-bias, abs=1.5)
    _, err_off = _fly_biased(world, False, bias)
    late = slice(30, None)
    assert np.sqrt(np.mean(err_on[late] ** 2)) < 0.7 * np.sqrt(np.mean(err_off[late] ** 2))


def test_the_measured_heading_is_published_with_the_fix(world):
    """The frames the heading is measured on carry the heading the map says (VisionFix v2): within
    a degree of the true one although the compass is 6 degrees off; the others carry NaN."""
    ref_rgb, day = world
    cfg = PerceptionConfig(heading_offset=HeadingOffsetConfig(enabled=True, min_template_px=48,
                                                              min_run=3, learn_every_n=2,
                                                              warmup_measurements=5))
    pipe = PerceptionPipeline(ref_rgb, 0.5, "none", cfg)
    true_heading, bias = RAD(20.0), RAD(6.0)
    measured, unmeasured = [], 0
    for k in range(40):
        u, v = 300.0 + 2.0 * k, 150.0 + 0.5 * k
        res = pipe.process(render(day, u, v, true_heading), true_heading + bias, ALT, 0.1 * k,
                           prior_enu_m=pipe.matcher.pixel_to_world(u, v))
        if math.isfinite(res.heading_rad):
            measured.append(math.degrees(res.heading_rad))
        else:
            unmeasured += 1
    assert len(measured) >= 10 and unmeasured >= 5
    errors = np.array(measured[3:]) - 20.0          # the first ones may sit at the probe's edge
    assert np.sqrt(np.mean(errors ** 2)) < 1.0, errors


def test_learning_off_is_the_plain_pipeline(world):
    ref_rgb, day = world
    a = PerceptionPipeline(ref_rgb, 0.5, "none")
    assert a.heading_deviation is None
    b = PerceptionPipeline(ref_rgb, 0.5, "none", PerceptionConfig())
    image = render(day, 320.0, 200.0, 0.3)
    ra, rb = a.process(image, 0.3, ALT, 0.0), b.process(image, 0.3, ALT, 0.0)
    assert ra.position_px == rb.position_px


def test_node_pipeline_factory_passes_the_scenario_key(world):
    from types import SimpleNamespace

    from perception.node import make_pipeline
    ref_rgb, _ = world
    w = SimpleNamespace(reference_map=lambda kind: ref_rgb, m_per_px=0.5)
    assert make_pipeline(w, PerceptionNodeConfig(heading_learning=True)).heading_deviation is not None
    assert make_pipeline(w, PerceptionNodeConfig()).heading_deviation is None


def test_realistic_profile_learns_the_heading():
    from scenenav.app.scenario import load_scenario
    assert load_scenario(None, ("realism=realistic",)).perception.heading_learning
    assert not load_scenario(None, ("realism=paper",)).perception.heading_learning
