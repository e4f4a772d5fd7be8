"""Matchability: how often a capture taken at a position really matches there (beyond the paper).

For a map position (u, v) we simulate ``n_captures`` noisy nadir captures from the ORTHOPHOTO (what
the camera sees) and match each against the REFERENCE map (the map of another day) with zero-mean
normalised cross-correlation (``cv2.TM_CCOEFF_NORMED``, the matcher's default score). The
matchability is the share of captures whose correlation peak lands within ``tolerance_m`` (5 m) of
the true match position (the true position moved by the reference misregistration the world states,
``CaptureScene.true_match_uv``).

The world comes as a ``perception.capture.CaptureScene``: on a world with a surface model (and
relief on, the default) the captures are rendered in perspective through the relief renderer and
matched against the chosen reference (orthophoto or the perspective one); on a flat world, or with
relief off, they are today's images.

One simulated capture:

1. a random true heading psi ~ U[0, 2 pi); the 200 x 200 camera image (``CaptureScene.camera_image``)
   is, on a flat scene, resampled from the orthophoto with one bilinear ``warpAffine``
   (``render_camera``: image-up = forward, camera ground sampling distance = 2 h tan(fov / 2) / 200
   at the TRUE altitude h), with relief rendered from the pose at h;
2. photometric noise on the camera image: gain, offset, gamma, Gaussian blur, additive noise;
3. alignment exactly as in flight (``perception.alignment.align_capture``, north-up, inscribed
   square, map scale) with the MEASURED heading psi + N(0, heading_sigma) and altitude
   h (1 + N(0, altitude_sigma_rel));
4. NCC against the reference map. Approximation: only a window of top-left offsets within
   +-``search_radius_px`` (default 100 px = 53 m) of the truth is searched, not the whole map. A false
   peak further away than that is missed, so the windowed matchability is an upper bound of the
   global one; ``validate_windowed`` measures the agreement on a subset with a global search.

Everything random comes from a seeded ``numpy.random.Generator``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np
from tqdm import tqdm

from perception.alignment import align_capture
from scenenav.core.camera_geometry import ground_footprint_m

if TYPE_CHECKING:
    from perception.capture import CaptureScene

log = logging.getLogger(__name__)

CAMERA_PX = 200
"""The paper's camera image size (section 6.1: 200 x 200, 60 degree field of view)."""
GLOBAL_SEARCH = -1
"""``search_radius_px`` value meaning: search the whole reference map."""


@dataclass(frozen=True)
class CaptureNoise:
    """Noise of one simulated capture (sensor errors + photometry).

    heading_sigma_deg: compass error (1 sigma); altitude_sigma_rel: barometric altitude error as a
    fraction of the altitude (2 % = 2 m at 100 m), it becomes a template scale error; the rest are
    photometric: gain ~ U[gain_min, gain_max], offset ~ U[-offset_max, offset_max],
    gamma ~ exp(U[-log_gamma_max, log_gamma_max]), Gaussian blur sigma ~ U[0, blur_sigma_max_px]
    (camera pixels), additive Gaussian noise sigma ``noise_sigma`` (grey levels in [0, 1]).
    """

    heading_sigma_deg: float = 2.0
    altitude_sigma_rel: float = 0.02
    gain_min: float = 0.8
    gain_max: float = 1.2
    offset_max: float = 0.05
    log_gamma_max: float = 0.2
    blur_sigma_max_px: float = 1.0
    noise_sigma: float = 0.02


@dataclass(frozen=True)
class MatchabilityConfig:
    """How matchability is simulated. ``search_radius_px = GLOBAL_SEARCH`` searches the whole map."""

    n_captures: int = 8
    tolerance_m: float = 5.0
    search_radius_px: int = 100
    altitude_m: float = 100.0
    fov_deg: float = 60.0
    noise: CaptureNoise = field(default_factory=CaptureNoise)

    def __post_init__(self) -> None:
        if self.n_captures < 1:
            raise ValueError(f"n_captures = {self.n_captures}: expected >= 1")
        if self.tolerance_m <= 0.0:
            raise ValueError(f"tolerance_m = {self.tolerance_m}: expected > 0")
        if self.search_radius_px != GLOBAL_SEARCH and self.search_radius_px < 1:
            raise ValueError(f"search_radius_px = {self.search_radius_px}: expected >= 1 or {GLOBAL_SEARCH}")


