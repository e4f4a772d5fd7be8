"""Normalized cross-correlation scene matcher (paper section 3, equation (1)) and its tracker.

``SceneMatcher.match`` correlates an aligned template with a window of the reference map cropped
around a predicted position (a view: the map is never copied or converted per fix), or with the whole
map when there is no prediction (coarse-to-fine on big maps). Every result carries quality metrics
(peak, PSR, second-peak ratio), a sub-pixel position, a 2x2 covariance and per-stage timings.
``MatchTracker`` predicts the next position (constant velocity), sizes the window from the predicted
movement and the template size, and falls back to a global search after N low-quality matches.

Covariance (computed in pixels^2 on the (u, v) axes, then converted to ENU m^2: times m_per_px^2,
cross term negated because v points south), see docs/perception.md:

    C = s * (1 - r^2) / (N_eff r) * A^-1  +  floor^2 I  +  w * diag(Rx^2, Ry^2) / 3

``r`` is the peak NCC and ``A`` minus the Hessian of the paraboloid fitted to its 3x3 neighbourhood.
The first term propagates the correlation noise through the peak fit: the part of the capture that
does not match (energy fraction 1 - r^2) adds noise of variance (1 - r^2) / N_eff to the surface,
where N_eff = n_px sqrt(det(A / r)) / (2 pi) is the number of independent pixels in the template
(template area over the area of the correlation lobe); the peak moves by that noise's gradient over
the curvature. ``s`` is ``cov_local_scale``, ``floor`` is ``cov_floor_px`` (interpolation,
resampling and sensor errors the noise model does not see). ``w`` in [0, 1] is the ambiguity
weight, 0 when PSR >= psr_confident and second_peak_ratio <= second_peak_ratio_confident, rising
linearly to 1 at min_psr / max_second_peak_ratio; ``Rx, Ry`` are the half-extents of the search (a
uniform distribution over the searched area has variance R^2 / 3). An ambiguous match therefore gets a
covariance as wide as the area searched.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field
from enum import Enum

import cv2
import numpy as np

from perception.config import MatcherConfig, NccMethod
from scenenav.core.frames import pixel_to_world, world_to_pixel

log = logging.getLogger(__name__)

_CV_METHOD = {NccMethod.CCORR_NORMED: cv2.TM_CCORR_NORMED,
              NccMethod.CCOEFF_NORMED: cv2.TM_CCOEFF_NORMED}
#: Template grey-level standard deviation below which the template is flat (no correlation defined).
FLAT_TEMPLATE_STD = 1e-4
#: Floor on the side-lobe standard deviation in the PSR denominator.
_SIDELOBE_STD_FLOOR = 1e-6
#: Floor on 1 - peak^2 in the local term (a perfect match still has interpolation error).
_MISMATCH_FLOOR = 1e-3
#: Floor on the peak in the local term (a peak near 0 carries no position information anyway).
_PEAK_FLOOR = 0.05
#: Variance (px^2) of an axis whose peak sits on the map edge (no curvature available).
_EDGE_AXIS_VAR_PX2 = 1.0
_MS = 1000.0


def _paraboloid_pinv() -> np.ndarray:
    rows = []
    for y in (-1.0, 0.0, 1.0):
        for x in (-1.0, 0.0, 1.0):
            rows.append([1.0, x, y, x * x, x * y, y * y])
    return np.linalg.pinv(np.asarray(rows))


_PARABOLOID_PINV = _paraboloid_pinv()   # (6, 9): least-squares f = a0 + a1 x + a2 y + a3 x^2 + a4 xy + a5 y^2


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
    ``window_px`` = (u0, v0, width, height) of the reference area searched. ``timings_ms`` has
    ``crop``, ``ncc`` and ``refine``.
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
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class _Surface:
    """Correlation surface over a window, with the window's origin in map pixels."""

    values: np.ndarray
    u0: int
    v0: int
    at_map_edge: tuple[bool, bool, bool, bool]   # left, right, top, bottom of the window is the map edge


@dataclass(frozen=True)
class _Peak:
    ix: int
    iy: int
    dx: float
    dy: float
    value: float
    curvature: np.ndarray | None   # A = -Hessian (2x2), None when not a proper maximum
    edge_axes: tuple[bool, bool]   # x / y axis had no neighbour on one side (map edge)
    at_border: bool                # at a window edge that is not the map edge


