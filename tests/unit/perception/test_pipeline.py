"""Perception pipeline end to end on a synthetic world, one test per false-match method."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from perception.assistant_map import AssistantMap
from perception.config import PerceptionConfig, UnknownPolicy
from perception.decision import Decision, FalseMatchMethod
from perception.match_metrics import MatchMetrics
from perception.ncc_search import SearchMode
from perception.pipeline import BadInput, PerceptionPipeline, Reason
from perception.tracker import TrackState
from scenenav.core.errors import UserError

MPP = 0.5
ALT = 40.0          # footprint 46.2 m = 92 map px
FOV = 60.0
CAM = 200
LAKE_COLS = 150     # columns [0, 150) are a lake: flat on the reference, ripples in flight
H, W = 400, 500


def texture(h: int, w: int, seed: int, sigma: float = 2.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), sigma)
    return ((t - t.min()) / (t.max() - t.min())).astype(np.float32)


def render(world: np.ndarray, u: float, v: float, heading: float, alt: float = ALT) -> np.ndarray:
    """Camera image (RGB uint8) at continuous pixel (u, v) from ``alt``: image-up = heading, right = right."""
    g = 2.0 * alt * math.tan(math.radians(FOV) / 2.0) / CAM / MPP
    jj, ii = np.meshgrid(np.arange(CAM) - (CAM - 1) / 2.0, np.arange(CAM) - (CAM - 1) / 2.0)
    c, s = math.cos(heading), math.sin(heading)
    mx = (u - 0.5 + g * (c * jj - s * ii)).astype(np.float32)
    my = (v - 0.5 + g * (s * jj + c * ii)).astype(np.float32)
    gray = cv2.remap(world, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    g8 = np.clip(np.rint(gray * 255), 0, 255).astype(np.uint8)
    return np.dstack([g8, g8, g8])


def make_synthetic_world() -> tuple[np.ndarray, np.ndarray]:
    """(reference RGB uint8, flight-day grey float32)."""
    ref = texture(H, W, seed=11)
    ref[:, :LAKE_COLS] = 0.5
    rng = np.random.default_rng(12)
    day = 0.8 * ref + 0.1 + rng.normal(0, 0.01, ref.shape).astype(np.float32)   # another day
    ref8 = np.clip(np.rint(ref * 255), 0, 255).astype(np.uint8)
    return np.dstack([ref8, ref8, ref8]), day.astype(np.float32)


def fly(pipe: PerceptionPipeline, day: np.ndarray, n: int, u0: float = 300.0, v0: float = 200.0,
        t0: float = 0.0, heading: float = 0.4):
    """n captures at 10 Hz moving east at 10 m/s (2 px per frame). Returns [(result, (u, v))]."""
    out = []
    for k in range(n):
        u, v = u0 + 2.0 * k, v0 + 0.5 * k
        out.append((pipe.process(render(day, u, v, heading + 0.05 * k), heading + 0.05 * k, ALT,
                                 t0 + 0.1 * k), (u, v)))
    return out


def err_m(res, uv) -> float:
    return math.hypot(res.position_px[0] - uv[0], res.position_px[1] - uv[1]) * MPP


def cnn_fake(batch: np.ndarray) -> np.ndarray:
    """Fake 4-class CNN: a flat capture is class 1 (bad area)."""
    assert batch.ndim == 3 and batch.dtype == np.float32 and batch.shape[1:] == (CAM, CAM)
    assert 0.0 <= batch.min() and batch.max() <= 1.0
    var = batch.reshape(len(batch), -1).var(axis=1)
    good = np.array([0.05, 0.8, 0.1, 0.05], np.float32)
    bad = np.array([0.9, 0.05, 0.03, 0.02], np.float32)
    return np.stack([bad if x < 1e-3 else good for x in var])


def test_method_none_accepts_all_and_tracks(world):
    ref, day = world
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    results = fly(pipe, day, 6)
    for k, (r, uv) in enumerate(results):
        assert r.valid and r.accepted and r.decision is Decision.ACCEPT
        assert r.reason is Reason.NO_DETECTION
        assert err_m(r, uv) < 0.3
        assert r.search is (SearchMode.GLOBAL if k == 0 else SearchMode.WINDOW)
        assert math.isnan(r.p_true) and all(math.isnan(p) for p in r.p_classes)
        assert isinstance(r.metrics, MatchMetrics) and r.metrics.peak > 0.5
        assert r.metrics == MatchMetrics(r.metrics.peak, r.metrics.psr, r.metrics.second_peak_ratio)
        assert r.timings.total_ms >= r.timings.align_ms + r.timings.ncc_ms > 0.0
        assert r.covariance_m2.shape == (2, 2) and np.all(np.linalg.eigvalsh(r.covariance_m2) > 0)
        assert np.trace(r.covariance_m2) < 1.0
    assert pipe.tracker.state is TrackState.TRACKING
    x, y = results[-1][0].position_enu_m
    u, v = results[-1][1]
    assert (x, y) == pytest.approx(((u - W / 2) * MPP, (H / 2 - v) * MPP), abs=0.3)


def test_method_cnn_classifies_every_capture(world):
    ref, day = world
    calls = []

    def clf(batch):
        calls.append(len(batch))
        return cnn_fake(batch)

    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.CNN, classify=clf)
    results = fly(pipe, day, 3)
    assert calls == [1, 1, 1]
    for r, _uv in results:
        assert r.accepted and r.reason is Reason.ACCEPTED
        assert r.p_true == pytest.approx(0.95)
        assert r.p_classes == pytest.approx((0.05, 0.8, 0.1, 0.05))
        assert pipe.assistant_map.lookup(*r.position_px) == pytest.approx(0.95)
    lake = pipe.process(render(day, 70.0, 200.0, 0.0), 0.0, ALT, 1.0)
    assert lake.valid and not lake.accepted and lake.reason is Reason.CNN_BAD_AREA
    assert lake.p_true == pytest.approx(0.1)
    assert pipe.assistant_map.coverage() > 0.0


def test_method_assistant_map_uses_the_map(world):
    ref, day = world
    amap = AssistantMap(W, H, MPP)
    amap.probability[:, LAKE_COLS:] = 0.9
    amap.probability[:, :LAKE_COLS] = 0.2
    amap.probability[300:, :] = 0.3                # textured but known to be a bad area
    amap.probability[:, 450:] = np.nan             # not visited
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.ASSISTANT_MAP, assistant_map=amap)
    for r, _ in fly(pipe, day, 3):
        assert r.accepted and r.p_true == pytest.approx(0.9) and r.reason is Reason.ACCEPTED
    pipe.reset()
    bad = pipe.process(render(day, 300.0, 340.0, 0.0), 0.0, ALT, 2.0)
    assert bad.quality_ok and not bad.accepted and bad.reason is Reason.MAP_BAD_AREA
    assert bad.p_true == pytest.approx(0.3)
    # Unvisited pixel and no classifier: unknown_policy (default reject, or accept).
    pipe.reset()
    unknown = pipe.process(render(day, 455.0, 200.0, 0.0), 0.0, ALT, 3.0)
    assert unknown.quality_ok and not unknown.accepted and unknown.reason is Reason.MAP_UNKNOWN
    assert math.isnan(unknown.p_true)
    cfg = dataclasses.replace(PerceptionConfig(), unknown_policy=UnknownPolicy.ACCEPT)
    pipe2 = PerceptionPipeline(ref, MPP, FalseMatchMethod.ASSISTANT_MAP, cfg, assistant_map=amap)
    assert pipe2.process(render(day, 455.0, 200.0, 0.0), 0.0, ALT, 3.0).accepted


def test_low_quality_match_looks_up_the_predicted_pixel(world):
    ref, day = world
    amap = AssistantMap(W, H, MPP)
    amap.probability[:] = 0.9
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.ASSISTANT_MAP, assistant_map=amap)
    fly(pipe, day, 4)                              # u = 300..306 (+2 px per 0.1 s), v = 200..201.5
    amap.write_patch(308.0, 202.0, 3, 0.1)         # only around the predicted pixel: a bad area
    noise = np.random.default_rng(1).integers(0, 256, (CAM, CAM, 3), dtype=np.uint8)
    r = pipe.process(noise, 0.4, ALT, 0.4)
    assert not r.quality_ok
    assert math.hypot(r.position_px[0] - 308.0, r.position_px[1] - 202.0) > 3.0   # match elsewhere
    assert pipe.tracker.last_prediction.uv == pytest.approx((308.0, 202.0), abs=0.3)
    assert not r.accepted and r.reason is Reason.MAP_BAD_AREA and r.p_true == pytest.approx(0.1)


def test_method_assistant_map_classifies_unknown_once(world):
    ref, day = world
    calls = []

    def clf(batch):
        calls.append(len(batch))
        return cnn_fake(batch)

    pipe = PerceptionPipeline(ref, MPP, "assistant-map", classify=clf)
    first = pipe.process(render(day, 300.0, 200.0, 0.3), 0.3, ALT, 0.0)
    assert first.accepted and calls == [1] and first.p_true == pytest.approx(0.95)
    assert pipe.assistant_map.lookup(*first.position_px) == pytest.approx(0.95)
    again = pipe.process(render(day, 300.0, 200.0, 0.3), 0.3, ALT, 0.1)   # hovering: known now
    assert again.accepted and calls == [1]


def test_method_statistical_flags_a_jump(world):
    ref, day = world
    cfg = dataclasses.replace(PerceptionConfig(), statistical_window=10)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.STATISTICAL, cfg)
    steady = fly(pipe, day, 8)
    assert all(r.accepted for r, _ in steady)
    assert steady[-1][0].statistical_variance_m2 < 0.1
    rng = np.random.default_rng(5)
    rejected = []
    for k in range(3):     # garbage captures: the match lands anywhere in the window
        noise = rng.integers(0, 256, (CAM, CAM, 3), dtype=np.uint8)
        r = pipe.process(noise, 0.4, ALT, 0.8 + 0.1 * k)
        assert r.valid
        rejected.append(not r.accepted and r.reason is Reason.STATISTICAL_VARIANCE)
    assert any(rejected)


def test_prior_seeds_the_first_window(world):
    ref, day = world
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    x, y = (310.0 - W / 2) * MPP + 3.0, (H / 2 - 210.0) * MPP - 2.0
    r = pipe.process(render(day, 310.0, 210.0, 1.0), 1.0, ALT, 0.0, prior_enu_m=(x, y))
    assert r.search is SearchMode.WINDOW and err_m(r, (310.0, 210.0)) < 0.3


def test_template_larger_than_map_is_invalid(world):
    ref, day = world
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    r = pipe.process(render(day, 300.0, 200.0, 0.0), 0.0, 400.0, 0.0)
    assert not r.valid and not r.accepted and r.reason is Reason.TEMPLATE_TOO_LARGE
    assert all(math.isnan(c) for c in r.position_enu_m)
    # An absurd altitude is refused before any resampling (no giant allocation).
    assert pipe.process(render(day, 300.0, 200.0, 0.0), 0.0, 1e9, 0.1).reason is Reason.TEMPLATE_TOO_LARGE
    low = pipe.process(render(day, 300.0, 200.0, 0.0), 0.0, 3.0, 0.2)      # 6 px template (3.46 m)
    assert not low.valid and low.reason is Reason.TEMPLATE_TOO_SMALL and low.template_side_px == 6


def test_uniform_capture_is_invalid(world):
    ref, _ = world
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    r = pipe.process(np.full((CAM, CAM, 3), 90, np.uint8), 0.0, ALT, 0.0)
    assert not r.valid and not r.accepted and r.reason is Reason.FLAT_CAPTURE
    assert math.isnan(r.position_enu_m[0]) and math.isnan(r.metrics.peak)


@pytest.mark.parametrize("image,heading,alt,t", [
    (np.zeros((CAM, CAM, 3), np.uint8), float("nan"), ALT, 0.0),
    (np.zeros((CAM, CAM, 3), np.uint8), 0.0, float("nan"), 0.0),
    (np.zeros((CAM, CAM, 3), np.uint8), 0.0, 0.0, 0.0),
    (np.zeros((CAM, CAM, 3), np.uint8), 0.0, -1.0, 0.0),
    (np.zeros((CAM, CAM, 3), np.uint8), 0.0, ALT, float("nan")),
    (np.zeros((CAM, CAM, 3), np.float64), 0.0, ALT, 0.0),
    (np.zeros((CAM, CAM, 5), np.uint8), 0.0, ALT, 0.0),
    (None, 0.0, ALT, 0.0),
])
def test_bad_input_raises(world, image, heading, alt, t):
    ref, _ = world
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    with pytest.raises(BadInput):
        pipe.process(image, heading, alt, t)


def test_configuration_errors(world):
    ref, _ = world
    with pytest.raises(UserError):
        PerceptionPipeline(ref, MPP, FalseMatchMethod.CNN)              # no classifier
    with pytest.raises(UserError):
        PerceptionPipeline(ref, MPP, "magic")
    with pytest.raises(UserError):
        PerceptionPipeline(ref, MPP, "assistant-map", assistant_map=AssistantMap(10, 10, MPP))


def test_config_loads_from_a_mapping_with_range_checks():
    from perception.config import MatcherConfig, NccMethod
    from scenenav.core.config import ConfigError, load_config

    cfg = load_config(PerceptionConfig, {"method": "assistant-map", "unknown_policy": "accept",
                                         "matcher": {"ncc_method": "ccorr_normed", "lost_after_n": 5}})
    assert cfg.method is FalseMatchMethod.ASSISTANT_MAP and cfg.unknown_policy is UnknownPolicy.ACCEPT
    assert cfg.matcher == MatcherConfig(ncc_method=NccMethod.CCORR_NORMED, lost_after_n=5)
    assert cfg.statistical_window == 30 and cfg.statistical_threshold_m2 == 1.4
    assert cfg.true_match_tolerance_m == 5.0 and cfg.fov_deg == 60.0
    with pytest.raises(ConfigError):
        load_config(PerceptionConfig, {"fov_deg": 0.0})
    with pytest.raises(ConfigError):
        load_config(PerceptionConfig, {"matcher": {"min_psr": 20.0}})      # > psr_confident
    with pytest.raises(ConfigError):
        load_config(PerceptionConfig, {"method": "magic"})


def test_capture_scaled_with_the_fov_it_was_taken_with(world):
    """A capture taken with a 40-degree camera matches only when the pipeline uses that FOV (the
    node passes CameraFrame.fov_deg); the configured 60 degrees would scale it wrongly."""
    ref, day = world
    narrow = 40.0
    # Altitude at which the 40-degree camera sees exactly what the 60-degree one sees at ALT.
    alt = ALT * math.tan(math.radians(FOV) / 2.0) / math.tan(math.radians(narrow) / 2.0)
    img = render(day, 300.0, 200.0, 0.4)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE)
    right = pipe.process(img, 0.4, alt, 0.0, fov_deg=narrow)
    assert right.valid and err_m(right, (300.0, 200.0)) < 0.3
    pipe.reset()
    default = pipe.process(img, 0.4, ALT, 0.1)                   # cfg.fov_deg (60) at ALT: same scale
    assert err_m(default, (300.0, 200.0)) < 0.3
    pipe.reset()
    wrong = pipe.process(img, 0.4, alt, 0.2)                     # 60 degrees assumed at alt: too big
    assert not wrong.valid or wrong.metrics.peak < right.metrics.peak - 0.2


@pytest.mark.parametrize("method", [FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP,
                                    FalseMatchMethod.STATISTICAL, FalseMatchMethod.NONE])
def test_fixes_below_the_rated_height_are_rejected_unrated(world, method):
    """cnn / assistant-map: a capture covering less than min_rated_footprint_share of the rated
    footprint is matched (valid) but rejected without classification; other methods, and the gate
    off, decide as before."""
    ref, day = world
    calls = []

    def clf(batch):
        calls.append(len(batch))
        return cnn_fake(batch)

    def pipeline(share):
        cfg = dataclasses.replace(PerceptionConfig(), rated_altitude_m=ALT, min_rated_footprint_share=share)
        return PerceptionPipeline(ref, MPP, method, cfg, classify=clf)

    low_alt = ALT * 0.69        # 0.48 of the rated footprint's area
    img = render(day, 300.0, 200.0, 0.4)
    gated = method in (FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP)
    low = pipeline(0.5).process(img, 0.4, low_alt, 0.0)
    assert low.valid
    if gated:
        assert not low.accepted and low.reason is Reason.BELOW_RATED_HEIGHT and not calls
        assert math.isnan(low.p_true)
    else:
        assert low.reason is not Reason.BELOW_RATED_HEIGHT
    calls.clear()
    at_rated = pipeline(0.5).process(img, 0.4, ALT * 0.72, 0.0)     # 0.52 of the area: rated
    off = pipeline(0.0).process(img, 0.4, low_alt, 0.0)
    for r in (at_rated, off):
        assert r.valid and r.reason is not Reason.BELOW_RATED_HEIGHT
    assert calls == ([1, 1] if gated else [])


def test_pointing_term_geometry():
    """Attitude error: isotropic altitude * tan(sigma); heading error: |d| * sigma across the offset."""
    from perception.fix_covariance import pointing_covariance_m2
    c = pointing_covariance_m2(100.0, (0.0, 0.0), math.radians(1.0), math.radians(5.0))
    assert c == pytest.approx(np.eye(2) * (100.0 * math.tan(math.radians(1.0))) ** 2)
    c = pointing_covariance_m2(100.0, (0.0, 27.0), 0.0, math.radians(2.0))   # centre 27 m north
    assert math.sqrt(c[0, 0]) == pytest.approx(27.0 * math.radians(2.0))     # moves east-west
    assert c[1, 1] == pytest.approx(0.0) and c[0, 1] == pytest.approx(0.0)
    c = pointing_covariance_m2(100.0, (10.0, 10.0), 0.0, math.radians(2.0))  # across the diagonal
    w, v = np.linalg.eigh(c)
    assert w[0] == pytest.approx(0.0, abs=1e-12)
    assert abs(v[:, 1] @ np.array([1.0, -1.0]) / math.sqrt(2.0)) == pytest.approx(1.0)


def test_pointing_errors_widen_the_published_covariance_only(world):
    """The same captures with pointing_attitude_std_deg set: same positions and decisions, covariance
    wider by (altitude tan sigma)^2 on each axis (nadir capture: no heading term)."""
    ref, day = world
    plain = fly(PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE), day, 5)
    cfg = PerceptionConfig(pointing_attitude_std_deg=1.0, pointing_heading_std_deg=3.0)
    wide = fly(PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE, cfg), day, 5)
    extra = (ALT * math.tan(math.radians(1.0))) ** 2
    for (a, _), (b, _) in zip(plain, wide, strict=True):
        assert a.position_enu_m == b.position_enu_m and a.decision is b.decision
        assert b.covariance_m2 == pytest.approx(a.covariance_m2 + np.eye(2) * extra)
    with pytest.raises(UserError, match="pointing_attitude_std_deg"):
        PerceptionConfig(pointing_attitude_std_deg=-1.0)


def test_covariance_scale_scales_the_whole_published_covariance(world):
    """covariance_scale multiplies the published covariance, pointing term included; positions and
    decisions stay the same."""
    ref, day = world
    base = PerceptionConfig(pointing_attitude_std_deg=1.0)
    plain = fly(PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE, base), day, 5)
    scaled = fly(PerceptionPipeline(ref, MPP, FalseMatchMethod.NONE,
                                    dataclasses.replace(base, covariance_scale=0.25)), day, 5)
    for (a, _), (b, _) in zip(plain, scaled, strict=True):
        assert a.position_enu_m == b.position_enu_m and a.decision is b.decision
        assert b.covariance_m2 == pytest.approx(a.covariance_m2 * 0.25)
    with pytest.raises(UserError, match="covariance_scale"):
        PerceptionConfig(covariance_scale=0.0)


@pytest.mark.parametrize("continue_track", [False, True])
def test_a_trusted_track_continues_below_the_rated_height(world, continue_track):
    """Descending through the rated height over a good area: with track_below_rated the window
    matches that continue the accepted track are accepted (track-continuation); a capture of
    somewhere else is not (the track coasts through it), and a sharp match 4 m off the prediction
    ends the trust for good. Without it all are below-rated."""
    ref, day = world
    cfg = dataclasses.replace(PerceptionConfig(), rated_altitude_m=ALT, min_rated_footprint_share=0.5,
                              track_below_rated=continue_track)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.CNN, cfg, classify=cnn_fake)
    u, v, heading = 300.0, 200.0, 0.4
    for k in range(6):                       # at the rated height: accepted
        r = pipe.process(render(day, u + k, v, heading), heading, ALT, 0.1 * k)
        assert r.accepted and r.reason is Reason.ACCEPTED
    low = []
    for k in range(6, 12):                   # 0.6 x ALT: 0.36 of the rated area
        alt = ALT * 0.6
        low.append(pipe.process(render(day, u + k, v, heading, alt), heading, alt, 0.1 * k))
    assert all(r.valid for r in low)
    if continue_track:
        assert all(r.accepted and r.reason is Reason.TRACK_CONTINUATION for r in low)
        assert all(err_m(r, (u + 6 + i, v)) < 0.5 for i, r in enumerate(low))
        alt = ALT * 0.6
        elsewhere = pipe.process(render(day, u + 60, v + 40, heading, alt), heading, alt, 1.2)
        assert not elsewhere.accepted
        back = pipe.process(render(day, u + 13, v, heading, alt), heading, alt, 1.3)
        assert back.accepted and back.reason is Reason.TRACK_CONTINUATION, back.reason
        off = pipe.process(render(day, u + 14 + 8, v, heading, alt), heading, alt, 1.4)   # 4 m off
        assert off.valid and off.quality_ok and not off.accepted
        again = pipe.process(render(day, u + 15 + 8, v, heading, alt), heading, alt, 1.5)
        assert not again.accepted and again.reason is Reason.BELOW_RATED_HEIGHT   # trust is gone
    else:
        assert all(not r.accepted and r.reason is Reason.BELOW_RATED_HEIGHT for r in low)


def test_a_climb_below_the_rated_height_is_fixed_near_the_estimate(world):
    """Climbing below the rated height with no track (below_rated_near_estimate_m): the search goes
    around the estimate, and a window match that is the below_rated_min_run-th in a row on one
    constant-velocity line is accepted (near-estimate). Without an estimate, below
    below_rated_min_altitude_m, or with the option off, they are below-rated; a track that wanders
    farther from the estimate than the radius is rejected and dropped."""
    ref, day = world
    cfg = dataclasses.replace(PerceptionConfig(), rated_altitude_m=ALT, min_rated_footprint_share=0.5,
                              below_rated_near_estimate_m=20.0, below_rated_min_run=3,
                              below_rated_min_altitude_m=ALT * 0.5)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.CNN, cfg, classify=cnn_fake)
    u, v, heading, alt = 300.0, 200.0, 0.4, ALT * 0.6
    east, north = pipe.matcher.pixel_to_world(u, v)
    estimate = (east + 6.0, north - 4.0, 2.0, 2.0)          # 7 m off: within the 20 m window
    out = [pipe.process(render(day, u, v, heading, alt), heading, alt, 0.1 * k, estimate=estimate)
           for k in range(7)]
    assert all(r.valid and r.quality_ok and err_m(r, (u, v)) < 0.5 for r in out)
    # the 3rd match is the first on the line through two before it: the 5th is the 3rd in a row
    assert [r.accepted for r in out] == [False] * 4 + [True] * 3
    assert all(r.reason is Reason.BELOW_RATED_HEIGHT for r in out[:4])
    assert all(r.reason is Reason.NEAR_ESTIMATE for r in out[4:]) and pipe.near_estimate_accepted == 3
    # the estimate moves 40 m away: the track's next match is beyond the radius, rejected, dropped
    far = (east + 40.0, north, 2.0, 2.0)
    r = pipe.process(render(day, u, v, heading, alt), heading, alt, 0.8, estimate=far)
    assert r.valid and not r.accepted and r.reason is Reason.BELOW_RATED_HEIGHT
    assert pipe.tracker.state is not TrackState.TRACKING
    # off, no estimate, or too low: below-rated as before
    for radius, est, lowest in ((0.0, estimate, 0.0), (20.0, None, 0.0), (20.0, estimate, alt + 1.0)):
        other = PerceptionPipeline(ref, MPP, FalseMatchMethod.CNN,
                                   dataclasses.replace(cfg, below_rated_near_estimate_m=radius,
                                                       below_rated_min_altitude_m=lowest),
                                   classify=cnn_fake)
        rs = [other.process(render(day, u, v, heading, alt), heading, alt, 0.1 * k, estimate=est)
              for k in range(7)]
        assert all(not r.accepted and r.reason is Reason.BELOW_RATED_HEIGHT for r in rs)
    with pytest.raises(UserError, match="below_rated_near_estimate_m"):
        PerceptionConfig(below_rated_near_estimate_m=-1.0)
