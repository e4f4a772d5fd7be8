"""The statistical false-match detector used as the paper's baseline (section 6.3, after ref. [3]).

The paper observes "the variance of the position over a sliding window of the last 30 measurements"
and flags a false match when it exceeds 1.4, without saying variance of what. The raw variance of a
moving drone's position grows with its speed (10 m/s over 30 fixes spans metres), so it cannot be the
quantity compared with a fixed 1.4. We use the variance of the *detrended* position:

* over the window, fit x(t) = a + b t and y(t) = c + d t by least squares (constant velocity, which is
  what a drone flying a leg does over ~1 s);
* the statistic is the residual variance of the 2-D position, x and y combined:

      variance_m2 = (sum of squared x residuals + sum of squared y residuals) / (n - 2)

  i.e. the trace of the residual covariance (the unbiased per-axis variances, summed), in m^2.

A steady track gives a variance near the measurement noise (x + y variances); a false match is a jump
of tens of metres off the line and drives the variance far above 1.4 m^2 for as long as it stays in
the window, which reproduces the paper's latency (Figure 8, the "112 %" over-detection).
Fewer than 3 measurements give no statistic: the fix is not flagged and the variance is NaN.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

#: Paper 6.3: sliding window of 30 measurements, threshold 1.4.
PAPER_WINDOW = 30
PAPER_THRESHOLD_M2 = 1.4
_MIN_SAMPLES = 3
_LINE_PARAMS = 2


class StatisticalDetector:
    """Sliding-window residual-variance detector. ``update`` returns (flag_false, variance_m2)."""

    def __init__(self, window: int = PAPER_WINDOW, threshold: float = PAPER_THRESHOLD_M2) -> None:
        if int(window) < _MIN_SAMPLES:
            raise ValueError(f"window = {window!r}: expected an integer >= {_MIN_SAMPLES}")
        if not (math.isfinite(threshold) and threshold > 0.0):
            raise ValueError(f"threshold = {threshold!r}: expected a positive number (m^2)")
        self.window = int(window)
        self.threshold = float(threshold)
        self._samples: deque[tuple[float, float, float]] = deque(maxlen=self.window)
        self.variance_m2 = float("nan")

    def reset(self) -> None:
        """Empty the window."""
        self._samples.clear()
        self.variance_m2 = float("nan")

    def __len__(self) -> int:
        return len(self._samples)

    def update(self, x_m: float, y_m: float, t_s: float) -> tuple[bool, float]:
        """Add a measurement; return (flag_false = variance > threshold, variance in m^2)."""
        for name, value in (("x_m", x_m), ("y_m", y_m), ("t_s", t_s)):
            if not math.isfinite(value):
                raise ValueError(f"{name} = {value!r}: expected a finite number")
        self._samples.append((float(t_s), float(x_m), float(y_m)))
        self.variance_m2 = detrended_variance_m2(np.asarray(self._samples, dtype=np.float64))
        flag = bool(math.isfinite(self.variance_m2) and self.variance_m2 > self.threshold)
        return flag, self.variance_m2


def detrended_variance_m2(samples: np.ndarray) -> float:
    """Residual variance (x + y, m^2) of (t, x, y) rows about a least-squares constant-velocity line.

    NaN for fewer than 3 rows. When all times are equal the line degenerates to the mean position
    (divisor n - 1).
    """
    n = samples.shape[0]
    if n < _MIN_SAMPLES:
        return float("nan")
    t = samples[:, 0] - samples[:, 0].mean()
    xy = samples[:, 1:3] - samples[:, 1:3].mean(axis=0)
    stt = float(t @ t)
    if stt <= 1e-12 * max(1.0, float(np.abs(samples[:, 0]).max()) ** 2):
        ssr = float((xy * xy).sum())
        return ssr / (n - 1)
    slope = (t @ xy) / stt                       # (2,) velocity estimate
    resid = xy - np.outer(t, slope)
    ssr = float((resid * resid).sum())
    return ssr / (n - _LINE_PARAMS)
