"""The gradient refinement of the match position (MatcherConfig.gradient_refine_radius_px)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_matcher import M_PER_PX, crop, texture

from perception.config import MatcherConfig, PerceptionConfig
from perception.ncc_search import SceneMatcher, gradient_magnitude
from scenenav.core.config import ConfigError

SIDE = 80


@pytest.fixture(scope="module")
def ref() -> np.ndarray:
    return texture(300, 400, seed=3)


def _truth_uv(x0: int, y0: int) -> tuple[float, float]:
    return x0 + SIDE / 2.0, y0 + SIDE / 2.0


def test_off_by_default_and_when_zero(ref):
    assert MatcherConfig().gradient_refine_radius_px == 0
    m = SceneMatcher(ref, M_PER_PX).match(crop(ref, 150, 100, SIDE), (190.0, 140.0), 10)
    assert math.isnan(m.gradient_shift_px)


def test_exact_match_stays_exact(ref):
    cfg = MatcherConfig(gradient_refine_radius_px=12)
    m = SceneMatcher(ref, M_PER_PX, cfg).match(crop(ref, 150, 100, SIDE), (195.0, 133.0), 10)
    u, v = _truth_uv(150, 100)
    assert math.isfinite(m.gradient_shift_px) and m.gradient_shift_px < 0.2
    assert math.hypot(m.position_px[0] - u, m.position_px[1] - v) < 0.2
    x, y = SceneMatcher(ref, M_PER_PX).pixel_to_world(*m.position_px)
    assert m.position_enu_m == pytest.approx((x, y))


def test_shading_pulls_intensity_not_gradient(ref):
    """A smooth illumination ramp over the template (another day's light) moves the intensity NCC
    peak of a blurry texture; the gradient peak, on the texture's edges, stays closer to the truth."""
    sharp = np.clip(ref + 0.6 * (texture(300, 400, seed=4, sigma=0.7) - 0.5), 0.0, 1.0).astype(np.float32)
    tpl = crop(sharp, 150, 100, SIDE).copy()
    yy, xx = np.mgrid[0:SIDE, 0:SIDE].astype(np.float32)
    tpl *= 0.55 + 0.9 * (xx / SIDE) ** 2              # dark on the left, bright on the right
    tpl = np.ascontiguousarray(tpl, dtype=np.float32)
    u, v = _truth_uv(150, 100)
    plain = SceneMatcher(sharp, M_PER_PX).match(tpl, (u, v), 10)
    refined = SceneMatcher(sharp, M_PER_PX, MatcherConfig(gradient_refine_radius_px=10)).match(tpl, (u, v), 10)
    err = lambda m: math.hypot(m.position_px[0] - u, m.position_px[1] - v)   # noqa: E731
    assert err(refined) < 0.5
    assert err(refined) <= err(plain)
    # the metrics and covariance are the intensity search's
    assert (refined.peak, refined.psr, refined.second_peak_ratio) == (plain.peak, plain.psr,
                                                                     plain.second_peak_ratio)
    np.testing.assert_array_equal(refined.covariance_m2, plain.covariance_m2)


def test_mask_edge_is_not_an_edge(ref):
    """Pixels outside the template mask (filled with 0) would add a strong false edge along the mask
    border; the eroded mask keeps it out and the refined position stays on the truth."""
    tpl = crop(ref, 120, 90, SIDE).copy()
    mask = np.ones((SIDE, SIDE), bool)
    mask[:, :25] = False
    tpl[~mask] = 0.0
    m = SceneMatcher(ref, M_PER_PX, MatcherConfig(gradient_refine_radius_px=8)).match(
        tpl, (161.0, 131.0), 8, mask=mask)
    u, v = _truth_uv(120, 90)
    assert math.hypot(m.position_px[0] - u, m.position_px[1] - v) < 0.3


def test_no_gradient_peak_inside_keeps_intensity_position():
    """A template whose gradient surface peaks on the refinement window's edge keeps the
    intensity position (NaN shift): a linear ramp has the same gradient everywhere."""
    ramp = np.tile(np.linspace(0.0, 1.0, 400, dtype=np.float32), (300, 1))
    rng = np.random.default_rng(0)
    ref = np.ascontiguousarray(ramp + 0.002 * rng.standard_normal(ramp.shape).astype(np.float32))
    tpl = crop(ref, 100, 100, SIDE)
    m = SceneMatcher(ref, M_PER_PX, MatcherConfig(gradient_refine_radius_px=6)).match(tpl, (140.0, 140.0), 6)
    plain = SceneMatcher(ref, M_PER_PX).match(tpl, (140.0, 140.0), 6)
    if math.isnan(m.gradient_shift_px):
        assert m.position_px == plain.position_px
    else:                                   # refined: then within the refinement radius
        assert m.gradient_shift_px <= 6.0 * math.sqrt(2.0) + 1.0


def test_gradient_magnitude_of_a_step():
    img = np.zeros((20, 20), np.float32)
    img[:, 10:] = 1.0
    g = gradient_magnitude(img)
    assert g.dtype == np.float32 and g.shape == img.shape
    assert g[5, 9] > 0 and g[5, 10] > 0 and g[5, 3] == 0 and g[5, 16] == 0


def test_gradient_magnitude_does_not_depend_on_buffer_alignment():
    """The same image at 16 buffer offsets gives the same bits (lockstep runs repeat byte for byte)."""
    img = texture(120, 150, seed=9)
    outs = []
    for offset in range(16):
        buf = np.empty(img.size + 16, np.float32)
        view = buf[offset:offset + img.size].reshape(img.shape)
        view[:] = img
        outs.append(gradient_magnitude(view))
    for out in outs[1:]:
        np.testing.assert_array_equal(out, outs[0])


@pytest.mark.parametrize("bad", [-1, 201])
def test_radius_is_checked(bad):
    with pytest.raises(ConfigError, match="gradient_refine_radius_px"):
        MatcherConfig(gradient_refine_radius_px=bad)


def test_tighter_fixes_on_the_3d_city(default_world):
    """On the default world's 3-D captures against its 500 m perspective reference (another day's
    sun and shadows), window searches as the tracker makes them: the refined fixes are tighter
    than the intensity ones and no more of them are gross."""
    from perception.alignment import align_capture
    from scenenav.app.relief_experiment import (
        ALTITUDE_M,
        CAMERA_PX,
        FOV_DEG,
        Comparison,
        _scenes,
        sample_positions,
    )
    world = default_world
    scene = _scenes(world)[Comparison.RELIEF_PERSPECTIVE]
    poses = sample_positions(world, 60, seed=5)
    tu, tv = scene.true_match_uv(np.array([p.u_px for p in poses]), np.array([p.v_px for p in poses]))
    pcfg = PerceptionConfig(fov_deg=FOV_DEG)
    cfg = pcfg.matcher
    errors = {}
    for radius in (0, 24):
        matcher = SceneMatcher(scene.reference_gray, scene.m_per_px,
                               dataclasses.replace(cfg, gradient_refine_radius_px=radius))
        e = []
        for i, p in enumerate(poses):
            cam = scene.camera_image(p.u_px, p.v_px, p.heading_rad, ALTITUDE_M, FOV_DEG, CAMERA_PX)
            a = align_capture(cam, p.heading_rad, ALTITUDE_M, FOV_DEG, scene.m_per_px, pcfg.crop_mode,
                              (matcher.width_px, matcher.height_px))
            m = matcher.match(a.template, (float(tu[i]), float(tv[i])), 24,
                              mask=None if a.mask_is_full else a.mask)
            e.append(math.hypot(m.position_px[0] - tu[i], m.position_px[1] - tv[i]) * scene.m_per_px)
        errors[radius] = np.array(e)
    # (seed 5: median 0.25 vs 0.97 m, 11 vs 15 of 60 over 5 m)
    assert np.median(errors[24]) < 0.6 * np.median(errors[0])
    assert np.count_nonzero(errors[24] > 5.0) <= np.count_nonzero(errors[0] > 5.0)

