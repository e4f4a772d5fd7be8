"""Arms of a junction as a crop shows them: count the roads that cross an annulus around its centre.

The road graph's degree (``worlds.landcover.Junction.arms``) is what the generator built, not what a
crop shows: an arm may end in a stub after a few metres, run into a square or a parking lot, curve
out of the crop before it is visible as an arm, or merge with a neighbouring road. The paper's
hand-picked Google-Maps crops (5.2) were labelled by eye, i.e. by what the image shows.

:func:`visible_arms` counts, in the ground-truth road raster (``LandCover.ROAD``: carriageways), the
roads that leave the junction and reach (almost) the crop border: the road pixels connected to the
junction (to any road within ``inner_share`` of the crop side from the centre) inside the disc of
radius ``outer_share`` of the side, and their separate crossings of that circle at least
``min_arm_width_m`` wide. A stub ending inside the disc, or a road passing the crop corner without
meeting the junction inside the disc, does not count.

:func:`arm_check` compares that count with the graph's arm count and returns why a crop is
ambiguous, if it is (``ArmVerdict``). The dataset builder drops ambiguous junction crops when asked
(``scenenav dataset --arms visible``, docs/cnn.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np


@dataclass(frozen=True)
class ArmCountConfig:
    """Annulus and thresholds of the visible-arm count (shares of the crop side, metres)."""

    inner_share: float = 0.25       # inner circle radius / crop side (12.5 m on a 50 m crop)
    outer_share: float = 0.45       # outer circle radius / crop side (22.5 m)
    angle_steps: int = 360
    min_arm_width_m: float = 2.5    # narrower road regions on the inner circle are noise
    max_paved_share: float = 0.35   # squares + parking lots in the annulus above this share: ambiguous


DEFAULT_ARM_COUNT = ArmCountConfig()


class ArmVerdict(str, Enum):
    """Outcome of comparing the visible arms with the graph's arm count."""

    AGREE = "agree"                     # visible arm count = graph arm count (class-wise)
    DISAGREE = "disagree"               # the crop shows another arm count than the graph
    PAVED = "paved"                     # a square or parking lot fills much of the annulus
    UNREADABLE = "unreadable"           # no road at the centre, or road all around the circle


def _circle(mask: np.ndarray, u: float, v: float, r: float, n_ang: int) -> np.ndarray:
    """(n_ang,) nearest samples of ``mask`` on the circle of radius r around continuous (u, v)."""
    ang = np.arange(n_ang, dtype=np.float64) * (2.0 * math.pi / n_ang)
    mx = (u - 0.5 + r * np.cos(ang)).astype(np.float32)[None, :]
    my = (v - 0.5 + r * np.sin(ang)).astype(np.float32)[None, :]
    return cv2.remap(mask, mx, my, interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=0)[0]


def _runs(ring: np.ndarray, min_len: float) -> int:
    """Circular runs of non-zero values at least ``min_len`` samples long."""
    on = ring.astype(bool)
    if on.all():
        return 1
    if not on.any():
        return 0
    on = np.roll(on, -int(np.flatnonzero(~on)[0]))   # start on a gap
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return int(np.sum((ends - starts) >= min_len))


def _junction_road(road: np.ndarray, u: float, v: float, r_out: float, r_in: float) -> np.ndarray | None:
    """Road pixels connected to the junction (any road pixel within ``r_in`` of the centre) inside
    the disc of radius ``r_out + 2`` around (u, v), in a window; None when no road is near the centre."""
    h, w = road.shape
    rad = int(math.ceil(r_out)) + 3
    cu, cv_ = int(math.floor(u)), int(math.floor(v))
    x0, y0 = max(cu - rad, 0), max(cv_ - rad, 0)
    x1, y1 = min(cu + rad + 1, w), min(cv_ + rad + 1, h)
    win = road[y0:y1, x0:x1].copy()
    yy, xx = np.mgrid[y0:y1, x0:x1]
    d = np.hypot(xx + 0.5 - u, yy + 0.5 - v)
    win[d > r_out + 2.0] = 0
    n, lab = cv2.connectedComponents(win, connectivity=8)
    core = np.unique(lab[(d <= r_in) & (win > 0)])
    core = core[core > 0]
    if core.size == 0:
        return None
    out = np.zeros_like(road)
    out[y0:y1, x0:x1] = np.isin(lab, core).astype(np.uint8)
    return out


def visible_arms(road: np.ndarray, u: float, v: float, crop_px: float, m_per_px: float,
                 cfg: ArmCountConfig = DEFAULT_ARM_COUNT) -> int:
    """Arms the crop centred on continuous map pixel (u, v) shows: road regions connected to the
    junction (road within ``inner_share`` of the side from the centre) that cross the circle at
    ``outer_share`` of the side. ``road``: uint8 mask (1 = carriageway) of the whole map; 0 when
    no road is near the centre, -1 when the circle is road all around (a paved area, not arms)."""
    r_in, r_out = cfg.inner_share * crop_px, cfg.outer_share * crop_px
    mine = _junction_road(road, u, v, r_out, r_in)
    if mine is None:
        return 0
    ring = _circle(mine, u, v, r_out, cfg.angle_steps)
    if ring.all():
        return -1
    min_len = cfg.min_arm_width_m / m_per_px / r_out * cfg.angle_steps / (2.0 * math.pi)
    return _runs(ring, min_len)


def paved_share(paved: np.ndarray, u: float, v: float, crop_px: float, cfg: ArmCountConfig = DEFAULT_ARM_COUNT) -> float:
    """Share of the annulus covered by ``paved`` (uint8 mask: squares, parking lots)."""
    vals = [_circle(paved, u, v, r, cfg.angle_steps).mean()
            for r in np.linspace(cfg.inner_share * crop_px, cfg.outer_share * crop_px, 5)]
    return float(np.mean(vals))


def arm_check(graph_arms: int, road: np.ndarray, paved: np.ndarray, u: float, v: float, crop_px: float,
              m_per_px: float, cfg: ArmCountConfig = DEFAULT_ARM_COUNT) -> tuple[ArmVerdict, int]:
    """(verdict, visible arm count) for a junction crop centred at (u, v); four or more arms are one class."""
    seen = visible_arms(road, u, v, crop_px, m_per_px, cfg)
    if seen <= 0:
        return ArmVerdict.UNREADABLE, seen
    if paved_share(paved, u, v, crop_px, cfg) > cfg.max_paved_share:
        return ArmVerdict.PAVED, seen
    if min(seen, 4) != min(graph_arms, 4):
        return ArmVerdict.DISAGREE, seen
    return ArmVerdict.AGREE, seen