def _timer() -> float:
    return time.perf_counter()


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
        self._levels: list[tuple[int, np.ndarray]] = []   # (factor, level image), factor ascending
        if max(ref.shape) > self.cfg.coarse_above_px:
            self._build_pyramid()

    # ------------------------------------------------------------------------------ geometry
    def pixel_to_world(self, u: float, v: float) -> tuple[float, float]:
        """Continuous map pixel -> world ENU metres."""
        return pixel_to_world(u, v, self.width_px, self.height_px, self.m_per_px)

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
        template = self._check_template(template)
        mask_f = self._mask_or_none(mask, template.shape)
        if predicted_uv is None:
            return self._global(template, mask_f)
        radius = self.cfg.min_window_margin_px if search_radius_px is None else search_radius_px
        if not (math.isfinite(predicted_uv[0]) and math.isfinite(predicted_uv[1])
                and math.isfinite(radius) and radius >= 0.0):
            raise ValueError(f"predicted_uv={predicted_uv}, search_radius_px={radius}: expected finite")
        return self._windowed(template, mask_f, predicted_uv, radius)

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
                  centre_uv: tuple[float, float], radius: float) -> MatchResult:
        t0 = _timer()
        th, tw = template.shape
        x0, y0, x1, y1 = self._window_bounds(centre_uv, radius, tw, th)
        window = self.reference[y0:y1, x0:x1]          # a view, never a copy
        flat = float(template.std()) < FLAT_TEMPLATE_STD
        t1 = _timer()
        values = (np.zeros((y1 - y0 - th + 1, x1 - x0 - tw + 1), np.float32) if flat
                  else self._correlate(window, template, mask))
        t2 = _timer()
        surface = _Surface(values, x0, y0, (x0 == 0, x1 == self.width_px, y0 == 0,
                                            y1 == self.height_px))
        n_valid = None if mask is None else int(np.count_nonzero(mask))
        result = self._finish(surface, tw, th, flat, SearchMode.WINDOW, (x0, y0, x1 - x0, y1 - y0),
                              n_valid)
        t3 = _timer()
        result.timings_ms.update(crop=(t1 - t0) * _MS, ncc=(t2 - t1) * _MS, refine=(t3 - t2) * _MS)
        return result

    def _global(self, template: np.ndarray, mask: np.ndarray | None) -> MatchResult:
        th, tw = template.shape
        level = self._pick_level(tw, th)
        if level is None:
            t0 = _timer()
            flat = float(template.std()) < FLAT_TEMPLATE_STD
            values = (np.zeros((self.height_px - th + 1, self.width_px - tw + 1), np.float32) if flat
                      else self._correlate(self.reference, template, mask))
            t1 = _timer()
            surface = _Surface(values, 0, 0, (True, True, True, True))
            n_valid = None if mask is None else int(np.count_nonzero(mask))
            result = self._finish(surface, tw, th, flat, SearchMode.GLOBAL,
                                  (0, 0, self.width_px, self.height_px), n_valid)
            result.timings_ms.update(crop=0.0, ncc=(t1 - t0) * _MS, refine=(_timer() - t1) * _MS)
            return result
        return self._coarse_to_fine(template, mask, level)

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
                        level: tuple[int, np.ndarray]) -> MatchResult:
        cfg = self.cfg
        t0 = _timer()
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
        flat = float(template.std()) < FLAT_TEMPLATE_STD
        t1 = _timer()
        if flat:
            cvalues = np.zeros((img.shape[0] - cth + 1, img.shape[1] - ctw + 1), np.float32)
        else:
            cvalues = self._correlate(img, ctemplate, cmask)
        t2 = _timer()
        # Coarse metrics (over the whole map) and the top candidates, suppressed around each.
        ciy, cix = np.unravel_index(int(np.argmax(cvalues)), cvalues.shape)
        cpeak = float(cvalues[ciy, cix])
        cexcl = _exclusion_radius(cvalues, int(cix), int(ciy),
                                  max(2, int(math.ceil(cfg.exclusion_radius_px / factor))))
        cpsr = _psr(cvalues, int(cix), int(ciy), cpeak, cexcl)
        cspr = _second_peak_ratio(cvalues, int(cix), int(ciy), cpeak, cexcl)
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
            fine.append(self._windowed(template, mask, cand, radius))
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
        cov = self._covariance_from(best, cpsr, spr, rx, ry)
        fine_ncc = sum(r.timings_ms["ncc"] for r in fine)
        fine_other = (t4 - t3) * _MS - fine_ncc
        result = MatchResult(
            position_px=best.position_px, position_enu_m=best.position_enu_m, peak=best.peak,
            psr=cpsr, second_peak_ratio=spr, covariance_m2=cov,
            quality_ok=self._quality_ok(best.peak, cpsr, spr, best.peak_at_border, flat),
            peak_at_border=best.peak_at_border, flat_template=flat, search=SearchMode.COARSE_TO_FINE,
            window_px=(0, 0, self.width_px, self.height_px),
            timings_ms={"crop": (t1 - t0) * _MS, "ncc": (t2 - t1) * _MS + fine_ncc,
                        "refine": (t3 - t2) * _MS + fine_other})
        return result

    # ------------------------------------------------------------------------------ metrics
    def _finish(self, surface: _Surface, tw: int, th: int, flat: bool, search: SearchMode,
                window: tuple[int, int, int, int], n_valid_px: int | None = None) -> MatchResult:
        cfg = self.cfg
        vals = surface.values
        iy, ix = np.unravel_index(int(np.argmax(vals)), vals.shape)
        pk = _refine_peak(vals, int(ix), int(iy), surface.at_map_edge)
        if flat:
            psr, spr = 0.0, 1.0
            peak = 0.0
        else:
            peak = pk.value
            excl = _exclusion_radius(vals, pk.ix, pk.iy, cfg.exclusion_radius_px)
            psr = _psr(vals, pk.ix, pk.iy, peak, excl)
            spr = _second_peak_ratio(vals, pk.ix, pk.iy, peak, excl)
        u = surface.u0 + pk.ix + pk.dx + tw / 2.0
        v = surface.v0 + pk.iy + pk.dy + th / 2.0
        rx = max(0.5, (vals.shape[1]) / 2.0)
        ry = max(0.5, (vals.shape[0]) / 2.0)
        n_px = tw * th if n_valid_px is None else n_valid_px
        cov = self._covariance_px(peak, pk.curvature, pk.edge_axes, psr, spr, rx, ry, n_px)
        x, y = self.pixel_to_world(u, v)
        return MatchResult(
            position_px=(float(u), float(v)), position_enu_m=(x, y), peak=float(peak), psr=float(psr),
            second_peak_ratio=float(spr), covariance_m2=_px_to_enu_cov(cov, self.m_per_px),
            quality_ok=self._quality_ok(peak, psr, spr, pk.at_border, flat),
            peak_at_border=pk.at_border, flat_template=flat, search=search, window_px=window,
            timings_ms={})

    def _quality_ok(self, peak: float, psr: float, spr: float, at_border: bool, flat: bool) -> bool:
        cfg = self.cfg
        return bool(not flat and not at_border and peak >= cfg.min_peak and psr >= cfg.min_psr
                    and spr <= cfg.max_second_peak_ratio)

    def _ambiguity_weight(self, psr: float, spr: float, peak: float = 1.0) -> float:
        cfg = self.cfg
        if not (math.isfinite(psr) and math.isfinite(spr) and math.isfinite(peak)):
            return 1.0
        w_psr = (cfg.psr_confident - psr) / (cfg.psr_confident - cfg.min_psr)
        w_spr = (spr - cfg.second_peak_ratio_confident) / (
            cfg.max_second_peak_ratio - cfg.second_peak_ratio_confident)
        w_peak = (cfg.peak_confident - peak) / (cfg.peak_confident - cfg.min_peak)
        return float(min(1.0, max(0.0, w_psr, w_spr, w_peak)))

    def _covariance_px(self, peak: float, curvature: np.ndarray | None, edge_axes: tuple[bool, bool],
                       psr: float, spr: float, rx: float, ry: float, n_px: int) -> np.ndarray:
        """Covariance in px^2 (see the module docstring)."""
        cfg = self.cfg
        uniform = np.diag([rx * rx / 3.0, ry * ry / 3.0])
        if curvature is None or peak <= 0.0:
            local = uniform.copy()
        else:
            r = max(peak, _PEAK_FLOOR)
            n_eff = max(1.0, n_px * math.sqrt(max(np.linalg.det(curvature / r), 0.0)) / (2.0 * math.pi))
            noise = max(1.0 - min(r, 1.0) ** 2, _MISMATCH_FLOOR) / (n_eff * r)
            local = cfg.cov_local_scale * noise * np.linalg.inv(curvature)
            for axis, edge in enumerate(edge_axes):
                if edge:
                    local[axis, :] = 0.0
                    local[:, axis] = 0.0
                    local[axis, axis] = _EDGE_AXIS_VAR_PX2
        w = self._ambiguity_weight(psr, spr, peak)
        cov = local + cfg.cov_floor_px ** 2 * np.eye(2) + w * uniform
        # Never wider than "anywhere in the searched area" plus the floor, never asymmetric.
        cov = 0.5 * (cov + cov.T)
        cov[0, 0] = min(cov[0, 0], uniform[0, 0] * 2.0 + cfg.cov_floor_px ** 2)
        cov[1, 1] = min(cov[1, 1], uniform[1, 1] * 2.0 + cfg.cov_floor_px ** 2)
        lim = math.sqrt(cov[0, 0] * cov[1, 1]) * 0.999
        cov[0, 1] = cov[1, 0] = float(np.clip(cov[0, 1], -lim, lim))
        return cov

    def _covariance_from(self, best: MatchResult, psr: float, spr: float, rx: float,
                         ry: float) -> np.ndarray:
        """Coarse-to-fine: the best candidate's covariance (ENU) plus the ambiguity of the whole
        search (diagonal, so the axis orientation does not matter)."""
        m2 = self.m_per_px ** 2
        local_px = best.covariance_m2 / m2
        w = self._ambiguity_weight(psr, spr, best.peak)
        cov = local_px + w * np.diag([rx * rx / 3.0, ry * ry / 3.0])
        return cov * m2


