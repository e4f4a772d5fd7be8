"""The camera as an optical-flow sensor: the image motion between two consecutive frames.

A downward camera fixed to the body sees the ground move by (du, dv) pixels between two captures
``dt`` apart. Over a surface at range r, that is the flow a dedicated flow sensor measures (the
``FlowSample`` convention, body FLU): for a vehicle moving with body velocity (vx, vy) and turning at
body rates (wx, wy), the mean apparent angular rate of the surface at the image centre is
(-vy / r - wx, vx / r - wy). With the fixed mount's axes (image right = body -y, image up = body +x,
``sitl.camera_model.fixed_mount_axes``) and the pinhole's focal length f (px):

    flow_x = -du / (f dt),   flow_y = +dv / (f dt)

(u right, v down). The shift is the peak of the phase correlation of the two undistorted grey
captures (their means removed, a Hann window against the image border), with the normalised
cross-power spectrum weighted by a Gaussian (``PEAK_SIGMA_PX``): the peak is then a Gaussian a few
pixels wide whose sub-pixel position a three-point fit of its logarithm finds without the pull
towards whole pixels a centroid has (OpenCV's ``phaseCorrelate`` measured 1.93 px for a 1.73 px
shift of a smooth texture). The peak's height against that of two identical images, in [0, 1], is
the quality: a texture-less or changed scene has none. The body rotation is NOT removed here: the autopilot removes it
with its own gyro over the same interval (as ArduPilot does for a flow sensor without a gyro of its
own) and divides by the range it estimates (SN_CAM_FLOW, docs/autopilot.md).

Why a camera flow (issue 12, docs/realism.md "The camera as a flow sensor"): at 100 m a flow module
of the PAW3902 class measures 0.05 rad/s per sample, 5 m/s of velocity noise; the 200 px camera
registers consecutive frames to about 0.2 px (0.01 rad/s at 10 Hz), which holds the dead-reckoned
velocity in the stretches where no map match is true.

Pure: numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Two captures further apart than this are not consecutive (a dropped frame, a paused run): no flow.
MAX_INTERVAL_S = 0.5
#: 1-sigma width (px) of the correlation peak the spectral weighting makes
PEAK_SIGMA_PX = 1.5


@dataclass(frozen=True)
class CameraFlow:
    """Flow between the previous capture and this one: ``flow_flu_rad_s`` (rad/s, body x and y, the
    body rotation not removed), ``interval_s`` (s), ``quality`` (phase-correlation response, 0..1)."""

    flow_flu_rad_s: tuple[float, float]
    interval_s: float
    quality: float


class FrameFlow:
    """Keeps the previous capture; ``update`` returns the flow from it to the new one (None for the
    first capture, after a gap longer than ``MAX_INTERVAL_S``, or when the size changed)."""

    def __init__(self) -> None:
        self._prev: tuple[float, np.ndarray] | None = None      # (t s, windowed spectrum)
        self._shape: tuple[int, int] | None = None
        self._window = np.zeros((0, 0))
        self._weight = np.zeros((0, 0))
        self._ideal_peak = 1.0

    def reset(self) -> None:
        self._prev = None

    def update(self, t_s: float, gray: np.ndarray, focal_px: tuple[float, float]) -> CameraFlow | None:
        """``gray``: the undistorted capture (float, any range), ``focal_px``: its focal lengths
        (fx, fy) in pixels, ``t_s``: its capture time (s)."""
        fx, fy = (float(f) for f in focal_px)
        img = np.asarray(gray, dtype=np.float64)
        if img.ndim != 2 or min(img.shape) < 8 or not np.all(np.isfinite(img)):
            self._prev = None
            return None
        if img.shape != self._shape:
            self._prepare(img.shape)
            self._prev = None
        spectrum = np.fft.rfft2((img - img.mean()) * self._window)
        prev, self._prev = self._prev, (float(t_s), spectrum)
        if prev is None or not (fx > 0.0 and fy > 0.0):
            return None
        dt = float(t_s) - prev[0]
        if not 0.0 < dt <= MAX_INTERVAL_S:
            return None
        du, dv, quality = self._peak(spectrum * np.conj(prev[1]))
        return CameraFlow((-du / (fx * dt), dv / (fy * dt)), dt, quality)

    def _prepare(self, shape: tuple[int, int]) -> None:
        h, w = shape
        self._shape = (h, w)
        self._window = np.outer(np.hanning(h), np.hanning(w))
        ky = np.fft.fftfreq(h) * h
        kx = np.fft.rfftfreq(w) * w
        # a Gaussian peak of PEAK_SIGMA_PX in space is a Gaussian of N / (2 pi sigma) in frequency
        sy, sx = h / (2.0 * math.pi * PEAK_SIGMA_PX), w / (2.0 * math.pi * PEAK_SIGMA_PX)
        self._weight = np.exp(-0.5 * ((ky[:, None] / sy) ** 2 + (kx[None, :] / sx) ** 2))
        self._weight[0, 0] = 0.0                                      # the means are removed
        self._ideal_peak = float(np.fft.irfft2(self._weight, s=shape)[0, 0])

    def _peak(self, cross: np.ndarray) -> tuple[float, float, float]:
        """(du, dv, quality) of the weighted, normalised cross-power spectrum ``cross``."""
        h, w = self._shape or (0, 0)
        mag = np.abs(cross)
        floor = 1e-12 * max(float(mag.max()), 1e-300)
        norm = np.divide(cross, mag, out=np.zeros_like(cross), where=mag > floor)
        r = np.fft.irfft2(norm * self._weight, s=(h, w))
        i, j = np.unravel_index(int(np.argmax(r)), r.shape)
        peak = float(r[i, j])
        quality = float(min(max(peak / self._ideal_peak, 0.0), 1.0)) if self._ideal_peak > 0 else 0.0
        di = _log_parabola(r[(i - 1) % h, j], peak, r[(i + 1) % h, j])
        dj = _log_parabola(r[i, (j - 1) % w], peak, r[i, (j + 1) % w])
        dv = (i if i <= h // 2 else i - h) + di
        du = (j if j <= w // 2 else j - w) + dj
        return float(du), float(dv), quality


def _log_parabola(left: float, centre: float, right: float) -> float:
    """Sub-pixel offset of a Gaussian peak from three samples (the parabola through their logs);
    0 when a sample is not positive or the fit is not a maximum."""
    if min(left, centre, right) <= 0.0:
        return 0.0
    a, b, c = math.log(left), math.log(centre), math.log(right)
    den = a - 2.0 * b + c
    if den >= 0.0:
        return 0.0
    return float(min(max(0.5 * (a - c) / den, -0.5), 0.5))
