"""The cars of one day: moving cars on the traffic lanes, parked cars in the stalls, and their paint.

Each day (capture or reference) draws its own cars from the traffic stream, so the orthophoto and
the reference map show different traffic over identical roads.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from worlds.city_config import Stream, stream_rng
from worlds.drawing import fill_convex
from worlds.materials import CAR_COLOURS, CAR_WEIGHTS
from worlds.reference import DayConditions

if TYPE_CHECKING:
    from worlds.scene import Scene

CAR_HEIGHT_M = 1.5


@dataclass
class Cars:
    """The cars of one day, in continuous pixel coordinates."""

    corners: np.ndarray     # (n, 4, 2), corners[0] -> corners[1] along the car, [1] at the front
    colour: np.ndarray      # (n, 3)
    centre_v: np.ndarray    # (n,)


def cars_for_day(sc: Scene, day: DayConditions) -> Cars:
    cfg = sc.cfg
    mpp = cfg.m_per_px
    rng = stream_rng(cfg, Stream.TRAFFIC, day.traffic_seed)
    lanes = sc.lanes
    pos_list, dir_list = [], []
    total = float(lanes.usable.sum()) if lanes.usable.size else 0.0
    if total > 0 and cfg.cars_per_100m_lane > 0:
        n = int(rng.poisson(total * mpp / 100.0 * cfg.cars_per_100m_lane))
        g = np.sort(rng.uniform(0.0, total, n))
        cum = np.concatenate([[0.0], np.cumsum(lanes.usable)])
        lane = np.clip(np.searchsorted(cum, g, side="right") - 1, 0, len(lanes.usable) - 1)
        keep = np.ones(n, dtype=bool)
        if n > 1:
            close = (np.diff(g) < 7.0 / mpp) & (lane[1:] == lane[:-1])
            keep[1:] &= ~close
        g, lane = g[keep], lane[keep]
        arc = lanes.start[lane] + (g - cum[lane])
        j = np.clip(np.searchsorted(lanes.arc, arc, side="right") - 1, 0, len(lanes.arc) - 2)
        seg = lanes.pts[j + 1] - lanes.pts[j]
        seg_len = np.maximum(np.hypot(seg[:, 0], seg[:, 1]), 1e-9)
        frac = np.clip((arc - lanes.arc[j]) / seg_len, 0.0, 1.0)
        pos_list.append(lanes.pts[j] + seg * frac[:, None])
        dir_list.append(seg / seg_len[:, None] * lanes.sign[lane][:, None])
    if len(sc.spots):
        occupied = rng.random(len(sc.spots)) < cfg.parking_occupancy
        sp = sc.spots[occupied]
        flip = np.where(rng.random(len(sp)) < 0.5, 1.0, -1.0)[:, None]
        pos_list.append(sp[:, :2])
        dir_list.append(sp[:, 2:] * flip)
    if not pos_list:
        return Cars(np.zeros((0, 4, 2)), np.zeros((0, 3)), np.zeros(0))
    pos = np.concatenate(pos_list)
    direc = np.concatenate(dir_list)
    m = len(pos)
    length = rng.uniform(4.0, 5.0, m) / mpp
    width = rng.uniform(1.7, 1.95, m) / mpp
    side = np.stack([-direc[:, 1], direc[:, 0]], axis=1)
    hl = (direc * (length / 2)[:, None])
    hw = (side * (width / 2)[:, None])
    corners = np.stack([pos - hl - hw, pos + hl - hw, pos + hl + hw, pos - hl + hw], axis=1)
    probs = np.array(CAR_WEIGHTS) / sum(CAR_WEIGHTS)
    colour = np.array(CAR_COLOURS, dtype=np.float32)[rng.choice(len(CAR_COLOURS), size=m, p=probs)]
    colour *= rng.uniform(0.9, 1.1, (m, 1)).astype(np.float32)
    return Cars(corners, colour, pos[:, 1])


def paint_cars(canvas: np.ndarray, cars: Cars, idx: np.ndarray, top: int) -> None:
    for i in idx:
        c = cars.corners[i]
        col = cars.colour[i]
        fill_convex(canvas, c, tuple(float(x) for x in col), 0, top)
        front = c[1] - c[0]
        shield = np.array([c[0] + front * 0.58, c[0] + front * 0.75, c[3] + front * 0.75,
                           c[3] + front * 0.58])
        fill_convex(canvas, shield, tuple(float(x) * 0.3 + 10 for x in col), 0, top)
