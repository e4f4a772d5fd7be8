"""Metrics of a correlation peak: sub-pixel refinement, exclusion radius, PSR, second-peak ratio.

Pure numpy/OpenCV functions over one correlation surface (``values[iy, ix]`` = NCC of the template
placed with its top-left corner at window pixel (ix, iy)); ``perception.ncc_search`` calls them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: Floor on the side-lobe standard deviation in the PSR denominator.
_SIDELOBE_STD_FLOOR = 1e-6


def _paraboloid_pinv() -> np.ndarray:
    rows = []
    for y in (-1.0, 0.0, 1.0):
        for x in (-1.0, 0.0, 1.0):
            rows.append([1.0, x, y, x * x, x * y, y * y])
    return np.linalg.pinv(np.asarray(rows))


_PARABOLOID_PINV = _paraboloid_pinv()   # (6, 9): least-squares f = a0 + a1 x + a2 y + a3 x^2 + a4 xy + a5 y^2


@dataclass(frozen=True)
class Peak:
    """The refined maximum of a correlation surface (integer index + sub-pixel offset)."""

    ix: int
    iy: int
    dx: float
    dy: float
    value: float
    curvature: np.ndarray | None   # A = -Hessian (2x2), None when not a proper maximum
    edge_axes: tuple[bool, bool]   # x / y axis had no neighbour on one side (map edge)
    at_border: bool                # at a window edge that is not the map edge


def refine_peak(vals: np.ndarray, ix: int, iy: int,
                at_map_edge: tuple[bool, bool, bool, bool]) -> Peak:
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
            return Peak(ix, iy, dx, dy, max(value, float(fitted)), curv, (False, False), at_border)
        # Not a proper maximum (saddle/flat): fall through to separable 1-D fits.
    dx, cx = _parabola_1d(vals, ix, iy, axis=1) if x_ok else (0.0, None)
    dy, cy = _parabola_1d(vals, ix, iy, axis=0) if y_ok else (0.0, None)
    curv = None
    if (cx is not None or not x_ok) and (cy is not None or not y_ok) and (x_ok or y_ok):
        curv = np.diag([cx if cx is not None else 1.0, cy if cy is not None else 1.0])
    return Peak(ix, iy, dx, dy, value, curv, (not x_ok, not y_ok), at_border)


def _parabola_1d(vals: np.ndarray, ix: int, iy: int, axis: int) -> tuple[float, float | None]:
    if axis == 1:
        fm, f0, fp = float(vals[iy, ix - 1]), float(vals[iy, ix]), float(vals[iy, ix + 1])
    else:
        fm, f0, fp = float(vals[iy - 1, ix]), float(vals[iy, ix]), float(vals[iy + 1, ix])
    curv = -(fm - 2.0 * f0 + fp)
    if curv <= 0.0:
        return 0.0, None
    return float(np.clip(0.5 * (fp - fm) / curv, -0.5, 0.5)), curv


def exclusion_radius(vals: np.ndarray, ix: int, iy: int, min_radius: int) -> int:
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


def peak_to_sidelobe_ratio(vals: np.ndarray, ix: int, iy: int, peak: float, excl: int) -> float:
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


def second_peak_ratio(vals: np.ndarray, ix: int, iy: int, peak: float, excl: int) -> float:
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
