"""Fix errors split by the mean building height in the camera footprint (issue 11, item 5).

Relief is what makes scene matching over a city hard (buildings lean, facades show, streets hide
behind blocks), so every error figure is also reported per bin of the *mean surface height in the
camera footprint at the capture*: the mean of ``World.heights_m`` (metres above the ground, 0 on a
flat world) over the square the nadir camera sees from the capture's height (side
``2 h tan(fov / 2)``, turned with the heading), sampled on a ``FOOTPRINT_SAMPLES`` x
``FOOTPRINT_SAMPLES`` grid of bilinear samples.

Bins (``HEIGHT_BIN_EDGES_M``): < 2 m (open ground, parks, water), 2-6 m (low houses, sparse trees),
6-12 m (housing), 12-20 m (perimeter blocks), >= 20 m (towers); the edges follow the building
heights of issue 11 (houses 6-12 m, blocks 12-24 m, towers 24-40 m), averaged with the streets
between them.

Per set of errors (``ErrorStats``): count, median, RMS of the errors up to the false-match
threshold (5 m by default: the accuracy of the true matches), the share over the threshold (false
matches) and over ``GROSS_ERROR_M`` (20 m: matches on another part of the city).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from scenenav.core.camera_geometry import ground_footprint_m

#: Upper edges of the height bins (m); the last bin is open.
HEIGHT_BIN_EDGES_M: tuple[float, ...] = (2.0, 6.0, 12.0, 20.0)
#: A match this far off lands on another part of the map (issue 11 reports the share over 20 m).
GROSS_ERROR_M = 20.0
#: Samples per side of the footprint grid (64 x 64 bilinear samples per capture, 1.8 m apart at 100 m).
FOOTPRINT_SAMPLES = 64


def footprint_mean_height_m(heights_m: np.ndarray, m_per_px: float, x_m, y_m, heading_rad,
                            altitude_m, fov_deg: float, samples: int = FOOTPRINT_SAMPLES) -> np.ndarray:
    """Mean surface height (m) in the nadir camera footprint of each capture.

    ``x_m, y_m`` (world ENU of the nadir point), ``heading_rad`` (compass, the image's up) and
    ``altitude_m`` are arrays of the same length (or scalars); ``heights_m`` is (H, W) at
    ``m_per_px`` with the world conventions of scenenav/core/frames.py. Samples off the map take the
    nearest edge pixel's height. Non-finite inputs give NaN.
    """
    x = np.atleast_1d(np.asarray(x_m, dtype=float))
    y = np.atleast_1d(np.asarray(y_m, dtype=float))
    hdg = np.broadcast_to(np.asarray(heading_rad, dtype=float), x.shape)
    alt = np.broadcast_to(np.asarray(altitude_m, dtype=float), x.shape)
    out = np.full(x.shape, np.nan)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(hdg) & np.isfinite(alt) & (alt > 0)
    if not ok.any():
        return out
    hh, ww = heights_m.shape
    side = ground_footprint_m(1.0, fov_deg) * alt[ok]                       # (K,)
    s = (np.arange(samples) + 0.5) / samples - 0.5                          # (S,) in (-0.5, 0.5)
    a, b = np.meshgrid(s, s, indexing="xy")                                 # a: right, b: up
    a, b = a.ravel()[None, :] * side[:, None], b.ravel()[None, :] * side[:, None]
    c, sn = np.cos(hdg[ok])[:, None], np.sin(hdg[ok])[:, None]
    # image right = (cos h, -sin h), image up = (sin h, cos h) in (east, north)
    px = x[ok][:, None] + a * c + b * sn
    py = y[ok][:, None] - a * sn + b * c
    u = px / m_per_px + ww / 2.0
    v = hh / 2.0 - py / m_per_px
    vals = map_coordinates(np.asarray(heights_m, dtype=np.float32), [v.ravel() - 0.5, u.ravel() - 0.5],
                           order=1, mode="nearest")
    out[ok] = vals.reshape(u.shape).mean(axis=1)
    return out


@dataclass(frozen=True)
class HeightBin:
    """Mean footprint heights in [lo_m, hi_m) (hi_m None: no upper edge)."""

    lo_m: float
    hi_m: float | None

    @property
    def label(self) -> str:
        if self.lo_m <= 0.0 and self.hi_m is not None:
            return f"< {self.hi_m:g} m"
        if self.hi_m is None:
            return f">= {self.lo_m:g} m"
        return f"{self.lo_m:g}-{self.hi_m:g} m"

    def contains(self, h: np.ndarray) -> np.ndarray:
        upper = np.inf if self.hi_m is None else self.hi_m
        return (h >= self.lo_m) & (h < upper)


def height_bins(edges_m: tuple[float, ...] = HEIGHT_BIN_EDGES_M) -> tuple[HeightBin, ...]:
    """The bins of ``edges_m``: [0, e0), [e0, e1), ..., [e_last, inf)."""
    lows = (0.0,) + tuple(edges_m)
    highs: tuple[float | None, ...] = tuple(edges_m) + (None,)
    return tuple(HeightBin(lo, hi) for lo, hi in zip(lows, highs, strict=True))


def _opt(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


@dataclass(frozen=True)
class ErrorStats:
    """Figures of a set of horizontal fix errors (m). None where the set is empty."""

    n: int
    median_m: float | None
    rms_up_to_threshold_m: float | None     # RMS of the errors <= threshold (the true matches)
    share_over_threshold: float | None      # false matches / n
    share_over_gross: float | None          # errors > gross_m / n

    @classmethod
    def of(cls, errors_m: np.ndarray, threshold_m: float, gross_m: float = GROSS_ERROR_M) -> "ErrorStats":
        e = np.asarray(errors_m, dtype=float)
        e = np.where(np.isnan(e), np.inf, e)          # an unmatched capture counts as far off
        n = int(e.size)
        if n == 0:
            return cls(0, None, None, None, None)
        good = e[e <= threshold_m]
        return cls(n=n, median_m=_opt(float(np.median(e))),
                   rms_up_to_threshold_m=float(np.sqrt(np.mean(good ** 2))) if good.size else None,
                   share_over_threshold=float(np.mean(e > threshold_m)),
                   share_over_gross=float(np.mean(e > gross_m)))

    def to_dict(self) -> dict:
        return {"n": self.n, "median_m": self.median_m, "rms_up_to_threshold_m": self.rms_up_to_threshold_m,
                "share_over_threshold": self.share_over_threshold, "share_over_gross": self.share_over_gross}


@dataclass(frozen=True)
class HeightBinStats:
    """The errors of the captures whose mean footprint height falls in ``bin``."""

    bin: HeightBin
    mean_height_m: float | None           # mean of their footprint heights
    stats: ErrorStats

    def to_dict(self) -> dict:
        return {"label": self.bin.label, "lo_m": self.bin.lo_m, "hi_m": self.bin.hi_m,
                "mean_height_m": self.mean_height_m, **self.stats.to_dict()}


@dataclass(frozen=True)
class HeightSplit:
    """Errors overall and per height bin."""

    threshold_m: float
    gross_m: float
    overall: ErrorStats
    bins: tuple[HeightBinStats, ...]

    def to_dict(self) -> dict:
        return {"threshold_m": self.threshold_m, "gross_m": self.gross_m, "overall": self.overall.to_dict(),
                "bins": [b.to_dict() for b in self.bins]}


def split_by_height(errors_m: np.ndarray, mean_heights_m: np.ndarray, threshold_m: float,
                    gross_m: float = GROSS_ERROR_M,
                    bins: tuple[HeightBin, ...] | None = None) -> HeightSplit:
    """``ErrorStats`` of all errors and of each height bin (captures with a NaN height: overall only)."""
    e = np.asarray(errors_m, dtype=float)
    h = np.asarray(mean_heights_m, dtype=float)
    if e.shape != h.shape:
        raise ValueError(f"errors {e.shape} and heights {h.shape}: expected the same shape")
    out = []
    for b in bins if bins is not None else height_bins():
        sel = b.contains(h)
        out.append(HeightBinStats(bin=b, mean_height_m=float(np.mean(h[sel])) if sel.any() else None,
                                  stats=ErrorStats.of(e[sel], threshold_m, gross_m)))
    return HeightSplit(threshold_m=float(threshold_m), gross_m=float(gross_m),
                       overall=ErrorStats.of(e, threshold_m, gross_m), bins=tuple(out))
