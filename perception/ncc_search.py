"""Normalized cross-correlation search of the reference map (paper section 3, equation (1)).

``SceneMatcher.match`` correlates an aligned template with a window of the reference map cropped
around a predicted position (a view: the map is never copied or converted per fix), or with the whole
map when there is no prediction (coarse-to-fine on big maps). Every result carries quality metrics
(peak, PSR, second-peak ratio: ``perception.peak_metrics``), a sub-pixel position, a 2x2 covariance
(``perception.fix_covariance``) and per-stage timings. ``perception.tracker.MatchTracker`` decides
where to search.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from enum import Enum

import cv2
import numpy as np

from perception.config import MatcherConfig, NccMethod
from perception.fix_covariance import (
    ambiguity_weight,
    coarse_to_fine_covariance_m2,
    covariance_parts_px,
    px_to_enu_cov,
)
from perception.match_metrics import MatchMetrics, SearchTimes
from perception.ncc_fft import FftNcc
from perception.ncc_fft import warm_up as ncc_fft_warm_up
from perception.peak_metrics import (
    exclusion_radius,
    peak_to_sidelobe_ratio,
    second_peak_ratio,
    surface_peak_metrics,
)
from perception.peak_metrics import warm_up as peak_metrics_warm_up
from scenenav.core.frames import world_to_pixel

log = logging.getLogger(__name__)

_CV_METHOD = {NccMethod.CCORR_NORMED: cv2.TM_CCORR_NORMED,
              NccMethod.CCOEFF_NORMED: cv2.TM_CCOEFF_NORMED}
#: Template grey-level standard deviation below which the template is flat (no correlation defined).
FLAT_TEMPLATE_STD = 1e-4
_MS = 1000.0


class SearchMode(str, Enum):
    """How the reference was searched for one match."""

    WINDOW = "window"                  # a window around a predicted position
    GLOBAL = "global"                  # the whole map at full resolution
    COARSE_TO_FINE = "coarse-to-fine"  # whole map on a pyramid level, candidates verified full-res


@dataclass(frozen=True)
class MatchResult:
    """One NCC match. Positions are of the template centre (= the nadir point).

    ``position_px`` is in continuous map pixels (u column, v row; see scenenav/core/frames.py),
    ``position_enu_m`` in world ENU metres. ``covariance_m2`` is 2x2 (x east, y north).
    ``window_px`` = (u0, v0, width, height) of the reference area searched. ``timings``: wall-clock
    time of the window crop, the correlation and the peak refinement. ``gradient_shift_px``: how far
    the gradient refinement (``MatcherConfig.gradient_refine_radius_px``) moved the position from the
    intensity peak (NaN: not refined: off, a flat template, or no gradient peak inside the window).
    ``covariance_m2`` is the mixture "here, or anywhere in the area searched"
    (``perception.fix_covariance``); its parts: ``local_covariance_m2`` (here), ``ambiguity_weight``
    (the weight of "anywhere") and ``search_area_m2`` (the area searched).
    """

    position_px: tuple[float, float]
    position_enu_m: tuple[float, float]
    peak: float
    psr: float
    second_peak_ratio: float
    covariance_m2: np.ndarray
    quality_ok: bool
    peak_at_border: bool
    flat_template: bool
    search: SearchMode
    window_px: tuple[int, int, int, int]
    timings: SearchTimes = field(default_factory=SearchTimes)
    gradient_shift_px: float = math.nan
    local_covariance_m2: np.ndarray | None = None
    ambiguity_weight: float = 1.0
    search_area_m2: float = math.nan

    @property
    def metrics(self) -> MatchMetrics:
        """Peak, PSR and second-peak ratio as one typed value."""
        return MatchMetrics(self.peak, self.psr, self.second_peak_ratio)


def _timer() -> float:
    return time.perf_counter()


def gradient_magnitude(image: np.ndarray) -> np.ndarray:
    """Sobel (3 x 3) gradient magnitude of a float32 grey image, float32, same shape.

    The magnitude is numpy's sqrt(gx^2 + gy^2), not cv2.magnitude: OpenCV's vectorised magnitude
    gives other last bits depending on where the buffer lies in memory, and a last bit is enough to
    make two lockstep runs of one scenario differ (measured: cv2.magnitude on the same values at 16
    buffer offsets was not bit-identical; Sobel and this were).
    """
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3)
    np.multiply(gx, gx, out=gx)
    np.multiply(gy, gy, out=gy)
    np.add(gx, gy, out=gx)
    return np.sqrt(gx, out=gx)


#: A template pixel enters the gradient NCC only if its whole 3 x 3 Sobel support, and one pixel more,
#: is valid: the mask is eroded by this kernel (the edge of the mask is not an edge of the scene).
_GRADIENT_MASK_KERNEL = np.ones((5, 5), np.uint8)


def _is_flat(template: np.ndarray) -> bool:
    """Grey-level standard deviation below FLAT_TEMPLATE_STD (no correlation defined). One
    cv2.meanStdDev pass (double accumulators) instead of numpy's float32 mean, difference and square."""
    return float(cv2.meanStdDev(template)[1][0, 0]) < FLAT_TEMPLATE_STD


