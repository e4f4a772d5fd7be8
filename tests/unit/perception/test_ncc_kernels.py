"""The compiled matcher kernels against plain-numpy references: the DFT NCC surface
(perception.ncc_fft), the one-pass peak metrics (perception.peak_metrics.surface_peak_metrics) and
the closed-form covariance (perception.fix_covariance)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from perception.config import MatcherConfig
from perception.fix_covariance import covariance_px
from perception.ncc_fft import FftNcc, _mul_conj_ccs
from perception.peak_metrics import (
    exclusion_radius,
    peak_to_sidelobe_ratio,
    refine_peak,
    second_peak_ratio,
    surface_peak_metrics,
)


def texture(h: int, w: int, seed: int, sigma: float = 2.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), sigma)
    return ((t - t.min()) / (t.max() - t.min())).astype(np.float32)


def ncc_reference(window: np.ndarray, template: np.ndarray) -> np.ndarray:
    """TM_CCOEFF_NORMED in float64 by its definition (NaN where a patch is flat)."""
    w = window.astype(np.float64)
    t = template.astype(np.float64) - template.mean(dtype=np.float64)
    p = sliding_window_view(w, template.shape)
    pz = p - p.mean(axis=(2, 3), keepdims=True)
    num = (pz * t).sum(axis=(2, 3))
    den = np.sqrt((pz ** 2).sum(axis=(2, 3)) * (t ** 2).sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


# ------------------------------------------------------------------------------ DFT NCC surface
@pytest.mark.parametrize("seed", range(12))
def test_surface_matches_the_definition_on_random_sizes(seed):
    rng = np.random.default_rng(seed)
    ref = texture(160, 150, seed)
    th, tw = (int(x) for x in rng.integers(2, 60, 2))
    wh, ww = th + int(rng.integers(0, 45)), tw + int(rng.integers(0, 45))
    y0, x0 = int(rng.integers(0, 160 - wh + 1)), int(rng.integers(0, 150 - ww + 1))
    ty, tx = int(rng.integers(0, 160 - th + 1)), int(rng.integers(0, 150 - tw + 1))
    template = np.ascontiguousarray(ref[ty:ty + th, tx:tx + tw])
    template += 0.05 * rng.standard_normal(template.shape).astype(np.float32)
    out, k = FftNcc().surface(ref, x0, y0, x0 + ww, y0 + wh, template)
    expect = ncc_reference(ref[y0:y0 + wh, x0:x0 + ww], template)
    assert out.dtype == np.float32 and out.shape == expect.shape
    np.testing.assert_allclose(out, expect, atol=2e-5)
    assert k == int(np.argmax(out))                     # the first maximum, row-major
    assert out.flat[k] == pytest.approx(expect.max(), abs=2e-5)
    cv = cv2.matchTemplate(ref[y0:y0 + wh, x0:x0 + ww], template, cv2.TM_CCOEFF_NORMED)
    np.testing.assert_allclose(out, cv, atol=2e-3)      # OpenCV's own rounding is the larger


def test_exact_crop_peaks_at_one_in_its_place():
    ref = texture(300, 300, 3)
    template = np.ascontiguousarray(ref[110:174, 90:154])
    out, k = FftNcc().surface(ref, 70, 80, 70 + 130, 80 + 120, template)
    assert divmod(k, out.shape[1]) == (30, 20)
    assert out[30, 20] == pytest.approx(1.0, abs=1e-6)


def test_template_as_large_as_the_window_gives_one_value():
    ref = texture(80, 80, 4)
    template = np.ascontiguousarray(ref[10:50, 20:45])
    out, k = FftNcc().surface(ref, 20, 10, 45, 50, template)
    assert out.shape == (1, 1) and k == 0 and out[0, 0] == pytest.approx(1.0, abs=1e-6)


def test_flat_window_patches_give_zero_as_opencv():
    ref = texture(120, 120, 5)
    ref[40:100, 30:90] = 0.25                           # a uniform block: the patches inside are flat
    template = np.ascontiguousarray(texture(20, 20, 6))
    out, _ = FftNcc().surface(ref, 30, 40, 90, 100, template)
    assert np.all(out == 0.0)
    cv = cv2.matchTemplate(ref[40:100, 30:90], template, cv2.TM_CCOEFF_NORMED)
    assert np.all(cv == 0.0)


def test_non_finite_window_values_give_minus_one():
    ref = texture(100, 100, 7)
    ref[50, 50] = np.nan
    template = np.ascontiguousarray(ref[10:30, 10:30])
    out, _ = FftNcc().surface(ref, 40, 40, 70, 70, template)
    assert np.all(out == -1.0)


def test_surface_is_deterministic_and_independent_of_buffer_reuse():
    ref = texture(260, 260, 8)
    t1 = np.ascontiguousarray(ref[50:110, 60:120])
    t2 = np.ascontiguousarray(ref[100:140, 100:150])
    ncc = FftNcc()
    a, ka = ncc.surface(ref, 40, 30, 150, 140, t1)
    ncc.surface(ref, 80, 90, 170, 150, t2)           # another size in between, same buffers
    b, kb = ncc.surface(ref, 40, 30, 150, 140, t1)
    c, kc = FftNcc().surface(ref, 40, 30, 150, 140, t1)
    assert ka == kb == kc
    assert a.tobytes() == b.tobytes() == c.tobytes()


def test_template_larger_than_window_is_refused():
    ref = texture(50, 50, 9)
    with pytest.raises(ValueError):
        FftNcc().surface(ref, 0, 0, 10, 10, np.ascontiguousarray(ref[:12, :12]))


@pytest.mark.parametrize("shape", [(240, 240), (7, 9), (8, 8), (9, 6), (5, 4), (1, 8), (8, 1), (1, 1), (2, 3)])
def test_conjugate_product_of_packed_spectra_is_opencvs(shape):
    rng = np.random.default_rng(sum(shape))
    a = cv2.dft(rng.random(shape).astype(np.float32))
    b = cv2.dft(rng.random(shape).astype(np.float32))
    out = np.full_like(a, np.nan)
    _mul_conj_ccs(a, b, out)
    expect = cv2.mulSpectrums(a, b, 0, conjB=True)
    np.testing.assert_allclose(out, expect, rtol=0, atol=1e-6 * np.abs(expect).max())


# ------------------------------------------------------------------------------ peak metrics
def _reference_metrics(vals, ix, iy, edges, min_radius):
    pk = refine_peak(vals, ix, iy, edges)
    excl = exclusion_radius(vals, pk.ix, pk.iy, min_radius)
    psr = peak_to_sidelobe_ratio(vals, pk.ix, pk.iy, pk.value, excl)
    spr = second_peak_ratio(vals, pk.ix, pk.iy, pk.value, excl)
    return pk, excl, psr, spr


def _check_against_reference(vals, edges=(False, False, False, False), min_radius=6):
    iy, ix = divmod(int(vals.argmax()), vals.shape[1])
    pk, excl, psr, spr = _reference_metrics(vals, ix, iy, edges, min_radius)
    m = surface_peak_metrics(vals, edges, min_radius)
    assert (m.ix, m.iy) == (pk.ix, pk.iy)
    assert m.dx == pytest.approx(pk.dx, abs=1e-12) and m.dy == pytest.approx(pk.dy, abs=1e-12)
    assert m.value == pytest.approx(pk.value, abs=1e-12)
    assert m.edge_axes == pk.edge_axes and m.at_border == pk.at_border
    if pk.curvature is None:
        assert m.curvature is None
    else:
        c = pk.curvature
        assert m.curvature == pytest.approx((c[0, 0], c[0, 1], c[1, 1]), rel=1e-12, abs=1e-15)
    assert m.excl == excl
    if math.isnan(psr):
        assert math.isnan(m.psr)
    else:
        assert m.psr == pytest.approx(psr, rel=1e-9)
    assert m.second_peak_ratio == pytest.approx(spr, rel=1e-12)
    assert repr(surface_peak_metrics(vals, edges, min_radius, int(vals.argmax()))) == repr(m)   # argmax given
    return m


@pytest.mark.parametrize("seed", range(10))
def test_metrics_match_the_reference_on_correlation_surfaces(seed):
    rng = np.random.default_rng(seed)
    ref = texture(220, 220, seed + 20, sigma=float(rng.uniform(1.0, 4.0)))
    side = int(rng.integers(20, 90))
    ty, tx = (int(v) for v in rng.integers(40, 220 - side - 40, 2))
    template = np.ascontiguousarray(ref[ty:ty + side, tx:tx + side])
    template += float(rng.uniform(0.0, 0.3)) * rng.standard_normal(template.shape).astype(np.float32)
    r = int(rng.integers(4, 40))
    vals = cv2.matchTemplate(ref[ty - r:ty + side + r, tx - r:tx + side + r], template, cv2.TM_CCOEFF_NORMED)
    _check_against_reference(vals)


@pytest.mark.parametrize("edges", [(False,) * 4, (True, False, True, False), (True,) * 4])
@pytest.mark.parametrize("where", ["corner", "left", "bottom", "inside"])
def test_metrics_at_window_borders_and_map_edges(edges, where):
    h, w = 31, 40
    yy, xx = np.mgrid[0:h, 0:w]
    cy, cx = {"corner": (0, 0), "left": (15, 0), "bottom": (h - 1, 20), "inside": (12, 17)}[where]
    vals = (0.9 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 18.0)
            + 0.3 * np.exp(-((xx - 33) ** 2 + (yy - 25) ** 2) / 6.0)).astype(np.float32)
    m = _check_against_reference(vals, edges)
    assert (m.ix, m.iy) == (cx, cy)


def test_metrics_of_a_saddle_a_flat_top_and_a_negative_peak():
    yy, xx = np.mgrid[0:25, 0:26]
    saddle = (0.5 + 0.01 * (xx - 12.0) ** 2 - 0.02 * (yy - 11.0) ** 2).astype(np.float32)
    saddle[11, 12] += 0.3
    _check_against_reference(saddle)
    flat = np.full((20, 21), 0.4, np.float32)
    assert _check_against_reference(flat).curvature is None
    negative = (-0.5 - 0.001 * ((xx - 9.0) ** 2 + (yy - 7.0) ** 2)).astype(np.float32)
    assert _check_against_reference(negative).second_peak_ratio == 1.0


@pytest.mark.parametrize("shape", [(2, 9), (3, 3), (4, 5), (64, 65), (130, 129)])
def test_metrics_on_small_and_subsampled_surfaces(shape):
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    vals = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), 1.5)
    _check_against_reference(vals, min_radius=2)


def test_median_of_even_and_odd_counts():
    rng = np.random.default_rng(3)
    for shape in [(10, 10), (9, 9), (130, 131)]:          # even, odd, subsampled (step 2)
        vals = rng.random(shape).astype(np.float32)
        vals[5, 5] = 2.0
        _check_against_reference(vals, min_radius=1)


# ------------------------------------------------------------------------------ covariance
def _covariance_numpy(cfg, peak, curvature, edge_axes, psr, spr, rx, ry, n_px):
    """The covariance with np.linalg, as it was computed before the closed forms."""
    from perception.fix_covariance import ambiguity_weight
    ux, uy = rx * rx / 3.0, ry * ry / 3.0
    a = np.array([[curvature[0], curvature[1]], [curvature[1], curvature[2]]])
    r = max(peak, 0.05)
    n_eff = max(1.0, n_px * math.sqrt(max(np.linalg.det(a / r), 0.0)) / (2.0 * math.pi))
    noise = max(1.0 - min(r, 1.0) ** 2, 1e-3) / (n_eff * r)
    local = cfg.cov_local_scale * noise * np.linalg.inv(a)
    if edge_axes[0]:
        local[0, :] = local[:, 0] = 0.0
        local[0, 0] = 1.0
    if edge_axes[1]:
        local[1, :] = local[:, 1] = 0.0
        local[1, 1] = 1.0
    c = local + cfg.cov_floor_px ** 2 * np.eye(2) + ambiguity_weight(cfg, psr, spr, peak) * np.diag([ux, uy])
    c = 0.5 * (c + c.T)
    c[0, 0] = min(c[0, 0], 2 * ux + cfg.cov_floor_px ** 2)
    c[1, 1] = min(c[1, 1], 2 * uy + cfg.cov_floor_px ** 2)
    lim = math.sqrt(c[0, 0] * c[1, 1]) * 0.999
    c[0, 1] = c[1, 0] = float(np.clip(c[0, 1], -lim, lim))
    return c


@pytest.mark.parametrize("seed", range(20))
def test_closed_form_covariance_matches_numpy_linalg(seed):
    rng = np.random.default_rng(seed)
    cfg = MatcherConfig()
    l1, l2 = rng.uniform(1e-3, 0.5, 2)
    th = rng.uniform(0, math.pi)
    rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    a = rot @ np.diag([l1, l2]) @ rot.T
    curv = (float(a[0, 0]), float(a[0, 1]), float(a[1, 1]))
    edge = (bool(rng.random() < 0.2), bool(rng.random() < 0.2))
    args = (cfg, float(rng.uniform(0.3, 1.0)), curv, edge, float(rng.uniform(5, 15)),
            float(rng.uniform(0.2, 0.9)), 26.5, 27.0, 188 * 188)
    np.testing.assert_allclose(covariance_px(*args), _covariance_numpy(*args), rtol=1e-12, atol=1e-15)
