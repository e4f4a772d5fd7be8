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


def covariance_px(cfg: MatcherConfig, peak: float, curvature: np.ndarray | None,
                  edge_axes: tuple[bool, bool], psr: float, spr: float, rx: float, ry: float,
                  n_px: int) -> np.ndarray:
    """Covariance in px^2 (see the module docstring)."""
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
    w = ambiguity_weight(cfg, psr, spr, peak)
    cov = local + cfg.cov_floor_px ** 2 * np.eye(2) + w * uniform
    # Never wider than "anywhere in the searched area" plus the floor, never asymmetric.
    cov = 0.5 * (cov + cov.T)
    cov[0, 0] = min(cov[0, 0], uniform[0, 0] * 2.0 + cfg.cov_floor_px ** 2)
    cov[1, 1] = min(cov[1, 1], uniform[1, 1] * 2.0 + cfg.cov_floor_px ** 2)
    lim = math.sqrt(cov[0, 0] * cov[1, 1]) * 0.999
    cov[0, 1] = cov[1, 0] = float(np.clip(cov[0, 1], -lim, lim))
    return cov


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
