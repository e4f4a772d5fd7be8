"""The 2x2 covariance of a scene-matching fix (see docs/perception.md, "Covariance").

Computed in pixels^2 on the (u, v) axes, then converted to ENU m^2 (times m_per_px^2, cross term
negated because v points south):

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

import math

import numpy as np

from perception.config import MatcherConfig

#: Floor on 1 - peak^2 in the local term (a perfect match still has interpolation error).
_MISMATCH_FLOOR = 1e-3
#: Floor on the peak in the local term (a peak near 0 carries no position information anyway).
_PEAK_FLOOR = 0.05
#: Variance (px^2) of an axis whose peak sits on the map edge (no curvature available).
_EDGE_AXIS_VAR_PX2 = 1.0


def ambiguity_weight(cfg: MatcherConfig, psr: float, spr: float, peak: float = 1.0) -> float:
    """0 for a confident match, rising linearly to 1 at the quality-gate limits (NaN: 1)."""
    if not (math.isfinite(psr) and math.isfinite(spr) and math.isfinite(peak)):
        return 1.0
    w_psr = (cfg.psr_confident - psr) / (cfg.psr_confident - cfg.min_psr)
    w_spr = (spr - cfg.second_peak_ratio_confident) / (
        cfg.max_second_peak_ratio - cfg.second_peak_ratio_confident)
    w_peak = (cfg.peak_confident - peak) / (cfg.peak_confident - cfg.min_peak)
    return float(min(1.0, max(0.0, w_psr, w_spr, w_peak)))


def _local_terms(cfg: MatcherConfig, peak: float, curvature: tuple[float, float, float] | None,
                 edge_axes: tuple[bool, bool], ux: float, uy: float,
                 n_px: int) -> tuple[float, float, float, float]:
    """The local (peak-fit) term's four entries, px^2; without a usable curvature the search area's
    uniform variances ``ux``, ``uy``."""
    if curvature is None or peak <= 0.0:
        l00, l01, l10, l11 = ux, 0.0, 0.0, uy
    else:
        c00, c01, c11 = curvature
        r = max(peak, _PEAK_FLOOR)
        det_r = (c00 / r) * (c11 / r) - (c01 / r) * (c01 / r)
        n_eff = max(1.0, n_px * math.sqrt(max(det_r, 0.0)) / (2.0 * math.pi))
        noise = max(1.0 - min(r, 1.0) ** 2, _MISMATCH_FLOOR) / (n_eff * r)
        k = cfg.cov_local_scale * noise
        det = c00 * c11 - c01 * c01
        l00, l01, l10, l11 = k * (c11 / det), k * (-c01 / det), k * (-c01 / det), k * (c00 / det)
        if edge_axes[0]:
            l00, l01, l10 = _EDGE_AXIS_VAR_PX2, 0.0, 0.0
        if edge_axes[1]:
            l11, l01, l10 = _EDGE_AXIS_VAR_PX2, 0.0, 0.0
    return l00, l01, l10, l11


def covariance_px(cfg: MatcherConfig, peak: float, curvature: tuple[float, float, float] | None,
                  edge_axes: tuple[bool, bool], psr: float, spr: float, rx: float, ry: float,
                  n_px: int) -> np.ndarray:
    """Covariance in px^2 (see the module docstring). ``curvature``: (c00, c01, c11) of the
    symmetric A = -Hessian (positive definite), None without a usable one.

    Scalar arithmetic on the four entries; det(A / r) and A^-1 by the 2x2 closed forms.
    """
    return covariance_parts_px(cfg, peak, curvature, edge_axes, psr, spr, rx, ry, n_px)[0]


def covariance_parts_px(cfg: MatcherConfig, peak: float, curvature: tuple[float, float, float] | None,
                        edge_axes: tuple[bool, bool], psr: float, spr: float, rx: float, ry: float,
                        n_px: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(``covariance_px``'s covariance, the local covariance without the ambiguity term, the
    ambiguity weight), px^2, from one evaluation of the local term. The local covariance (local term
    plus the floor) is where the peak lies if this is the right place (``local_mode_posterior``)."""
    ux, uy = rx * rx / 3.0, ry * ry / 3.0          # diag of the uniform (search-area) term
    l00, l01, l10, l11 = _local_terms(cfg, peak, curvature, edge_axes, ux, uy, n_px)
    w = ambiguity_weight(cfg, psr, spr, peak)
    f2 = cfg.cov_floor_px ** 2
    # local + f2 I + w U, then 0.5 (C + C^T) (the diagonal unchanged by it), term by term
    c00 = (l00 + f2) + w * ux
    c11 = (l11 + f2) + w * uy
    c01 = 0.5 * (((l01 + f2 * 0.0) + w * 0.0) + ((l10 + f2 * 0.0) + w * 0.0))
    # Never wider than "anywhere in the searched area" plus the floor, never asymmetric.
    c00 = min(c00, ux * 2.0 + f2)
    c11 = min(c11, uy * 2.0 + f2)
    lim = math.sqrt(c00 * c11) * 0.999
    c01 = _clip(c01, -lim, lim)
    local01 = 0.5 * (l01 + l10)
    local = np.array([[l00 + f2, local01], [local01, l11 + f2]])
    return np.array([[c00, c01], [c01, c11]]), local, w