# ---------------------------------------------------------------------------------- helpers
def _px_to_enu_cov(cov_px: np.ndarray, m_per_px: float) -> np.ndarray:
    """(u east, v south) px^2 -> (x east, y north) m^2: scale, and flip the cross term's sign."""
    out = cov_px * (m_per_px * m_per_px)
    out[0, 1] = out[1, 0] = -out[0, 1]
    return out


def _refine_peak(vals: np.ndarray, ix: int, iy: int,
                 at_map_edge: tuple[bool, bool, bool, bool]) -> _Peak:
    """Sub-pixel peak: least-squares paraboloid on the 3x3 neighbourhood (1-D fits on edges)."""
    h, w = vals.shape
    value = float(vals[iy, ix])
    left, right, top, bottom = ix == 0, ix == w - 1, iy == 0, iy == h - 1
    at_border = ((left and not at_map_edge[0]) or (right and not at_map_edge[1])
                 or (top and not at_map_edge[2]) or (bottom and not at_map_edge[3]))
    x_ok = not (left or right)
    y_ok = not (top or bottom)
    if x_ok and y_ok:
        patch = vals[iy - 1:iy + 2, ix - 1:ix + 2].astype(np.float64).ravel()
        a = _PARABOLOID_PINV @ patch
        hess = np.array([[2.0 * a[3], a[4]], [a[4], 2.0 * a[5]]])
        grad = np.array([a[1], a[2]])
        curv = -hess
        if curv[0, 0] > 0.0 and np.linalg.det(curv) > 0.0:
            d = np.linalg.solve(curv, grad)
            dx, dy = float(np.clip(d[0], -1.0, 1.0)), float(np.clip(d[1], -1.0, 1.0))
            fitted = a[0] + a[1] * dx + a[2] * dy + a[3] * dx * dx + a[4] * dx * dy + a[5] * dy * dy
            return _Peak(ix, iy, dx, dy, max(value, float(fitted)), curv, (False, False), at_border)
        # Not a proper maximum (saddle/flat): fall through to separable 1-D fits.
    dx, cx = _parabola_1d(vals, ix, iy, axis=1) if x_ok else (0.0, None)
    dy, cy = _parabola_1d(vals, ix, iy, axis=0) if y_ok else (0.0, None)
    curv = None
    if (cx is not None or not x_ok) and (cy is not None or not y_ok) and (x_ok or y_ok):
        curv = np.diag([cx if cx is not None else 1.0, cy if cy is not None else 1.0])
    return _Peak(ix, iy, dx, dy, value, curv, (not x_ok, not y_ok), at_border)


