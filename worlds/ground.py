"""Heights above the ground from a surface model: an nDSM as it is, or a DSM minus a ground model.

A DSM gives elevations of the visible surface (roofs, crowns, ground); the world needs heights above
the ground (``World.dsm_m``). The ground is a DTM when one is given, else estimated from the DSM
itself by :func:`estimate_ground_m`:

1. the DSM is cut into cells of ``GROUND_CELL_M`` and each cell keeps the ``GROUND_CELL_PERCENTILE``
   of its valid heights (robust to single low outliers such as noise or water);
2. a morphological opening (a minimum then a maximum filter over a square window of
   ``window_m``) removes every raised object narrower than the window in some direction
   (buildings, tree rows) and keeps planar terrain exactly (an opening maps a plane to itself);
3. a box filter of half the window smooths the steps the opening leaves, and the cells are
   interpolated bilinearly back to the grid.

The cell grid is padded by half a window of "no data" before the opening, so the minimum filter
continues planar ground linearly past the edge of the data and the maximum filter restores it right
up to that edge (without the pad, an opening lowers ground rising towards the edge by up to
``slope * window / 2``); the smoothing leaves a bias of about ``slope * window / 16`` within half a
window of the edge (0.25 m for a 3 % slope and a 120 m window), and the cell percentile puts
sloping ground ~``slope * cell / 2`` low everywhere (centimetres).

The window must exceed the smallest dimension of the largest building (default 150 m: city blocks
and halls are narrower; a larger mall needs ``--ground-window-m``); on curved terrain the opening
cuts crests and fills nothing, so heights on hill tops come out up to ``curvature * window^2 / 8``
too low. Holes (nodata) wider than the window take the low percentile of all valid cells.
"""

from __future__ import annotations

import math
from enum import Enum

import cv2
import numpy as np

#: Cell side (metres) of the low-percentile step (smaller than a street, larger than DSM noise).
GROUND_CELL_M = 5.0
#: Percentile of the heights in a cell that stands for its ground.
GROUND_CELL_PERCENTILE = 10.0
#: Default opening window (metres): wider than city blocks (~80-120 m) and halls (20-60 m).
DEFAULT_GROUND_WINDOW_M = 150.0


class DsmKind(str, Enum):
    """What the values of a ``--dsm`` raster are.

    ``ndsm``: heights above the ground (a normalised DSM), used as they are. ``dsm``: elevations of
    the surface (above a datum): the ground (``--dtm`` or :func:`estimate_ground_m`) is subtracted.
    """

    NDSM = "ndsm"
    DSM = "dsm"


def _odd(n: float) -> int:
    k = max(1, int(round(n)))
    return k if k % 2 == 1 else k + 1


def estimate_ground_m(dsm_m: np.ndarray, m_per_px: float,
                      window_m: float = DEFAULT_GROUND_WINDOW_M) -> np.ndarray:
    """Ground elevation (float32, same shape) under a DSM (float32 metres, NaN = nodata); see the
    module docstring. Raises ValueError when the DSM has no valid pixel."""
    dsm = np.asarray(dsm_m, dtype=np.float32)
    if not np.any(np.isfinite(dsm)):
        raise ValueError("the DSM has no valid pixel")
    h, w = dsm.shape
    c = max(1, int(round(GROUND_CELL_M / m_per_px)))
    ny, nx = math.ceil(h / c), math.ceil(w / c)
    padded = np.full((ny * c, nx * c), np.nan, dtype=np.float32)
    padded[:h, :w] = dsm
    cells = padded.reshape(ny, c, nx, c).transpose(0, 2, 1, 3).reshape(ny, nx, c * c)
    count = np.sum(np.isfinite(cells), axis=2)
    empty = count == 0
    ordered = np.sort(cells, axis=2)                   # NaN sort last
    rank = np.floor(GROUND_CELL_PERCENTILE / 100.0 * np.maximum(count - 1, 0)).astype(np.intp)
    low = np.take_along_axis(ordered, rank[..., None], axis=2)[..., 0].astype(np.float32)
    fallback = float(np.percentile(low[~empty], GROUND_CELL_PERCENTILE))
    k = _odd(window_m / (c * m_per_px))
    r = k // 2
    kernel = np.ones((k, k), dtype=np.uint8)
    big = np.float32(np.finfo(np.float32).max)
    # Pad by the window's half-width with "no data" (ignored by the minimum filter): the erosion then
    # continues a plane linearly into the pad, so the dilation restores it up to the edge of the data.
    padded_low = cv2.copyMakeBorder(np.where(empty, big, low).astype(np.float32), r, r, r, r,
                                    cv2.BORDER_CONSTANT, value=float(big))
    eroded = cv2.erode(padded_low, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=float(big))
    eroded[eroded >= big] = fallback                   # holes wider than the window
    opened = cv2.dilate(eroded, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=-float(big))
    ks = _odd(k / 2.0)
    smooth = cv2.blur(opened, (ks, ks), borderType=cv2.BORDER_REPLICATE)[r:r + ny, r:r + nx]
    full = cv2.resize(smooth, (nx * c, ny * c), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(full[:h, :w], dtype=np.float32)


def heights_above_ground(values_m: np.ndarray, kind: DsmKind, m_per_px: float,
                         dtm_m: np.ndarray | None = None,
                         window_m: float = DEFAULT_GROUND_WINDOW_M) -> np.ndarray:
    """``World.dsm_m`` from a DSM/nDSM on the world grid (float32 metres, NaN = nodata): nDSM as it
    is, DSM minus ``dtm_m`` (or the estimated ground); nodata (in either) -> 0, negatives -> 0."""
    values = np.asarray(values_m, dtype=np.float32)
    if DsmKind(kind) is DsmKind.DSM:
        ground = dtm_m if dtm_m is not None else estimate_ground_m(values, m_per_px, window_m)
        values = values - np.asarray(ground, dtype=np.float32)
    out = np.where(np.isfinite(values), values, np.float32(0.0))
    return np.maximum(out, np.float32(0.0)).astype(np.float32)


__all__ = ["DsmKind", "estimate_ground_m", "heights_above_ground", "DEFAULT_GROUND_WINDOW_M",
           "GROUND_CELL_M", "GROUND_CELL_PERCENTILE"]