def _clip(x: float, lo: float, hi: float) -> float:
    """``float(np.clip(x, lo, hi))`` for Python floats (NaN in any argument gives NaN)."""
    if math.isnan(x) or math.isnan(lo) or math.isnan(hi):
        return math.nan
    return min(max(x, lo), hi)


def coarse_to_fine_covariance_m2(cfg: MatcherConfig, best_covariance_m2: np.ndarray, best_peak: float,
                                 m_per_px: float, psr: float, spr: float, rx: float,
                                 ry: float) -> np.ndarray:
    """Coarse-to-fine: the best candidate's covariance (ENU) plus the ambiguity of the whole
    search (diagonal, so the axis orientation does not matter)."""
    m2 = m_per_px ** 2
    local_px = best_covariance_m2 / m2
    w = ambiguity_weight(cfg, psr, spr, best_peak)
    cov = local_px + w * np.diag([rx * rx / 3.0, ry * ry / 3.0])
    return cov * m2


def px_to_enu_cov(cov_px: np.ndarray, m_per_px: float) -> np.ndarray:
    """(u east, v south) px^2 -> (x east, y north) m^2: scale, and flip the cross term's sign."""
    out = cov_px * (m_per_px * m_per_px)
    out[0, 1] = out[1, 0] = -out[0, 1]
    return out


def pointing_covariance_m2(altitude_m: float, centre_offset_enu_m: tuple[float, float],
                           attitude_std_rad: float, heading_std_rad: float) -> np.ndarray:
    """ENU m^2 covariance a fix inherits from the pointing the alignment assumed (docs/perception.md,
    "Covariance", pointing term). The correlation surface cannot see it: a template aligned with a
    wrong attitude or heading still matches sharply, only at the wrong place.

    * Attitude (roll, pitch) error ``attitude_std_rad`` per axis: the ground point of a ray moves by
      ``altitude * tan(error)`` in each horizontal direction (small tilts), isotropic.
    * Heading error ``heading_std_rad``: the template centre's offset ``d`` from the nadir point
      (``AlignedCapture.centre_offset_px`` in metres, ENU; zero for a nadir camera) turns about the
      nadir point, so the fix moves by ``|d| * error`` perpendicular to ``d``.
    """
    h = max(float(altitude_m), 0.0)
    s_att = h * math.tan(max(float(attitude_std_rad), 0.0))
    dx, dy = float(centre_offset_enu_m[0]), float(centre_offset_enu_m[1])
    s_hdg2 = max(float(heading_std_rad), 0.0) ** 2
    # d_perp = (-dy, dx): s_hdg2 * d_perp d_perp^T
    return np.array([[s_att * s_att + s_hdg2 * dy * dy, -s_hdg2 * dx * dy],
                     [-s_hdg2 * dx * dy, s_att * s_att + s_hdg2 * dx * dx]])


def local_mode_posterior(fix_enu_m: tuple[float, float], local_covariance_m2: np.ndarray,
                         ambiguity: float, search_area_m2: float, prior_enu_m: tuple[float, float],
                         prior_covariance_m2: np.ndarray) -> float:
    """How much of the posterior an ambiguous match's own peak holds, given a Gaussian prior on the
    position (the autopilot's estimate). The match says: with probability 1 - ``ambiguity`` the
    vehicle is at the peak (``local_covariance_m2``), otherwise anywhere in the searched area
    (uniform over ``search_area_m2``); the module docstring's covariance is this mixture's moment.
    Against the prior N(prior, P) the two components weigh (1 - w) N(fix; prior, P + C_local) and
    w / area. Returns the first's share in [0, 1] (NaN inputs: 0)."""
    w = min(max(float(ambiguity), 0.0), 1.0)
    d = np.asarray(fix_enu_m, dtype=float) - np.asarray(prior_enu_m, dtype=float)
    S = np.asarray(local_covariance_m2, dtype=float) + np.asarray(prior_covariance_m2, dtype=float)
    det = float(S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0])
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(S)) and S[0, 0] > 0.0 and det > 0.0
            and math.isfinite(search_area_m2) and search_area_m2 > 0.0):
        return 0.0
    m2 = float(d @ np.linalg.solve(S, d))
    local = (1.0 - w) * math.exp(-0.5 * m2) / (2.0 * math.pi * math.sqrt(det))
    uniform = w / float(search_area_m2)
    total = local + uniform
    return local / total if total > 0.0 else 0.0