class SceneMatcher:
    """NCC matcher over one reference map (grey, float32, converted once here if given as uint8)."""

    def __init__(self, reference_gray: np.ndarray, m_per_px: float,
                 cfg: MatcherConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else MatcherConfig()
        if not isinstance(reference_gray, np.ndarray) or reference_gray.ndim != 2:
            raise ValueError("reference_gray: expected a 2-D grey image (H, W)")
        if not (math.isfinite(m_per_px) and m_per_px > 0.0):
            raise ValueError(f"m_per_px = {m_per_px!r}: expected a positive number")
        if reference_gray.dtype == np.uint8:
            ref = np.empty(reference_gray.shape, np.float32)
            np.multiply(reference_gray, np.float32(1.0 / 255.0), out=ref, casting="unsafe")
        elif reference_gray.dtype == np.float32:
            ref = np.ascontiguousarray(reference_gray)
        else:
            raise ValueError(f"reference_gray dtype {reference_gray.dtype}: expected uint8 or float32")
        self.reference = ref
        self.m_per_px = float(m_per_px)
        self.height_px, self.width_px = ref.shape
        self._method = _CV_METHOD[self.cfg.ncc_method]
        # window searches with the unmasked zero-mean NCC: our DFT correlation (perception.ncc_fft)
        self._fft = FftNcc() if self.cfg.ncc_method is NccMethod.CCOEFF_NORMED else None
        # numba kernels loaded now (once per process), not at the first fix: in lockstep a first fix
        # seconds late would time the node out
        peak_metrics_warm_up()
        if self._fft is not None:
            ncc_fft_warm_up()
        self._levels: list[tuple[int, np.ndarray]] = []   # (factor, level image), factor ascending
        if max(ref.shape) > self.cfg.coarse_above_px:
            self._build_pyramid()
        self._gradient_reference = (gradient_magnitude(ref) if self.cfg.gradient_refine_radius_px > 0
                                    else None)

    # ------------------------------------------------------------------------------ geometry
    def pixel_to_world(self, u: float, v: float) -> tuple[float, float]:
        """Continuous map pixel -> world ENU metres (``scenenav.core.frames.pixel_to_world``'s
        arithmetic on Python floats: the same bits without its array conversions)."""
        return ((float(u) - self.width_px / 2.0) * self.m_per_px,
                (self.height_px / 2.0 - float(v)) * self.m_per_px)

    def world_to_pixel(self, x_m: float, y_m: float) -> tuple[float, float]:
        """World ENU metres -> continuous map pixel."""
        return world_to_pixel(x_m, y_m, self.width_px, self.height_px, self.m_per_px)

    def _build_pyramid(self) -> None:
        t0 = _timer()
        img = self.reference
        factor = 1
        while max(img.shape) > self.cfg.coarse_target_px and min(img.shape) >= 2 * 8:
            img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
            factor *= 2
            self._levels.append((factor, img))
        log.info("reference %dx%d: pyramid factors %s built in %.0f ms", self.width_px, self.height_px,
                 [f for f, _ in self._levels], (_timer() - t0) * _MS)

    # ------------------------------------------------------------------------------ public
    def match(self, template: np.ndarray, predicted_uv: tuple[float, float] | None = None,
              search_radius_px: float | None = None, mask: np.ndarray | None = None) -> MatchResult:
        """Match ``template`` (float32, map resolution, north-up) against the reference.

        With ``predicted_uv`` (continuous pixels of the expected template centre) only a window of
        the template size plus ``search_radius_px`` (default: ``min_window_margin_px``) on each side
        is searched; without it the whole map is searched. ``mask`` (bool, template shape) marks
        valid template pixels; None or all-True uses the fast unmasked NCC.
        """
        t0 = _timer()
        template = self._check_template(template)
        mask_f = self._mask_or_none(mask, template.shape)
        flat = _is_flat(template)
        if predicted_uv is None:
            result = self._global(template, mask_f, flat, t0)
        else:
            radius = self.cfg.min_window_margin_px if search_radius_px is None else search_radius_px
            if not (math.isfinite(predicted_uv[0]) and math.isfinite(predicted_uv[1])
                    and math.isfinite(radius) and radius >= 0.0):
                raise ValueError(f"predicted_uv={predicted_uv}, search_radius_px={radius}: expected finite")
            result = self._windowed(template, mask_f, predicted_uv, radius, flat, t0)
        if self._gradient_reference is None or flat:
            return result
        return self._gradient_refined(result, template, mask_f)

    def _gradient_refined(self, result: MatchResult, template: np.ndarray,
                          mask: np.ndarray | None) -> MatchResult:
        """``result`` with its position from the gradient-magnitude NCC within
        ``gradient_refine_radius_px`` of its intensity peak (MatcherConfig); unchanged when the
        gradient surface has no peak inside that window (its maximum on the window's border)."""
        t0 = _timer()
        th, tw = template.shape
        gradient = gradient_magnitude(template)
        gmask = None
        if mask is not None:
            gmask = cv2.erode(mask, _GRADIENT_MASK_KERNEL)
            if not gmask.any():
                return result
        if float(cv2.meanStdDev(gradient, mask=None if gmask is None else gmask.astype(np.uint8))[1][0, 0]) \
                < FLAT_TEMPLATE_STD:
            return result
        x0, y0, x1, y1 = self._window_bounds(result.position_px, self.cfg.gradient_refine_radius_px, tw, th)
        values = self._correlate(self._gradient_reference[y0:y1, x0:x1], gradient, gmask)
        pk = surface_peak_metrics(values, (x0 == 0, x1 == self.width_px, y0 == 0, y1 == self.height_px),
                                  self.cfg.exclusion_radius_px)
        timings = dataclasses.replace(result.timings,
                                      refine_ms=result.timings.refine_ms + (_timer() - t0) * _MS)
        if pk.at_border:
            return dataclasses.replace(result, timings=timings)
        u = x0 + pk.ix + pk.dx + tw / 2.0
        v = y0 + pk.iy + pk.dy + th / 2.0
        shift = math.hypot(u - result.position_px[0], v - result.position_px[1])
        return dataclasses.replace(result, position_px=(float(u), float(v)),
                                   position_enu_m=self.pixel_to_world(u, v), timings=timings,
                                   gradient_shift_px=float(shift))

    # ------------------------------------------------------------------------------ checks
    def _check_template(self, template: np.ndarray) -> np.ndarray:
        if not isinstance(template, np.ndarray) or template.ndim != 2:
            raise ValueError("template: expected a 2-D float32 array")
        th, tw = template.shape
        if th > self.height_px or tw > self.width_px:
            raise ValueError(f"template {tw}x{th} px is larger than the map "
                             f"{self.width_px}x{self.height_px} px")
        if min(th, tw) < 2:
            raise ValueError(f"template {tw}x{th} px: expected at least 2 px per side")
        return np.ascontiguousarray(template, dtype=np.float32)

    @staticmethod
    def _mask_or_none(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
        if mask is None:
            return None
        if mask.shape != shape:
            raise ValueError(f"mask shape {mask.shape}: expected the template shape {shape}")
        if mask.all():
            return None
        return mask.astype(np.float32)

    # ------------------------------------------------------------------------------ correlation
    def _correlate(self, image: np.ndarray, template: np.ndarray,
                   mask: np.ndarray | None) -> np.ndarray:
        if mask is None:
            out = cv2.matchTemplate(image, template, self._method)
        else:
            out = cv2.matchTemplate(image, template, self._method, mask=mask)
        if not np.isfinite(out).all():
            np.nan_to_num(out, copy=False, nan=-1.0, posinf=-1.0, neginf=-1.0)
        return out

    def _window_bounds(self, centre_uv: tuple[float, float], radius: float,
                       tw: int, th: int) -> tuple[int, int, int, int]:
        r = int(math.ceil(radius))
        x_pred = int(round(centre_uv[0] - tw / 2.0))
        y_pred = int(round(centre_uv[1] - th / 2.0))
        x0 = min(max(x_pred - r, 0), self.width_px - tw)
        y0 = min(max(y_pred - r, 0), self.height_px - th)
        x1 = min(max(x_pred + r + tw, x0 + tw), self.width_px)
        y1 = min(max(y_pred + r + th, y0 + th), self.height_px)
        return x0, y0, x1, y1

    def _windowed(self, template: np.ndarray, mask: np.ndarray | None,
                  centre_uv: tuple[float, float], radius: float, flat: bool,
                  t0: float | None = None) -> MatchResult:
        if t0 is None:
            t0 = _timer()
        th, tw = template.shape
        x0, y0, x1, y1 = self._window_bounds(centre_uv, radius, tw, th)
        t1 = _timer()
        argmax = -1
        if flat:
            values = np.zeros((y1 - y0 - th + 1, x1 - x0 - tw + 1), np.float32)
        elif mask is None and self._fft is not None:
            values, argmax = self._fft.surface(self.reference, x0, y0, x1, y1, template)
        else:
            values = self._correlate(self.reference[y0:y1, x0:x1], template, mask)   # a view, never a copy
        t2 = _timer()
        n_valid = None if mask is None else int(np.count_nonzero(mask))
        return self._finish(values, x0, y0, (x0 == 0, x1 == self.width_px, y0 == 0, y1 == self.height_px),
                            tw, th, flat, SearchMode.WINDOW, (x0, y0, x1 - x0, y1 - y0), n_valid,
                            (t1 - t0) * _MS, (t2 - t1) * _MS, t2, argmax)

    def _global(self, template: np.ndarray, mask: np.ndarray | None, flat: bool,
                t0: float) -> MatchResult:
        th, tw = template.shape
        level = self._pick_level(tw, th)
        if level is None:
            t0 = _timer()
            values = (np.zeros((self.height_px - th + 1, self.width_px - tw + 1), np.float32) if flat
                      else self._correlate(self.reference, template, mask))
            t1 = _timer()
            n_valid = None if mask is None else int(np.count_nonzero(mask))
            return self._finish(values, 0, 0, (True, True, True, True), tw, th, flat, SearchMode.GLOBAL,
                                (0, 0, self.width_px, self.height_px), n_valid, 0.0, (t1 - t0) * _MS, t1)
        return self._coarse_to_fine(template, mask, level, flat, t0)

    def _pick_level(self, tw: int, th: int) -> tuple[int, np.ndarray] | None:
        best = None
        for factor, img in self._levels:
            if min(tw, th) / factor >= self.cfg.min_coarse_template_px:
                best = (factor, img)
        if best is None and self._levels:
            log.warning("template %dx%d px too small for the coarse levels: full-resolution global "
                        "search on a %dx%d map", tw, th, self.width_px, self.height_px)
        return best

    def _coarse_to_fine(self, template: np.ndarray, mask: np.ndarray | None,
                        level: tuple[int, np.ndarray], flat: bool, t0: float) -> MatchResult:
        cfg = self.cfg
        factor, img = level
        th, tw = template.shape
        fx = self.width_px / img.shape[1]
        fy = self.height_px / img.shape[0]
        ctw = max(2, int(round(tw / fx)))
        cth = max(2, int(round(th / fy)))
        ctemplate = cv2.resize(template, (ctw, cth), interpolation=cv2.INTER_AREA)
        cmask = None
        if mask is not None:
            cmask = (cv2.resize(mask, (ctw, cth), interpolation=cv2.INTER_AREA) > 0.999).astype(
                np.float32)
        t1 = _timer()
        if flat:
            cvalues = np.zeros((img.shape[0] - cth + 1, img.shape[1] - ctw + 1), np.float32)
        else:
            cvalues = self._correlate(img, ctemplate, cmask)
        t2 = _timer()
        # Coarse metrics (over the whole map) and the top candidates, suppressed around each.
        ciy, cix = np.unravel_index(int(np.argmax(cvalues)), cvalues.shape)
        cpeak = float(cvalues[ciy, cix])
        cexcl = exclusion_radius(cvalues, int(cix), int(ciy),
                                  max(2, int(math.ceil(cfg.exclusion_radius_px / factor))))
        cpsr = peak_to_sidelobe_ratio(cvalues, int(cix), int(ciy), cpeak, cexcl)
        cspr = second_peak_ratio(cvalues, int(cix), int(ciy), cpeak, cexcl)
        nms = max(cexcl, min(ctw, cth) // 4)
        work = cvalues.copy()
        candidates = []
        for _ in range(cfg.coarse_candidates):
            iy, ix = np.unravel_index(int(np.argmax(work)), work.shape)
            if not math.isfinite(float(work[iy, ix])) or work[iy, ix] <= -1.0:
                break
            candidates.append(((ix + ctw / 2.0) * fx, (iy + cth / 2.0) * fy))
            work[max(0, iy - nms):iy + nms + 1, max(0, ix - nms):ix + nms + 1] = -np.inf
        t3 = _timer()
        # Verify each candidate at full resolution in a small window.
        radius = 2.0 * max(fx, fy) + cfg.exclusion_radius_px
        fine: list[MatchResult] = []
        for cand in candidates:
            fine.append(self._windowed(template, mask, cand, radius, flat))
        t4 = _timer()
        fine.sort(key=lambda r: r.peak, reverse=True)
        best = fine[0]
        distinct = [r for r in fine[1:]
                    if math.hypot(r.position_px[0] - best.position_px[0],
                                  r.position_px[1] - best.position_px[1]) > cfg.exclusion_radius_px]
        if distinct and best.peak > 0.0:
            spr = max(0.0, distinct[0].peak) / best.peak
        else:
            spr = cspr
        rx, ry = self.width_px / 2.0, self.height_px / 2.0
        cov = coarse_to_fine_covariance_m2(cfg, best.covariance_m2, best.peak, self.m_per_px,
                                           cpsr, spr, rx, ry)
        m2 = self.m_per_px * self.m_per_px
        fine_ncc = sum(r.timings.ncc_ms for r in fine)
        fine_other = (t4 - t3) * _MS - fine_ncc
        result = MatchResult(
            position_px=best.position_px, position_enu_m=best.position_enu_m, peak=best.peak,
            psr=cpsr, second_peak_ratio=spr, covariance_m2=cov,
            quality_ok=self._quality_ok(best.peak, cpsr, spr, best.peak_at_border, flat),
            peak_at_border=best.peak_at_border, flat_template=flat, search=SearchMode.COARSE_TO_FINE,
            window_px=(0, 0, self.width_px, self.height_px),
            timings=SearchTimes(crop_ms=(t1 - t0) * _MS, ncc_ms=(t2 - t1) * _MS + fine_ncc,
                                refine_ms=(t3 - t2) * _MS + fine_other),
            local_covariance_m2=best.local_covariance_m2,
            ambiguity_weight=ambiguity_weight(cfg, cpsr, spr, best.peak),
            search_area_m2=4.0 * rx * ry * m2)
        return result

    # ------------------------------------------------------------------------------ metrics
    def _finish(self, vals: np.ndarray, u0: int, v0: int, at_map_edge: tuple[bool, bool, bool, bool],
                tw: int, th: int, flat: bool, search: SearchMode, window: tuple[int, int, int, int],
                n_valid_px: int | None, crop_ms: float, ncc_ms: float, t_refine: float,
                argmax: int = -1) -> MatchResult:
        """Peak, metrics and covariance of the surface ``vals`` whose (0, 0) is map pixel (u0, v0);
        ``at_map_edge``: left, right, top, bottom of the window is the map edge. ``t_refine``: when
        the correlation ended (the refinement time is measured from it). ``argmax``: the flat index
        of the surface's first maximum when the correlation found it (-1: search it here)."""
        cfg = self.cfg
        pk = surface_peak_metrics(vals, at_map_edge, cfg.exclusion_radius_px, argmax)
        if flat:
            psr, spr = 0.0, 1.0
            peak = 0.0
        else:
            peak, psr, spr = pk.value, pk.psr, pk.second_peak_ratio
        u = u0 + pk.ix + pk.dx + tw / 2.0
        v = v0 + pk.iy + pk.dy + th / 2.0
        rx = max(0.5, (vals.shape[1]) / 2.0)
        ry = max(0.5, (vals.shape[0]) / 2.0)
        n_px = tw * th if n_valid_px is None else n_valid_px
        cov, local, w = covariance_parts_px(cfg, peak, pk.curvature, pk.edge_axes, psr, spr, rx, ry, n_px)
        x, y = self.pixel_to_world(u, v)
        cov_m2 = px_to_enu_cov(cov, self.m_per_px)
        quality_ok = self._quality_ok(peak, psr, spr, pk.at_border, flat)
        return MatchResult(
            position_px=(float(u), float(v)), position_enu_m=(x, y), peak=float(peak), psr=float(psr),
            second_peak_ratio=float(spr), covariance_m2=cov_m2, quality_ok=quality_ok,
            peak_at_border=pk.at_border, flat_template=flat, search=search, window_px=window,
            timings=SearchTimes(crop_ms=crop_ms, ncc_ms=ncc_ms, refine_ms=(_timer() - t_refine) * _MS),
            local_covariance_m2=px_to_enu_cov(local, self.m_per_px),
            ambiguity_weight=w,
            search_area_m2=4.0 * rx * ry * self.m_per_px * self.m_per_px)

    def _quality_ok(self, peak: float, psr: float, spr: float, at_border: bool, flat: bool) -> bool:
        cfg = self.cfg
        return bool(not flat and not at_border and peak >= cfg.min_peak and psr >= cfg.min_psr
                    and spr <= cfg.max_second_peak_ratio)
