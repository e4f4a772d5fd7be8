"""Metrics of a correlation peak: sub-pixel refinement, exclusion radius, PSR, second-peak ratio.

Pure numpy/OpenCV functions over one correlation surface (``values[iy, ix]`` = NCC of the template
placed with its top-left corner at window pixel (ix, iy)); ``perception.ncc_search`` calls them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numba import njit

from perception.linalg2 import det2, solve2

#: numba options of the kernels here: cached on disk, no allocation inside (no runtime).
NO_NRT: dict[str, Any] = {"cache": True, "_nrt": False}

#: Floor on the side-lobe standard deviation in the PSR denominator.
_SIDELOBE_STD_FLOOR = 1e-6
#: 3x3 structuring element of the local-maximum test (built once).
_DILATE_KERNEL = np.ones((3, 3), np.uint8)


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
        a0, a1, a2, a3, a4, a5 = (_PARABOLOID_PINV @ patch).tolist()
        # curvature = -Hessian of the fit; its entries as the former np.array(...) negation gave them
        c00, c01, c11 = -(2.0 * a3), -a4, -(2.0 * a5)
        if c00 > 0.0:
            curv = np.array([[c00, c01], [c01, c11]])
            if det2(curv) > 0.0:
                d0, d1 = solve2(curv, np.array([a1, a2])).tolist()
                dx, dy = min(max(d0, -1.0), 1.0), min(max(d1, -1.0), 1.0)
                fitted = a0 + a1 * dx + a2 * dy + a3 * dx * dx + a4 * dx * dy + a5 * dy * dy
                return Peak(ix, iy, dx, dy, max(value, fitted), curv, (False, False), at_border)
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
    return min(max(0.5 * (fp - fm) / curv, -0.5), 0.5), curv


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
    base = _median(vals[::step, ::step])
    half = 0.5 * (peak + base)
    # Walk in Python over the peak's row and column (the lobe is a few pixels wide), comparing in
    # the surface's dtype as numpy's `row < half` does (the Python float rounded to float32 first).
    half_t = float(vals.dtype.type(half))
    row, col = vals[iy].tolist(), vals[:, ix].tolist()
    hwhm = 0
    for seq in (row[ix + 1:], row[ix::-1][1:], col[iy + 1:], col[iy::-1][1:]):
        dist = max(h, w)
        for k, x in enumerate(seq):
            if x < half_t:
                dist = k + 1
                break
        hwhm = max(hwhm, dist)
    cap = max(min_radius, min(h, w) // 4)
    return int(max(min_radius, min(2 * hwhm, cap)))


def _median(a: np.ndarray) -> float:
    """``float(np.median(a))`` (same selection, same mean of the middle pair, NaN if any NaN) without
    np.median's generic-axis machinery, which costs more than the selection on a window surface."""
    flat = a.ravel()
    n = flat.size
    if n == 0:
        return math.nan
    k = n // 2
    kth = [k, n - 1] if n % 2 else [k - 1, k, n - 1]
    part = np.partition(flat, kth)
    if math.isnan(part[n - 1]):
        return math.nan
    return float(part[k]) if n % 2 else float(np.mean(part[k - 1:k + 1]))


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
    ss = _sum_of_squares(v64) - _sum_of_squares(inner)
    mean = s / n
    var = max(ss / n - mean * mean, 0.0)
    return float((peak - mean) / max(math.sqrt(var), _SIDELOBE_STD_FLOOR))


#: np.vdot (OpenBLAS ddot) runs on one thread up to this many elements and splits a longer dot over
#: its threads: the bits then depend on the thread count, and on a loaded 2-core machine the split
#: cost ~5 ms CPU (40 ms wall) on a global surface instead of ~1 ms. Longer dots go in chunks.
_DOT_CHUNK = 10000


def _sum_of_squares(v: np.ndarray) -> float:
    """Sum of squares of a float64 array: ``np.vdot(v, v)`` up to _DOT_CHUNK elements (the same
    bits), chunks of it summed in order above (single-threaded whatever BLAS's thread count)."""
    flat = v.ravel()
    n = flat.size
    if n <= _DOT_CHUNK:
        return float(np.vdot(flat, flat))
    total = 0.0
    for i in range(0, n, _DOT_CHUNK):
        chunk = flat[i:i + _DOT_CHUNK]
        total += float(np.vdot(chunk, chunk))
    return total


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
    dil = cv2.dilate(vals, _DILATE_KERNEL)
    inner = vals[1:-1, 1:-1]                      # window-border pixels are never candidates
    cand = inner >= dil[1:-1, 1:-1]
    cand[max(0, iy - excl - 1):max(0, iy + excl), max(0, ix - excl - 1):max(0, ix + excl)] = False
    second = float(inner.max(where=cand, initial=-np.inf))
    if second == -math.inf:                       # no candidate (or only -inf ones: ratio 0 either way)
        return 0.0
    return float(min(1.0, max(0.0, second) / peak))


# ---------------------------------------------------------------------------------------------
# All of the above in one compiled pass over the surface (the matcher's path).