@dataclass(frozen=True)
class CaptureOutcome:
    """One simulated capture matched against the reference."""

    template: np.ndarray        # aligned north-up template (float32, [0, 1])
    camera_image: np.ndarray    # the raw 200 x 200 camera image (float32, [0, 1]) = online CNN input
    est_uv: tuple[float, float]
    error_m: float
    peak: float
    heading_rad: float

    def is_true(self, tolerance_m: float) -> bool:
        return self.error_m <= tolerance_m


@dataclass(frozen=True)
class MatchabilityResult:
    """Per position: ``score`` (K,) share of true matches; ``errors_m`` (K, n_captures)."""

    score: np.ndarray
    errors_m: np.ndarray
    peaks: np.ndarray


def footprint_px(altitude_m: float, fov_deg: float, m_per_px: float) -> int:
    """Side of the camera footprint in map pixels, rounded down (100 m, 60 deg, 0.53 m/px -> 217)."""
    return int(math.floor(ground_footprint_m(altitude_m, fov_deg) / m_per_px + 1e-9))


def render_camera(ortho_gray: np.ndarray, u: float, v: float, heading_rad: float, altitude_m: float,
                  fov_deg: float, m_per_px: float, camera_px: int = CAMERA_PX) -> np.ndarray:
    """The nadir camera image at map position (u, v) (continuous px) and compass heading.

    Image-up is the forward direction: camera offset (dx right, dy down) -> map offset
    g R(psi) (dx, dy) with R = [[cos, -sin], [sin, cos]] and g = map px per camera px.
    """
    g = ground_footprint_m(altitude_m, fov_deg) / m_per_px / camera_px
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    a = g * np.array([[c, -s], [s, c]])
    c_cam = np.array([(camera_px - 1) / 2.0, (camera_px - 1) / 2.0])
    c_map = np.array([u - 0.5, v - 0.5])          # continuous -> pixel-index coordinates
    m = np.hstack([a, (c_map - a @ c_cam)[:, None]])
    return cv2.warpAffine(ortho_gray, m, (camera_px, camera_px), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT_101)


def photometric_noise(img: np.ndarray, rng: np.random.Generator, noise: CaptureNoise) -> np.ndarray:
    """Gain, offset, gamma, blur and additive noise; clipped to [0, 1]."""
    out = img
    sigma = rng.uniform(0.0, noise.blur_sigma_max_px)
    if sigma > 0.2:
        out = cv2.GaussianBlur(out, (0, 0), sigma, borderType=cv2.BORDER_REFLECT_101)
    gamma = math.exp(rng.uniform(-noise.log_gamma_max, noise.log_gamma_max))
    out = np.power(np.clip(out, 0.0, 1.0), gamma, dtype=np.float32)
    out = out * np.float32(rng.uniform(noise.gain_min, noise.gain_max)) + np.float32(
        rng.uniform(-noise.offset_max, noise.offset_max))
    if noise.noise_sigma > 0.0:
        out = out + rng.normal(0.0, noise.noise_sigma, out.shape).astype(np.float32)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def ncc_peak(reference_gray: np.ndarray, template: np.ndarray, u: float, v: float,
             search_radius_px: int) -> tuple[float, float, float]:
    """Best TM_CCOEFF_NORMED placement of ``template`` around true centre (u, v) -> (est_u, est_v, peak).

    The window holds every top-left offset within +-search_radius_px of the true one (clipped to the
    map); ``GLOBAL_SEARCH`` searches the whole map. Estimates are continuous template centres.
    """
    th, tw = template.shape
    hh, ww = reference_gray.shape
    if search_radius_px == GLOBAL_SEARCH:
        x0, y0, x1, y1 = 0, 0, ww, hh
    else:
        tx = int(round(u - tw / 2.0))
        ty = int(round(v - th / 2.0))
        x0 = max(0, tx - search_radius_px)
        y0 = max(0, ty - search_radius_px)
        x1 = min(ww, tx + search_radius_px + tw)
        y1 = min(hh, ty + search_radius_px + th)
    window = reference_gray[y0:y1, x0:x1]
    if window.shape[0] < th or window.shape[1] < tw:
        return float("nan"), float("nan"), float("nan")
    res = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    _, peak, _, loc = cv2.minMaxLoc(res)
    return x0 + loc[0] + tw / 2.0, y0 + loc[1] + th / 2.0, float(peak)


