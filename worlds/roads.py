"""Roads in the material raster: sidewalks, kerbs, carriageway, lane markings, zebra crossings.

:func:`draw_roads` also returns the traffic lanes (:class:`Lanes`) the day's cars are sampled on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worlds.city_config import CityConfig
from worlds.drawing import arc_lengths, interp_polyline, polyline_normals, stroke, sub_polyline
from worlds.landcover import JunctionKind
from worlds.materials import Material
from worlds.road_graph import RoadClass, RoadGraph


@dataclass
class Lanes:
    """All traffic lanes concatenated, for vectorised car sampling."""

    pts: np.ndarray        # (N, 2) lane polyline points
    arc: np.ndarray        # (N,) global arc length (lanes separated by gaps)
    start: np.ndarray      # (L,) global arc of each lane's first usable point
    usable: np.ndarray     # (L,) usable length of each lane
    sign: np.ndarray       # (L,) +1 along the polyline, -1 against it


def _end_clearance_px(g: RoadGraph, e: int, n: int, mpp: float) -> float:
    """Distance from node n along edge e to where the junction area ends (0 for plain nodes)."""
    if g.degree(n) < 3 and g.kind(n) is not JunctionKind.CORNER:
        return 0.0
    widths = [g.edges[o].width_m for o in g.adj[n] if o != e]
    return (max(widths, default=0.0) / 2.0 + 1.0) / mpp


def draw_roads(material: np.ndarray, g: RoadGraph, cfg: CityConfig,
                rng: np.random.Generator) -> Lanes:
    mpp = cfg.m_per_px
    edges = g.alive_edges()
    shapes = {e: g.polyline(e) for e in edges}
    width_px = {e: g.edges[e].width_m / mpp for e in edges}
    for e in edges:
        stroke(material, [shapes[e]], int(Material.SIDEWALK),
                round(width_px[e] + 2 * cfg.sidewalk_width_m / mpp))
    for e in edges:
        stroke(material, [shapes[e]], int(Material.KERB), round(width_px[e]) + 2)
    for e in edges:
        stroke(material, [shapes[e]], int(Material.ROAD), round(width_px[e]))

    marks = np.zeros_like(material)
    thin = max(1, round(0.2 / mpp))
    zebra_w = max(1, round(0.8 / mpp))
    crossings = {n: rng.random() < 0.6 for n in range(len(g.pos))}
    lane_pts, lane_arc, lane_start, lane_len, lane_sign = [], [], [], [], []
    arc_offset = 0.0
    for e in edges:
        E = g.edges[e]
        w = width_px[e]
        dense = g.polyline(e, 1.0 / mpp)
        arc = arc_lengths(dense)
        total = arc[-1]
        clear = [_end_clearance_px(g, e, E.a, mpp), _end_clearance_px(g, e, E.b, mpp)]
        zebra = [crossings[E.a] and clear[0] > 0, crossings[E.b] and clear[1] > 0]
        s0 = clear[0] + (4.0 / mpp if zebra[0] else 0.0)
        s1 = total - clear[1] - (4.0 / mpp if zebra[1] else 0.0)
        normals = polyline_normals(dense)
        segs: list[np.ndarray] = []
        solids: list[np.ndarray] = []
        if s1 - s0 > 2.0 / mpp and E.width_m >= 7.0:
            if E.road_class is RoadClass.AVENUE:
                n_lanes = 2 if E.width_m < 19.0 else 3
                solids.append(sub_polyline(dense, arc, s0, s1))
                for k in range(1, n_lanes):
                    for sgn in (-1.0, 1.0):
                        off = dense + normals * (sgn * k * w / (2 * n_lanes))
                        segs += _dashes(off, arc_lengths(off), s0, s1, 3.0 / mpp, 9.0 / mpp)
                for sgn in (-1.0, 1.0):
                    off = dense + normals * (sgn * (w / 2.0 - 0.6 / mpp))
                    solids.append(sub_polyline(off, arc_lengths(off), s0, s1))
            else:
                segs += _dashes(dense, arc, s0, s1, 3.0 / mpp, 9.0 / mpp)
        stroke(marks, segs, 1, thin)
        stroke(marks, solids, 1, thin)
        for end, (cl, z) in enumerate(zip(clear, zebra, strict=True)):
            if not z or total < cl + 4.0 / mpp:
                continue
            a0, a1 = (cl, cl + 3.0 / mpp) if end == 0 else (total - cl - 3.0 / mpp, total - cl)
            p0, p1 = interp_polyline(dense, arc, [a0, a1])
            nrm = polyline_normals(np.array([p0, p1]))[0]
            offs = np.arange(-w / 2 + 0.6 / mpp, w / 2 - 0.6 / mpp, 1.6 / mpp)
            stripes = [np.array([p0 + nrm * o, p1 + nrm * o]) for o in offs]
            stroke(marks, stripes, 1, zebra_w)
        # traffic lanes
        n_dir = 1 if E.width_m < 10.0 else (2 if E.width_m < 18.0 else 3)
        lane_w = w / (2 * n_dir)
        c0 = clear[0] + 3.0 / mpp if clear[0] > 0 else 0.0
        c1 = total - (clear[1] + 3.0 / mpp if clear[1] > 0 else 0.0)
        if c1 - c0 < 6.0 / mpp:
            continue
        for k in range(n_dir):
            for sgn in (-1.0, 1.0):
                off = dense + normals * (sgn * (k + 0.5) * lane_w)
                oarc = arc_lengths(off)
                scale = oarc[-1] / max(total, 1e-9)
                lane_pts.append(off)
                lane_arc.append(oarc + arc_offset)
                lane_start.append(arc_offset + c0 * scale)
                lane_len.append((c1 - c0) * scale)
                lane_sign.append(sgn)
                arc_offset += oarc[-1] + 10.0
    on_road = (marks > 0) & (material == Material.ROAD)
    material[on_road] = Material.MARKING
    if lane_pts:
        lanes = Lanes(np.concatenate(lane_pts), np.concatenate(lane_arc), np.array(lane_start),
                       np.array(lane_len), np.array(lane_sign))
    else:
        lanes = Lanes(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))
    return lanes


def _dashes(poly: np.ndarray, arc: np.ndarray, s0: float, s1: float, dash: float,
            period: float) -> list[np.ndarray]:
    starts = np.arange(s0, s1 - 0.5 * dash, period)
    if starts.size == 0:
        return []
    ends = np.minimum(starts + dash, s1)
    p0 = interp_polyline(poly, arc, starts)
    p1 = interp_polyline(poly, arc, ends)
    return list(np.stack([p0, p1], axis=1))
