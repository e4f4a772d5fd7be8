"""The window NCC surface (``cv2.TM_CCOEFF_NORMED``) by our own DFT correlation, for tracking.

``cv2.matchTemplate`` (TM_CCOEFF_NORMED) on a tracking window (a 188 px template in a 240 px window:
a 53 x 53 surface) converts both images to float64 and runs its DFTs in double precision, takes the
window's sums from a fresh float64 integral image (two 241 x 241 arrays) and allocates all of it per
call. ``FftNcc`` computes the same surface with

* the template minus its mean written into a zero-padded float32 buffer (``_template_into_pad``),
  and the window minus that same mean into another, both buffers kept between fixes; the window
  sums of every template placement (of the window minus the mean, and of its square) by running
  sums in float64 in the same pass (``_window_into_pad``);
* three float32 ``cv2.dft`` calls of the optimal DFT size (template, window, inverse), each in
  place in those two buffers, and the conjugate product of the packed spectra in between
  (``_mul_conj_ccs``);
* one pass that normalises the correlation with those sums and finds the maximum
  (``_normalise``), with OpenCV's rules for a flat window patch (0) and for a ratio at or beyond
  +-1 (+-1 up to 1.125, else 0).

The numerator is the correlation of the zero-mean template with the window (the window's own mean
cancels against the zero-mean template), so no large sums are subtracted: the values are within
3e-6 of the float64 definition (``cv2.matchTemplate``'s within 8e-4 on small low-contrast templates:
it rounds the raw correlation to float32 before it subtracts the means), within 5e-7 of
``cv2.matchTemplate``'s on the tracking windows; the arg-max is the same on textured surfaces.
Deterministic: the same inputs give the same bits (every row transform is computed alike whatever
OpenCV's thread count). Pure: numpy, OpenCV and numba.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from typing import Any

import cv2
import numpy as np
from numba import njit

#: numba options of every kernel here: cached on disk, no allocation inside (no runtime).
NO_NRT: dict[str, Any] = {"cache": True, "_nrt": False}
_FLT_EPSILON = float(np.finfo(np.float32).eps)
#: DFT buffer sets kept per (rows, cols) of the DFT: template and window sizes vary little in a flight.
_MAX_BUFFER_SETS = 8


@njit(**NO_NRT)
def _template_into_pad(template, tpad, acc):  # pragma: no cover - compiled
    """``tpad`` <- the template minus its mean, zero outside; returns (mean, sum of squares of the
    zero-mean template), both in float64. ``acc``: float64 work row (template width): per-column
    partial sums, so the inner loops run across the row (vectorised) and the order is fixed."""
    th, tw = template.shape
    for x in range(tw):
        acc[x] = 0.0
    for y in range(th):
        row = template[y]
        for x in range(tw):
            acc[x] += row[x]
    total = 0.0
    for x in range(tw):
        total += acc[x]
        acc[x] = 0.0
    mean = total / (th * tw)
    for y in range(th):
        row = template[y]
        out = tpad[y]
        for x in range(tw):
            d = np.float64(row[x]) - mean
            acc[x] += d * d
            out[x] = d
        for x in range(tw, out.shape[0]):
            out[x] = 0.0
    for y in range(th, tpad.shape[0]):
        for x in range(tpad.shape[1]):
            tpad[y, x] = 0.0
    ss = 0.0
    for x in range(tw):
        ss += acc[x]
    return mean, ss


@njit(inline="always", **NO_NRT)
def _row_box_sums(acc1, acc2, tw, s1, s2, v):  # pragma: no cover - compiled
    """``s1[v, u]``, ``s2[v, u]`` <- the sums of ``acc1``/``acc2`` over ``tw`` entries from ``u`` on,
    for every ``u`` of the row (the first by four interleaved partial sums, then sliding)."""
    rw = s1.shape[1]
    a0 = a1 = a2 = a3 = 0.0
    b0 = b1 = b2 = b3 = 0.0
    n4 = tw - tw % 4
    for x in range(0, n4, 4):
        a0 += acc1[x]
        a1 += acc1[x + 1]
        a2 += acc1[x + 2]
        a3 += acc1[x + 3]
        b0 += acc2[x]
        b1 += acc2[x + 1]
        b2 += acc2[x + 2]
        b3 += acc2[x + 3]
    for x in range(n4, tw):
        a0 += acc1[x]
        b0 += acc2[x]
    a = (a0 + a1) + (a2 + a3)
    b = (b0 + b1) + (b2 + b3)
    s1[v, 0] = a
    s2[v, 0] = b
    for u in range(1, rw):
        a += acc1[u + tw - 1] - acc1[u - 1]
        b += acc2[u + tw - 1] - acc2[u - 1]
        s1[v, u] = a
        s2[v, u] = b


@njit(**NO_NRT)
def _window_into_pad(ref, y0, x0, wh, ww, c, th, tw, wpad, acc1, acc2, s1, s2):  # pragma: no cover - compiled
    """``wpad`` <- the window ``ref[y0:y0 + wh, x0:x0 + ww] - c`` (zero outside); ``s1[v, u]``,
    ``s2[v, u]`` <- the sums of ``window - c`` and of its square over the template (``th`` x
    ``tw``) placed at (u, v), float64.

    Column sums over ``th`` rows are kept per window column in ``acc1``/``acc2`` (the inner loops run
    across the row: vectorised) and slid down one row at a time; as soon as a placement row's
    column sums are complete, they are summed along the row (``_row_box_sums``)."""
    for x in range(ww):
        acc1[x] = 0.0
        acc2[x] = 0.0
    for y in range(wh):
        row = ref[y0 + y, x0:x0 + ww]           # contiguous rows: the inner loops vectorise
        out = wpad[y]
        for x in range(ww):
            d = np.float64(row[x]) - c
            out[x] = d
            acc1[x] += d
            acc2[x] += d * d
        for x in range(ww, out.shape[0]):
            out[x] = 0.0
        if y >= th:                 # drop the row that left the template's reach
            old = ref[y0 + y - th, x0:x0 + ww]
            for x in range(ww):
                o = np.float64(old[x]) - c
                acc1[x] -= o
                acc2[x] -= o * o
        v = y - th + 1              # the placement row whose column sums are complete now
        if v >= 0:
            _row_box_sums(acc1, acc2, tw, s1, s2, v)
    for y in range(wh, wpad.shape[0]):
        for x in range(wpad.shape[1]):
            wpad[y, x] = 0.0


@njit(**NO_NRT)
def _mul_conj_ccs(a, b, out):  # pragma: no cover - compiled
    """``cv2.mulSpectrums(a, b, 0, conjB=True)`` for 2-D CCS-packed spectra of a real array (float32);
    ``out`` may be ``a`` (each value pair is read before it is written)."""
    n, m = a.shape
    # column 0 (and m - 1 when m is even) holds a 1-D CCS spectrum down the rows
    for j in range(0, m, max(m - 1, 1)):
        if j > 0 and m % 2 == 1:
            break
        out[0, j] = a[0, j] * b[0, j]
        if n % 2 == 0:
            out[n - 1, j] = a[n - 1, j] * b[n - 1, j]
        for i in range(1, n - 1 + (n % 2), 2):
            ar, ai, br, bi = a[i, j], a[i + 1, j], b[i, j], b[i + 1, j]
            out[i, j] = ar * br + ai * bi
            out[i + 1, j] = ai * br - ar * bi
    # the other columns in (re, im) pairs along every row
    half = (m - 1) // 2
    for i in range(n):
        ra = a[i]
        rb = b[i]
        ro = out[i]
        for p in range(half):
            j = 2 * p + 1
            ar, ai, br, bi = ra[j], ra[j + 1], rb[j], rb[j + 1]
            ro[j] = ar * br + ai * bi
            ro[j + 1] = ai * br - ar * bi


@njit(**NO_NRT)
def _normalise(corr, scale, s1, s2, n_px, c, t_ss, out):  # pragma: no cover - compiled
    """``out`` <- NCC from ``corr`` (the correlation of the zero-mean template with ``window - c``,
    times ``scale``) and the window sums ``s1[v, u]``, ``s2[v, u]`` (of ``window - c`` over
    ``n_px`` pixels);
    returns the flat index of the first maximum (row-major, as ``ndarray.argmax``; a NaN wins).

    OpenCV's rules (``common_matchTemplate``): a window patch whose variance sum is at most
    min(0.5, 10 FLT_EPSILON x its sum of squares) gives 0; a ratio of magnitude at or above 1 gives
    +-1 below 1.125, else 0. ``t_ss``: the zero-mean template's sum of squares; at 0 (a flat
    template) the surface is 1, as OpenCV's."""
    rh, rw = out.shape
    t_norm = math.sqrt(t_ss)
    best = -math.inf
    best_k = -1
    for v in range(rh):
        for u in range(rw):
            a = s1[v, u]
            b = s2[v, u]
            diff2 = b - a * a / n_px
            if diff2 < 0.0:
                diff2 = 0.0
            raw2 = b + 2.0 * c * a + n_px * c * c      # the patch's own sum of squares
            num = corr[v, u] * scale
            if not (math.isfinite(num) and math.isfinite(diff2)):
                r = -1.0                                # what the matcher makes of a non-finite value
            elif t_ss <= 0.0:
                r = 1.0
            else:
                t = 0.0 if diff2 <= min(0.5, 10.0 * _FLT_EPSILON * raw2) else math.sqrt(diff2) * t_norm
                if abs(num) < t:
                    r = num / t
                elif abs(num) < t * 1.125:
                    r = 1.0 if num > 0.0 else -1.0
                else:
                    r = 0.0
            f = np.float32(r)
            out[v, u] = f
            if best_k < 0 or f > best or (f != f and best == best):
                best = f
                best_k = v * rw + u
    return best_k