@njit(**NO_NRT)
def _select(a, n, k):  # pragma: no cover - compiled
    """The k-th smallest of ``a[:n]`` (in place: afterwards ``a[:k]`` <= ``a[k]`` <= ``a[k + 1:n]``)."""
    lo, hi = 0, n - 1
    while lo < hi:
        mid = (lo + hi) // 2
        x, y, z = a[lo], a[mid], a[hi]          # median of three as pivot
        if x > y:
            x, y = y, x
        if y > z:
            y = x if x > z else z
        pivot = y
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return a[k]


@njit(**NO_NRT)
def _median_subsampled(vals, step, scratch):  # pragma: no cover - compiled
    """``_median(vals[::step, ::step])`` (float32 values, no NaN): the middle value, or the float32
    mean of the middle pair."""
    h, w = vals.shape
    n = 0
    for y in range(0, h, step):
        for x in range(0, w, step):
            scratch[n] = vals[y, x]
            n += 1
    k = n // 2
    hi = _select(scratch, n, k)
    if n % 2:
        return np.float64(hi)
    lo = scratch[0]
    for i in range(1, k):
        if scratch[i] > lo:
            lo = scratch[i]
    return np.float64((lo + hi) / np.float32(2.0))


@njit(**NO_NRT)
def surface_metrics(vals, ix, iy, edge_l, edge_r, edge_t, edge_b, min_radius, pinv,
                    scratch):  # pragma: no cover - compiled
    """Sub-pixel peak, exclusion radius, PSR and second-peak ratio of one float32 surface in one
    call: ``refine_peak``, ``exclusion_radius``, ``peak_to_sidelobe_ratio`` and ``second_peak_ratio``
    above, the same definitions; float64 sums in their own order (the last bits differ), every
    value widened with ``np.float64`` (numba's ``float()`` leaves a float32 a float32).

    ``(ix, iy)``: the integer maximum (-1, -1: found here, the first one row-major); ``edge_*``: the
    window's left/right/top/bottom side is the map edge; ``pinv``: ``_PARABOLOID_PINV``;
    ``scratch``: float32, at least ``vals.size`` (the median's selection). Returns (ix, iy, dx,
    dy, value, curvature kind (0 none, 1 full, 2 per-axis), c00, c01, c11, edge_x, edge_y,
    at_border, excl, psr, spr); the PSR is NaN with fewer than 8 side-lobe values."""
    h, w = vals.shape
    if ix < 0:
        best = vals[0, 0]
        ix, iy = 0, 0
        for y in range(h):
            for x in range(w):
                if vals[y, x] > best:
                    best = vals[y, x]
                    ix, iy = x, y
    value = np.float64(vals[iy, ix])
    # --- sub-pixel peak (refine_peak)
    left, right, top, bottom = ix == 0, ix == w - 1, iy == 0, iy == h - 1
    at_border = (left and not edge_l) or (right and not edge_r) or (top and not edge_t) or (bottom and not edge_b)
    x_ok = not (left or right)
    y_ok = not (top or bottom)
    kind = 0
    dx = dy = 0.0
    c00 = c01 = c11 = 0.0
    refined = value
    done = False
    if x_ok and y_ok:
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0
        for r in range(3):
            for c in range(3):
                f = np.float64(vals[iy - 1 + r, ix - 1 + c])
                m = 3 * r + c
                a0 += pinv[0, m] * f
                a1 += pinv[1, m] * f
                a2 += pinv[2, m] * f
                a3 += pinv[3, m] * f
                a4 += pinv[4, m] * f
                a5 += pinv[5, m] * f
        c00, c01, c11 = -(2.0 * a3), -a4, -(2.0 * a5)
        det = c00 * c11 - c01 * c01
        if c00 > 0.0 and det > 0.0:
            d0 = (c11 * a1 - c01 * a2) / det
            d1 = (c00 * a2 - c01 * a1) / det
            dx, dy = min(max(d0, -1.0), 1.0), min(max(d1, -1.0), 1.0)
            fitted = a0 + a1 * dx + a2 * dy + a3 * dx * dx + a4 * dx * dy + a5 * dy * dy
            refined = max(value, fitted)
            kind = 1
            done = True
    if not done:                                 # separable 1-D fits (edges, saddles, flat tops)
        cx = cy = -1.0
        if x_ok:
            fm, fp = np.float64(vals[iy, ix - 1]), np.float64(vals[iy, ix + 1])
            cx = -(fm - 2.0 * value + fp)
            if cx > 0.0:
                dx = min(max(0.5 * (fp - fm) / cx, -0.5), 0.5)
        if y_ok:
            fm, fp = np.float64(vals[iy - 1, ix]), np.float64(vals[iy + 1, ix])
            cy = -(fm - 2.0 * value + fp)
            if cy > 0.0:
                dy = min(max(0.5 * (fp - fm) / cy, -0.5), 0.5)
        c00 = c11 = 1.0
        c01 = 0.0
        if (cx > 0.0 or not x_ok) and (cy > 0.0 or not y_ok) and (x_ok or y_ok):
            kind = 2
            if x_ok:
                c00 = cx
            if y_ok:
                c11 = cy
    # --- exclusion radius (exclusion_radius: from the integer peak's value)
    step = max(1, int(math.sqrt(vals.size / 4096.0)))
    base = _median_subsampled(vals, step, scratch)
    half = np.float32(0.5 * (value + base))
    hwhm = 0
    for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        dist = max(h, w)
        k = 1
        x, y = ix + sx, iy + sy
        while 0 <= x < w and 0 <= y < h:
            if vals[y, x] < half:
                dist = k
                break
            k += 1
            x += sx
            y += sy
        hwhm = max(hwhm, dist)
    cap = max(min_radius, min(h, w) // 4)
    excl = max(min_radius, min(2 * hwhm, cap))
    # --- PSR over the side lobes (outside the (2 excl + 1)^2 square)
    y0, y1 = max(0, iy - excl), min(h, iy + excl + 1)
    x0, x1 = max(0, ix - excl), min(w, ix + excl + 1)
    n = h * w - (y1 - y0) * (x1 - x0)
    s = 0.0
    ss = 0.0
    for y in range(h):
        inside = y0 <= y < y1
        for x in range(w):
            if inside and x0 <= x < x1:
                continue
            f = np.float64(vals[y, x])
            s += f
            ss += f * f
    psr = math.nan
    if n >= 8:
        mean = s / n
        var = max(ss / n - mean * mean, 0.0)
        psr = (refined - mean) / max(math.sqrt(var), _SIDELOBE_STD_FLOOR)
    # --- second-peak ratio: the best interior 3x3 local maximum outside the square
    if refined <= 0.0:
        spr = 1.0
    elif h < 3 or w < 3:
        spr = 0.0
    else:
        second = -math.inf
        for y in range(1, h - 1):
            for x in range(1, w - 1):
                if abs(y - iy) <= excl and abs(x - ix) <= excl:
                    continue
                f = vals[y, x]
                if f <= second:
                    continue
                if (f >= vals[y - 1, x - 1] and f >= vals[y - 1, x] and f >= vals[y - 1, x + 1]
                        and f >= vals[y, x - 1] and f >= vals[y, x + 1] and f >= vals[y + 1, x - 1]
                        and f >= vals[y + 1, x] and f >= vals[y + 1, x + 1]):
                    second = f
        spr = 0.0 if second == -math.inf else min(1.0, max(0.0, np.float64(second)) / refined)
    return (ix, iy, dx, dy, refined, kind, c00, c01, c11, not x_ok, not y_ok, at_border, excl, psr, spr)


def warm_up() -> None:
    """Load (or compile once) ``surface_metrics`` on a tiny surface, so that a matcher's first fix
    costs what any fix does."""
    yy, xx = np.mgrid[0:9, 0:9]
    surface_peak_metrics((1.0 - 0.01 * ((xx - 4.0) ** 2 + (yy - 4.0) ** 2)).astype(np.float32),
                         (False, False, False, False), 2)


@dataclass(frozen=True)
class SurfaceMetrics:
    """A surface's refined peak and its quality metrics (``surface_peak_metrics``).

    ``curvature``: (c00, c01, c11) of A = -Hessian (2x2, symmetric), None when the peak is not a
    proper maximum; ``excl``: the exclusion radius; ``psr``: NaN with fewer than 8 side-lobe values.
    """

    ix: int
    iy: int
    dx: float
    dy: float
    value: float
    curvature: tuple[float, float, float] | None
    edge_axes: tuple[bool, bool]
    at_border: bool
    excl: int
    psr: float
    second_peak_ratio: float


def surface_peak_metrics(vals: np.ndarray, at_map_edge: tuple[bool, bool, bool, bool], min_radius: int,
                         argmax: int = -1) -> SurfaceMetrics:
    """Sub-pixel peak, exclusion radius, PSR and second-peak ratio of a float32 surface in one
    compiled pass (``surface_metrics``; definitions of ``refine_peak``, ``exclusion_radius``,
    ``peak_to_sidelobe_ratio`` and ``second_peak_ratio``). ``argmax``: the flat index of the first
    maximum if known (-1: found here)."""
    if vals.dtype != np.float32 or not vals.flags.c_contiguous:
        vals = np.ascontiguousarray(vals, dtype=np.float32)
    ix, iy = (-1, -1) if argmax < 0 else (argmax % vals.shape[1], argmax // vals.shape[1])
    (ix, iy, dx, dy, value, kind, c00, c01, c11, edge_x, edge_y, at_border, excl, psr,
     spr) = surface_metrics(vals, ix, iy, at_map_edge[0], at_map_edge[1], at_map_edge[2], at_map_edge[3],
                            min_radius, _PARABOLOID_PINV, np.empty(vals.size, np.float32))
    return SurfaceMetrics(ix, iy, dx, dy, value, None if kind == 0 else (c00, c01, c11), (edge_x, edge_y),
                          at_border, excl, psr, spr)