def simulate_capture(scene: CaptureScene, u: float, v: float, cfg: MatchabilityConfig,
                     rng: np.random.Generator, search_radius_px: int | None = None) -> CaptureOutcome:
    """One noisy capture at (u, v), aligned as in flight and matched against the scene's reference;
    the error is against the true match position (misregistration applied)."""
    noise = cfg.noise
    heading = rng.uniform(0.0, 2.0 * math.pi)
    cam = scene.camera_image(u, v, heading, cfg.altitude_m, cfg.fov_deg, CAMERA_PX)
    cam = photometric_noise(cam, rng, noise)
    heading_meas = heading + math.radians(rng.normal(0.0, noise.heading_sigma_deg))
    alt_meas = cfg.altitude_m * (1.0 + rng.normal(0.0, noise.altitude_sigma_rel))
    aligned = align_capture(cam, heading_meas, max(alt_meas, 1.0), cfg.fov_deg, scene.m_per_px)
    radius = cfg.search_radius_px if search_radius_px is None else search_radius_px
    tu, tv = scene.true_match_uv(u, v)
    eu, ev, peak = ncc_peak(scene.reference_gray, aligned.template, tu, tv, radius)
    err = math.hypot(eu - tu, ev - tv) * scene.m_per_px if math.isfinite(eu) else float("inf")
    return CaptureOutcome(template=aligned.template, camera_image=cam, est_uv=(eu, ev), error_m=err,
                          peak=peak, heading_rad=heading)


def matchability(scene: CaptureScene, positions_uv: np.ndarray, cfg: MatchabilityConfig,
                 rng: np.random.Generator, progress: bool = False,
                 search_radius_px: int | None = None) -> MatchabilityResult:
    """Matchability of every position (K, 2) (continuous (u, v) px): share of true matches."""
    pos = np.asarray(positions_uv, dtype=float).reshape(-1, 2)
    k, n = len(pos), cfg.n_captures
    errors = np.empty((k, n))
    peaks = np.empty((k, n))
    it = tqdm(range(k), desc="matchability", unit="pos", disable=not progress, leave=False)
    for i in it:
        u, v = pos[i]
        for j in range(n):
            out = simulate_capture(scene, u, v, cfg, rng, search_radius_px)
            errors[i, j] = out.error_m
            peaks[i, j] = out.peak
    score = np.mean(errors <= cfg.tolerance_m, axis=1) if k else np.zeros(0)
    return MatchabilityResult(score=score, errors_m=errors, peaks=peaks)


def validate_windowed(scene: CaptureScene, positions_uv: np.ndarray, cfg: MatchabilityConfig,
                      seed: int) -> dict[str, float]:
    """Compare windowed and global search on the same simulated captures (same seed per position).

    Returns the per-capture agreement of the true/false outcome, the share of captures true in the
    window but false globally (false peaks outside the window), and the mean score difference.
    """
    pos = np.asarray(positions_uv, dtype=float).reshape(-1, 2)
    if len(pos) == 0:
        return {"n_positions": 0.0}
    win = matchability(scene, pos, cfg, np.random.default_rng(seed))
    glo = matchability(scene, pos, cfg, np.random.default_rng(seed), search_radius_px=GLOBAL_SEARCH)
    tw = win.errors_m <= cfg.tolerance_m
    tg = glo.errors_m <= cfg.tolerance_m
    return {
        "n_positions": float(len(pos)),
        "n_captures": float(tw.size),
        "capture_agreement": float(np.mean(tw == tg)),
        "true_in_window_false_globally": float(np.mean(tw & ~tg)),
        "mean_score_window": float(np.mean(win.score)),
        "mean_score_global": float(np.mean(glo.score)),
        "label_agreement_at_0.5": float(np.mean((win.score >= 0.5) == (glo.score >= 0.5))),
    }