def _parabola_1d(vals: np.ndarray, ix: int, iy: int, axis: int) -> tuple[float, float | None]:
    if axis == 1:
        fm, f0, fp = float(vals[iy, ix - 1]), float(vals[iy, ix]), float(vals[iy, ix + 1])
    else:
        fm, f0, fp = float(vals[iy - 1, ix]), float(vals[iy, ix]), float(vals[iy + 1, ix])
    curv = -(fm - 2.0 * f0 + fp)
    if curv <= 0.0:
        return 0.0, None
    return float(np.clip(0.5 * (fp - fm) / curv, -0.5, 0.5)), curv


def _exclusion_radius(vals: np.ndarray, ix: int, iy: int, min_radius: int) -> int:
    """Radius of the square excluded around the peak for PSR and the second peak.

    Twice the main lobe's half width at half height (walking along the four axis directions until
    the surface falls below the midpoint between the peak and the surface median), at least
    ``min_radius`` and at most a quarter of the surface's smaller side (so that side lobes remain;
    a lobe that broad gives a low PSR, which is the truth: the peak is poorly localised).
    """
    h, w = vals.shape
    peak = float(vals[iy, ix])
    step = max(1, int(math.sqrt(vals.size / 4096.0)))       # median of a subsample on big surfaces
    base = float(np.median(vals[::step, ::step]))
    half = 0.5 * (peak + base)
    hwhm = 0
    for row in (vals[iy, ix + 1:], vals[iy, ix::-1][1:], vals[iy + 1:, ix], vals[iy::-1, ix][1:]):
        below = np.nonzero(row < half)[0]
        dist = int(below[0]) + 1 if below.size else max(h, w)
        hwhm = max(hwhm, dist)
    cap = max(min_radius, min(h, w) // 4)
    return int(max(min_radius, min(2 * hwhm, cap)))


def _psr(vals: np.ndarray, ix: int, iy: int, peak: float, excl: int) -> float:
    """(peak - mean of the side lobes) / std of the side lobes; side lobes = outside the
    (2 excl + 1)^2 square centred on the peak. NaN when fewer than 8 side-lobe samples."""
    h, w = vals.shape
    y0, y1 = max(0, iy - excl), min(h, iy + excl + 1)
    x0, x1 = max(0, ix - excl), min(w, ix + excl + 1)
    n_all = vals.size
    n_in = (y1 - y0) * (x1 - x0)
    n = n_all - n_in
    if n < 8:
        return float("nan")
    v64 = vals.astype(np.float64, copy=False)
    inner = v64[y0:y1, x0:x1]
    s = float(v64.sum()) - float(inner.sum())
    ss = float(np.vdot(v64, v64)) - float(np.vdot(inner, inner))
    mean = s / n
    var = max(ss / n - mean * mean, 0.0)
    return float((peak - mean) / max(math.sqrt(var), _SIDELOBE_STD_FLOOR))


def _second_peak_ratio(vals: np.ndarray, ix: int, iy: int, peak: float, excl: int) -> float:
    """Highest interior local maximum outside the exclusion square, divided by the peak.

    Window-border pixels are not candidates (a border maximum is usually the shoulder of something
    outside the window). 0 when there is no such maximum; 1 when the peak is not positive.
    """
    if peak <= 0.0:
        return 1.0
    h, w = vals.shape
    if h < 3 or w < 3:
        return 0.0
    dil = cv2.dilate(vals, np.ones((3, 3), np.uint8))
    cand = vals >= dil
    cand[0, :] = cand[-1, :] = False
    cand[:, 0] = cand[:, -1] = False
    cand[max(0, iy - excl):iy + excl + 1, max(0, ix - excl):ix + excl + 1] = False
    if not cand.any():
        return 0.0
    second = float(vals[cand].max())
    return float(min(1.0, max(0.0, second) / peak))


# ---------------------------------------------------------------------------------- tracker
class TrackState(str, Enum):
    """Tracker state."""

    ACQUIRING = "acquiring"   # no good fix yet: global search (or around an external prior)
    TRACKING = "tracking"     # windowed search around the constant-velocity prediction
    LOST = "lost"             # lost_after_n consecutive low-quality matches: global search


@dataclass(frozen=True)
class Prediction:
    """Where the next template centre is expected (continuous pixels) and how far to search."""

    uv: tuple[float, float]
    radius_px: float
    movement_px: float


class MatchTracker:
    """Windowed NCC tracking with constant-velocity prediction and global re-acquisition.

    Only quality-ok matches (see ``SceneMatcher``) update the track. The window radius is
    ``margin * (1 + misses) + movement_factor * |v| dt`` (``v`` from the last two good fixes); with a
    single good fix the velocity is unknown and ``max_speed_m_s * dt`` replaces the movement. A
    radius above ``max_search_radius_px``, or ``lost_after_n`` consecutive low-quality matches,
    switches to a global search; the first good global match restarts the track.
    """

    _HISTORY = 3

    def __init__(self, matcher: SceneMatcher, cfg: MatcherConfig | None = None) -> None:
        self.matcher = matcher
        self.cfg = cfg if cfg is not None else matcher.cfg
        self._fixes: deque[tuple[float, float, float]] = deque(maxlen=self._HISTORY)  # (t, u, v)
        self.state = TrackState.ACQUIRING
        self.misses = 0
        self.last_prediction: Prediction | None = None
        #: Good fixes since the track was last (re-)acquired (a long track is rarely a false one).
        self.track_fixes = 0

    def reset(self) -> None:
        """Forget the track (next match is global)."""
        self._fixes.clear()
        self.track_fixes = 0
        self.state = TrackState.ACQUIRING
        self.misses = 0
        self.last_prediction = None

    @property
    def velocity_px_s(self) -> tuple[float, float] | None:
        """Velocity from the last two good fixes (pixels/s), None when unknown."""
        if len(self._fixes) < 2:
            return None
        (t0, u0, v0), (t1, u1, v1) = self._fixes[-2], self._fixes[-1]
        dt = t1 - t0
        if dt <= 0.0:
            return None
        return (u1 - u0) / dt, (v1 - v0) / dt

    def last_movement_px(self) -> float:
        """Distance between the last two good fixes in pixels (0 when unknown)."""
        if len(self._fixes) < 2:
            return 0.0
        (_, u0, v0), (_, u1, v1) = self._fixes[-2], self._fixes[-1]
        return math.hypot(u1 - u0, v1 - v0)

    def predict(self, t_s: float) -> Prediction | None:
        """Constant-velocity prediction for time ``t_s``; None when a global search is due."""
        if not self._fixes or self.state is TrackState.LOST:
            return None
        cfg = self.cfg
        t_last, u_last, v_last = self._fixes[-1]
        dt = max(0.0, t_s - t_last)
        vel = self.velocity_px_s
        base = cfg.min_window_margin_px * (1 + self.misses)
        if vel is None:
            movement = cfg.max_speed_m_s / self.matcher.m_per_px * dt
            uv = (u_last, v_last)
            radius = base + movement
        else:
            uv = (u_last + vel[0] * dt, v_last + vel[1] * dt)
            movement = math.hypot(vel[0], vel[1]) * dt
            radius = base + cfg.movement_factor * movement
        if radius > cfg.max_search_radius_px:
            return None
        return Prediction(uv=uv, radius_px=radius, movement_px=movement)

    def match(self, template: np.ndarray, t_s: float, mask: np.ndarray | None = None,
              prior_uv: tuple[float, float] | None = None,
              prior_radius_px: float | None = None) -> MatchResult:
        """Predict, match, update. ``prior_uv`` (e.g. from the autopilot) is used only when the
        tracker has no prediction of its own; its search radius defaults to max_search_radius_px."""
        pred = self.predict(t_s)
        if pred is None and prior_uv is not None:
            radius = self.cfg.max_search_radius_px if prior_radius_px is None else prior_radius_px
            pred = Prediction(uv=prior_uv, radius_px=float(radius), movement_px=0.0)
        self.last_prediction = pred
        if pred is None:
            result = self.matcher.match(template, None, None, mask)
        else:
            result = self.matcher.match(template, pred.uv, pred.radius_px, mask)
        self._update(result, t_s)
        return result

    def _update(self, result: MatchResult, t_s: float) -> None:
        if result.quality_ok:
            if result.search is not SearchMode.WINDOW or self.state is not TrackState.TRACKING:
                self._fixes.clear()          # (re-)acquired: old velocity no longer applies
                self.track_fixes = 0
            self.track_fixes += 1
            if self._fixes and t_s <= self._fixes[-1][0]:
                self._fixes.pop()            # same or older timestamp: keep the newest only
            self._fixes.append((t_s, result.position_px[0], result.position_px[1]))
            self.misses = 0
            self.state = TrackState.TRACKING
            return
        self.misses += 1
        if self.state is TrackState.TRACKING and self.misses >= self.cfg.lost_after_n:
            log.info("tracker lost after %d low-quality matches: global search", self.misses)
            self.state = TrackState.LOST
            self.misses = 0
        elif self.state is not TrackState.TRACKING:
            self.misses = 0      # global search already; do not grow a window we do not use
