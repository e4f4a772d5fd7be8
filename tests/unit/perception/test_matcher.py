"""NCC matcher and tracker: hand-checked synthetic cases."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from perception.config import MatcherConfig, NccMethod
from perception.ncc_search import SceneMatcher, SearchMode
from perception.tracker import MatchTracker, TrackState

M_PER_PX = 0.5


def texture(h: int, w: int, seed: int = 0, sigma: float = 2.0) -> np.ndarray:
    """Smooth random texture in [0, 1] (float32): a unique NCC peak everywhere."""
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), sigma)
    t = (t - t.min()) / (t.max() - t.min())
    return t.astype(np.float32)


def crop(img: np.ndarray, x0: int, y0: int, side: int) -> np.ndarray:
    return np.ascontiguousarray(img[y0:y0 + side, x0:x0 + side])


def shifted_crop(img: np.ndarray, x0: float, y0: float, side: int) -> np.ndarray:
    """template(i, j) = img(y0 + i, x0 + j) with fractional x0, y0 (bilinear resampling)."""
    m = np.array([[1.0, 0.0, x0], [0.0, 1.0, y0]])
    return cv2.warpAffine(img, m, (side, side), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)


@pytest.fixture(scope="module")
def ref() -> np.ndarray:
    return texture(300, 400, seed=1)


def test_integer_shift_found_exactly(ref):
    m = SceneMatcher(ref, M_PER_PX)
    r = m.match(crop(ref, 123, 87, 64))
    # Template centre in continuous pixels: top-left + side / 2.
    assert r.position_px == pytest.approx((123 + 32, 87 + 32), abs=0.05)
    assert r.peak == pytest.approx(1.0, abs=1e-3)
    assert r.search is SearchMode.GLOBAL
    assert r.quality_ok
    # ENU: x = (u - W/2) m_per_px, y = (H/2 - v) m_per_px.
    assert r.position_enu_m == pytest.approx(((155 - 200) * M_PER_PX, (150 - 119) * M_PER_PX), abs=0.05)
    assert r.timings.ncc_ms > 0.0 and r.timings.crop_ms >= 0.0 and r.timings.refine_ms >= 0.0


@pytest.mark.parametrize("dx,dy", [(0.3, -0.4), (-0.25, 0.45), (0.5, 0.0)])
def test_subpixel_shift_within_0_2_px(ref, dx, dy):
    m = SceneMatcher(ref, M_PER_PX)
    x0, y0, side = 150 + dx, 100 + dy, 64
    r = m.match(shifted_crop(ref, x0, y0, side))
    assert abs(r.position_px[0] - (x0 + side / 2)) < 0.2
    assert abs(r.position_px[1] - (y0 + side / 2)) < 0.2


def test_window_and_global_agree(ref):
    m = SceneMatcher(ref, M_PER_PX)
    t = shifted_crop(ref, 201.3, 140.8, 70)
    g = m.match(t)
    w = m.match(t, predicted_uv=(g.position_px[0] + 6, g.position_px[1] - 7), search_radius_px=20)
    assert w.search is SearchMode.WINDOW
    assert w.position_px == pytest.approx(g.position_px, abs=1e-3)
    assert w.peak == pytest.approx(g.peak, abs=1e-4)
    u0, v0, ww, wh = w.window_px
    assert (ww, wh) == (70 + 2 * 20, 70 + 2 * 20)
    assert u0 <= g.position_px[0] - 35 and v0 <= g.position_px[1] - 35


def test_window_clipped_at_map_edge(ref):
    m = SceneMatcher(ref, M_PER_PX)
    r = m.match(crop(ref, 0, 0, 50), predicted_uv=(20.0, 30.0), search_radius_px=16)
    assert r.position_px == pytest.approx((25.0, 25.0), abs=0.05)
    assert r.window_px[:2] == (0, 0)
    assert not r.peak_at_border        # the map edge is not a window border


def test_peak_outside_window_is_flagged(ref):
    m = SceneMatcher(ref, M_PER_PX)
    t = crop(ref, 200, 120, 60)        # true centre (230, 150)
    r = m.match(t, predicted_uv=(230.0 + 30, 150.0), search_radius_px=8)
    assert r.peak_at_border
    assert not r.quality_ok


def test_uniform_map_is_flat_low_psr_wide_covariance():
    flat = np.full((200, 220), 0.5, np.float32)
    m = SceneMatcher(flat, M_PER_PX)
    r = m.match(crop(flat, 50, 60, 40), predicted_uv=(70.0, 80.0), search_radius_px=20)
    assert r.flat_template and not r.quality_ok
    assert r.psr < m.cfg.min_psr
    sigma_m = np.sqrt(np.diag(r.covariance_m2))
    # As wide as the searched area: uniform over +-20 px has sigma 20 / sqrt(3) px.
    assert np.all(sigma_m > 20 / math.sqrt(3) * M_PER_PX)


def test_unrelated_capture_on_near_uniform_map_low_psr_wide_covariance():
    rng = np.random.default_rng(3)
    lake = (0.5 + 0.01 * rng.standard_normal((240, 260))).astype(np.float32)
    capture = (0.5 + 0.01 * rng.standard_normal((48, 48))).astype(np.float32)   # another day's ripples
    m = SceneMatcher(lake, M_PER_PX)
    good = SceneMatcher(texture(240, 260, seed=4), M_PER_PX)
    r = m.match(capture, predicted_uv=(130.0, 120.0), search_radius_px=30)
    ok = good.match(crop(good.reference, 100, 90, 48), predicted_uv=(124.0, 114.0),
                    search_radius_px=30)
    assert r.peak < m.cfg.min_peak and not r.quality_ok
    assert ok.quality_ok
    assert np.trace(r.covariance_m2) > 50.0 * np.trace(ok.covariance_m2)
    assert math.sqrt(r.covariance_m2[0, 0]) > 5.0 * M_PER_PX


def test_repeated_pattern_second_peak_ratio_near_one():
    tile = texture(64, 64, seed=5)
    ref = texture(200, 300, seed=6)
    ref[40:104, 30:94] = tile
    ref[60:124, 200:264] = tile
    m = SceneMatcher(ref, M_PER_PX)
    r = m.match(tile.copy())
    assert r.second_peak_ratio > 0.95
    assert not r.quality_ok
    # Ambiguous: the covariance spans the whole map.
    assert math.sqrt(r.covariance_m2[0, 0]) > 50 * M_PER_PX


def test_ccorr_method_is_eq1(ref):
    cfg = MatcherConfig(ncc_method=NccMethod.CCORR_NORMED)
    m = SceneMatcher(ref, M_PER_PX, cfg)
    t = crop(ref, 40, 50, 48)
    r = m.match(t, predicted_uv=(64.0, 74.0), search_radius_px=10)
    assert r.position_px == pytest.approx((64.0, 74.0), abs=0.1)
    # Equation (1) by hand at the true offset.
    win = ref[50:98, 40:88].astype(np.float64)
    eq1 = (t * win).sum() / math.sqrt((t.astype(np.float64) ** 2).sum() * (win ** 2).sum())
    assert r.peak == pytest.approx(eq1, abs=1e-4)


def test_masked_template(ref):
    m = SceneMatcher(ref, M_PER_PX)
    t = crop(ref, 100, 100, 60)
    mask = np.ones(t.shape, bool)
    mask[:15, :15] = False
    t = t.copy()
    t[~mask] = 0.0
    r = m.match(t, predicted_uv=(133.0, 127.0), search_radius_px=12, mask=mask)
    assert r.position_px == pytest.approx((130.0, 130.0), abs=0.1)


def test_coarse_to_fine_global_search():
    big = texture(900, 1000, seed=7, sigma=3.0)
    cfg = MatcherConfig(coarse_above_px=512, coarse_target_px=256, min_coarse_template_px=24)
    m = SceneMatcher(big, M_PER_PX, cfg)
    r = m.match(shifted_crop(big, 611.4, 377.7, 128))
    assert r.search is SearchMode.COARSE_TO_FINE
    assert r.position_px == pytest.approx((611.4 + 64, 377.7 + 64), abs=0.2)
    assert r.quality_ok


def test_tracker_follows_and_reacquires_after_loss(ref):
    cfg = MatcherConfig(lost_after_n=2)
    m = SceneMatcher(ref, M_PER_PX, cfg)
    trk = MatchTracker(m)
    side, rng = 60, np.random.default_rng(8)
    # Constant velocity 40 px/s east, 20 px/s south, 10 Hz.
    for k in range(5):
        x0, y0 = 60 + 4.0 * k, 50 + 2.0 * k
        r = trk.match(shifted_crop(ref, x0, y0, side), t_s=0.1 * k)
        assert r.position_px == pytest.approx((x0 + 30, y0 + 30), abs=0.2)
        assert r.search is (SearchMode.GLOBAL if k == 0 else SearchMode.WINDOW)
    assert trk.state is TrackState.TRACKING
    assert trk.velocity_px_s == pytest.approx((40.0, 20.0), abs=1.0)
    pred = trk.predict(0.5)
    assert pred.uv == pytest.approx((60 + 20 + 30, 50 + 10 + 30), abs=0.3)
    assert pred.radius_px == pytest.approx(cfg.min_window_margin_px + math.hypot(4, 2), abs=0.2)
    # Garbage captures: the window grows, then the tracker is lost.
    noise = rng.random((side, side)).astype(np.float32)
    r1 = trk.match(noise, t_s=0.5)
    assert r1.search is SearchMode.WINDOW and not r1.quality_ok
    assert trk.predict(0.6).radius_px > pred.radius_px
    trk.match(noise, t_s=0.6)
    assert trk.state is TrackState.LOST
    # The drone reappears elsewhere: global search re-acquires it.
    r = trk.match(shifted_crop(ref, 250.0, 200.0, side), t_s=0.7)
    assert r.search is SearchMode.GLOBAL
    assert r.position_px == pytest.approx((280.0, 230.0), abs=0.2)
    assert trk.state is TrackState.TRACKING
    assert trk.velocity_px_s is None       # the old velocity no longer applies


def test_tracker_uses_prior_when_no_track(ref):
    m = SceneMatcher(ref, M_PER_PX)
    trk = MatchTracker(m)
    r = trk.match(crop(ref, 100, 100, 60), t_s=0.0, prior_uv=(135.0, 126.0), prior_radius_px=15)
    assert r.search is SearchMode.WINDOW
    assert r.position_px == pytest.approx((130.0, 130.0), abs=0.05)


def test_bad_template_rejected(ref):
    m = SceneMatcher(ref, M_PER_PX)
    with pytest.raises(ValueError):
        m.match(np.zeros((400, 400), np.float32))
    with pytest.raises(ValueError):
        m.match(np.zeros((10,), np.float32))


def test_covariance_is_elongated_along_the_texture_in_enu():
    """Texture smeared along the south-west/north-east diagonal: the position is least certain
    along that line, so in ENU (x east, y north) x and y are positively correlated."""
    rng = np.random.default_rng(9)
    n = 15
    kernel = np.zeros((n, n), np.float32)
    kernel[np.arange(n), n - 1 - np.arange(n)] = 1.0 / n     # row up <-> column right: SW-NE line
    base = cv2.GaussianBlur(rng.standard_normal((260, 300)).astype(np.float32), (0, 0), 1.0)
    ref = cv2.filter2D(base, -1, kernel)
    ref = (ref - ref.min()) / (ref.max() - ref.min())
    # A smeared lobe lowers the PSR; take it as confident and drop the floor so that only the
    # local (curvature) term is left. Another day's noise makes that term visible.
    cfg = MatcherConfig(min_psr=3.0, psr_confident=4.0, cov_floor_px=0.01)
    m = SceneMatcher(ref, M_PER_PX, cfg)
    capture = shifted_crop(ref, 120.3, 90.6, 64) + rng.normal(0, 0.05, (64, 64)).astype(np.float32)
    r = m.match(capture, predicted_uv=(153.0, 122.0), search_radius_px=20)
    assert r.position_px == pytest.approx((152.3, 122.6), abs=0.5)   # worst along the smear
    c = r.covariance_m2
    assert c[0, 1] == c[1, 0] > 0.0
    eigval, eigvec = np.linalg.eigh(c)
    major = eigvec[:, 1]
    assert abs(abs(major[0]) - abs(major[1])) < 0.2 and major[0] * major[1] > 0   # along (1, 1)
    assert eigval[1] > 5.0 * eigval[0]