def warm_up() -> None:
    """Load (or compile once) this module's kernels on a tiny window, so that a matcher's first fix
    costs what any fix does (a cold compile takes seconds; a node does this before it joins)."""
    ref = np.arange(64, dtype=np.float32).reshape(8, 8) % 5.0
    FftNcc().surface(ref, 0, 0, 8, 8, np.ascontiguousarray(ref[2:6, 1:5]))


class FftNcc:
    """TM_CCOEFF_NORMED surfaces of templates in windows of one map (see the module docstring).

    ``surface(ref, x0, y0, x1, y1, template)`` returns the float32 surface of ``template`` (C-contiguous
    float32) over the window ``ref[y0:y1, x0:x1]`` of the C-contiguous float32 map ``ref``, shape
    (window - template + 1), a new array, and the flat index of its first maximum. The DFT buffers
    are kept between calls (per DFT size, the last few).
    """

    def __init__(self) -> None:
        self._buffers: OrderedDict[tuple[int, int], dict[str, np.ndarray]] = OrderedDict()

    def _buffers_for(self, wh: int, ww: int) -> dict[str, np.ndarray]:
        key = (cv2.getOptimalDFTSize(wh), cv2.getOptimalDFTSize(ww))
        bufs = self._buffers.get(key)
        if bufs is None:
            bufs = {"t": np.empty(key, np.float32), "w": np.empty(key, np.float32),
                    "acc": np.empty((3, key[1]), np.float64)}
            self._buffers[key] = bufs
            if len(self._buffers) > _MAX_BUFFER_SETS:
                self._buffers.popitem(last=False)
        else:
            self._buffers.move_to_end(key)
        return bufs

    def surface(self, ref: np.ndarray, x0: int, y0: int, x1: int, y1: int,
                template: np.ndarray) -> tuple[np.ndarray, int]:
        """NCC surface of ``template`` over ``ref[y0:y1, x0:x1]`` and the flat index of its first maximum."""
        wh, ww = y1 - y0, x1 - x0
        th, tw = template.shape
        rh, rw = wh - th + 1, ww - tw + 1
        if rh < 1 or rw < 1:
            raise ValueError(f"template {tw}x{th} px is larger than the window {ww}x{wh} px")
        b = self._buffers_for(wh, ww)
        t, w, acc = b["t"], b["w"], b["acc"]
        n, m = t.shape
        sums = np.empty((2, rh, rw), np.float64)      # per placement: sum of window - c, of its square
        out = np.empty((rh, rw), np.float32)
        mean, t_ss = _template_into_pad(template, t, acc[0])
        _window_into_pad(ref, y0, x0, wh, ww, mean, th, tw, w, acc[1], acc[2], sums[0], sums[1])
        # two buffers, every transform in place (the same bits as into fresh arrays; a third of the
        # memory the caches have to hold)
        cv2.dft(t, t)
        cv2.dft(w, w)
        _mul_conj_ccs(w, t, w)
        cv2.dft(w, w, cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT)
        k = _normalise(w, 1.0 / (n * m), sums[0], sums[1], float(th * tw), mean, t_ss, out)
        return out, int(k)
