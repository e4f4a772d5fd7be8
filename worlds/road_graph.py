"""The street graph: a jittered, rotated grid with avenues, tees, corners, wyes, bends and curves.

:func:`build_graph` turns the grid into a graph with removed street segments (tees, corners),
corner-cutting diagonals (wyes), bends and curved edges, cuts it at the open features (joining it to
their ring roads, bridges over rivers) and makes sure every junction kind occurs.
:func:`graph_junctions` gives the junction ground truth.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from worlds.city_config import CityConfig
from worlds.features import Blocked, Ring
from worlds.landcover import Junction, JunctionKind, classify_arms

log = logging.getLogger(__name__)


class RoadClass(IntEnum):
    """Road classes: grid streets, avenues (every n-th grid line), corner-cutting diagonals."""

    STREET = 1
    AVENUE = 2
    DIAGONAL = 3


@dataclass
class Edge:
    """One road segment between two graph nodes (straight, or a quadratic Bezier)."""

    a: int
    b: int
    width_m: float
    road_class: RoadClass
    ctrl: np.ndarray | None = None   # quadratic Bezier control point (curved edges)
    alive: bool = True
    modified: bool = False


class RoadGraph:
    """Nodes (continuous pixel positions) and edges (straight or quadratic Bezier)."""

    def __init__(self) -> None:
        self.pos: list[np.ndarray] = []
        self.adj: list[list[int]] = []
        self.node_alive: list[bool] = []
        self.edges: list[Edge] = []

    def add_node(self, p) -> int:
        self.pos.append(np.asarray(p, dtype=float))
        self.adj.append([])
        self.node_alive.append(True)
        return len(self.pos) - 1

    def add_edge(self, a: int, b: int, width_m: float, road_class: RoadClass,
                 ctrl: np.ndarray | None = None, modified: bool = False) -> int:
        self.edges.append(Edge(a, b, width_m, road_class, ctrl, True, modified))
        e = len(self.edges) - 1
        self.adj[a].append(e)
        self.adj[b].append(e)
        return e

    def kill_edge(self, e: int) -> None:
        E = self.edges[e]
        if not E.alive:
            return
        E.alive = False
        self.adj[E.a].remove(e)
        self.adj[E.b].remove(e)

    def kill_node(self, n: int) -> None:
        for e in list(self.adj[n]):
            self.kill_edge(e)
        self.node_alive[n] = False

    def degree(self, n: int) -> int:
        return len(self.adj[n])

    def other(self, e: int, n: int) -> int:
        E = self.edges[e]
        return E.b if E.a == n else E.a

    def arm_angle(self, e: int, n: int) -> float:
        E = self.edges[e]
        target = E.ctrl if E.ctrl is not None else self.pos[self.other(e, n)]
        d = target - self.pos[n]
        return math.atan2(d[1], d[0])

    def chord(self, e: int) -> float:
        E = self.edges[e]
        return float(np.hypot(*(self.pos[E.b] - self.pos[E.a])))

    def polyline(self, e: int, step_px: float | None = None) -> np.ndarray:
        """Points along the edge from a to b; straight edges give 2 points unless step_px is set."""
        E = self.edges[e]
        pa, pb = self.pos[E.a], self.pos[E.b]
        length = self.chord(e)
        if E.ctrl is None:
            if step_px is None:
                return np.array([pa, pb])
            t = np.linspace(0.0, 1.0, max(2, int(math.ceil(length / step_px)) + 1))[:, None]
            return pa + t * (pb - pa)
        step = step_px if step_px is not None else 3.0
        t = np.linspace(0.0, 1.0, max(12, int(math.ceil(length / step)) + 1))[:, None]
        return (1 - t) ** 2 * pa + 2 * (1 - t) * t * E.ctrl + t ** 2 * pb

    def split(self, e: int, t_from_a: float, offset_px: float) -> int:
        """Replace edge e by two edges through a new node (offset sideways for bends)."""
        E = self.edges[e]
        pa, pb = self.pos[E.a], self.pos[E.b]
        d = pb - pa
        n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
        m = self.add_node(pa + t_from_a * d + n * offset_px)
        self.kill_edge(e)
        self.add_edge(E.a, m, E.width_m, E.road_class, modified=True)
        self.add_edge(m, E.b, E.width_m, E.road_class, modified=True)
        return m

    def kind(self, n: int) -> JunctionKind | None:
        return classify_arms([self.arm_angle(e, n) for e in self.adj[n]])

    def alive_edges(self) -> list[int]:
        return [i for i, E in enumerate(self.edges) if E.alive]


def _grid_graph(cfg: CityConfig, rng: np.random.Generator, angle: float) -> RoadGraph:
    W, H, mpp = cfg.width_px, cfg.height_px, cfg.m_per_px
    s = cfg.road_spacing_m / mpp
    half = 0.5 * math.hypot(W, H) + 1.5 * s
    jit = cfg.road_spacing_jitter

    def lines() -> tuple[np.ndarray, list[tuple[float, RoadClass]]]:
        pos = [-half - rng.uniform(0.0, s)]
        while pos[-1] < half:
            pos.append(pos[-1] + s * rng.uniform(1.0 - jit, 1.0 + jit))
        phase = int(rng.integers(cfg.avenue_every_n))
        styles = []
        for i in range(len(pos)):
            if i % cfg.avenue_every_n == phase:
                w = rng.uniform(cfg.avenue_width_min_m, cfg.avenue_width_max_m)
                styles.append((round(w * 2) / 2, RoadClass.AVENUE))
            else:
                w = rng.uniform(cfg.street_width_min_m, cfg.street_width_max_m)
                styles.append((round(w * 2) / 2, RoadClass.STREET))
        return np.array(pos), styles

    xs, col_styles = lines()
    ys, row_styles = lines()
    ca, sa = math.cos(angle), math.sin(angle)
    centre = np.array([W / 2.0, H / 2.0])
    jitter = cfg.node_jitter_m / mpp
    g = RoadGraph()
    index = -np.ones((len(xs), len(ys)), dtype=np.int64)
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            p = centre + np.array([ca * x - sa * y, sa * x + ca * y]) + rng.normal(0.0, jitter, 2)
            if -1.5 * s <= p[0] <= W + 1.5 * s and -1.5 * s <= p[1] <= H + 1.5 * s:
                index[i, j] = g.add_node(p)
    for i in range(len(xs)):
        for j in range(len(ys)):
            n = index[i, j]
            if n < 0:
                continue
            if i + 1 < len(xs) and index[i + 1, j] >= 0:
                w, cls = row_styles[j]
                g.add_edge(int(n), int(index[i + 1, j]), w, cls)
            if j + 1 < len(ys) and index[i, j + 1] >= 0:
                w, cls = col_styles[i]
                g.add_edge(int(n), int(index[i, j + 1]), w, cls)
    return g


def _in_map(p: np.ndarray, W: int, H: int, margin: float = 0.0) -> bool:
    return margin <= p[0] < W - margin and margin <= p[1] < H - margin


def _sample(raster: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Raster values at continuous points (0 outside the raster)."""
    H, W = raster.shape
    u = np.floor(pts[:, 0]).astype(np.int64)
    v = np.floor(pts[:, 1]).astype(np.int64)
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    out = np.zeros(len(pts), dtype=raster.dtype)
    out[inside] = raster[v[inside], u[inside]]
    return out


def _path_is_free(blocked: np.ndarray, pts: np.ndarray) -> bool:
    return not np.any(_sample(blocked, pts) != Blocked.FREE)


def _eligible_street(g: RoadGraph, e: int, min_len: float) -> bool:
    E = g.edges[e]
    return (E.alive and E.road_class is RoadClass.STREET and not E.modified and E.ctrl is None
            and g.chord(e) >= min_len)


def _corner_diagonal(g: RoadGraph, n: int, rng: np.random.Generator, cfg: CityConfig, s_px: float,
                     blocked: np.ndarray | None = None) -> bool:
    """Cut the corner between two perpendicular street arms of node n with a diagonal (two wyes)."""
    arms = sorted((g.arm_angle(e, n), e) for e in g.adj[n])
    pairs = []
    for k in range(len(arms)):
        (a1, e1), (a2, e2) = arms[k], arms[(k + 1) % len(arms)]
        gap = (a2 - a1) % (2 * math.pi)
        if (math.radians(70) <= gap <= math.radians(110) and _eligible_street(g, e1, 0.55 * s_px)
                and _eligible_street(g, e2, 0.55 * s_px)):
            pairs.append((e1, e2))
    if not pairs:
        return False
    e1, e2 = pairs[int(rng.integers(len(pairs)))]
    t1, t2 = rng.uniform(0.4, 0.6, 2)
    ends = []
    for e, t in ((e1, t1), (e2, t2)):
        E = g.edges[e]
        ends.append((e, t if E.a == n else 1.0 - t))
    p = [g.pos[g.edges[e].a] + t * (g.pos[g.edges[e].b] - g.pos[g.edges[e].a]) for e, t in ends]
    for here, there in ((p[0], p[1]), (p[1], p[0])):
        # keep the wye's acute angle open enough to read as two separate roads
        d1, d2 = g.pos[n] - here, there - here
        cos = float(d1 @ d2) / max(float(np.hypot(*d1) * np.hypot(*d2)), 1e-9)
        if cos > math.cos(math.radians(35.0)):
            return False
    if blocked is not None:
        seg = p[0] + np.linspace(0, 1, 40)[:, None] * (p[1] - p[0])
        if not _path_is_free(blocked, seg):
            return False
    m1 = g.split(ends[0][0], ends[0][1], 0.0)
    m2 = g.split(ends[1][0], ends[1][1], 0.0)
    hi = min(cfg.street_width_max_m, cfg.street_width_min_m + 3.0)
    width = round(rng.uniform(cfg.street_width_min_m, hi) * 2) / 2
    g.add_edge(m1, m2, width, RoadClass.DIAGONAL, modified=True)
    return True


def _bend(g: RoadGraph, e: int, rng: np.random.Generator,
          blocked: np.ndarray | None = None) -> bool:
    dev = math.radians(rng.uniform(16.0, 26.0))
    offset = 0.5 * g.chord(e) * math.tan(dev) * (1 if rng.random() < 0.5 else -1)
    if blocked is not None:
        E = g.edges[e]
        pa, pb = g.pos[E.a], g.pos[E.b]
        d = pb - pa
        n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
        m = 0.5 * (pa + pb) + n * offset
        t = np.linspace(0, 1, 30)[:, None]
        if not (_path_is_free(blocked, pa + t * (m - pa)) and _path_is_free(blocked, m + t * (pb - m))):
            return False
    g.split(e, 0.5, offset)
    return True


def build_graph(cfg: CityConfig, rng: np.random.Generator, angle: float, blocked: np.ndarray,
                 owner: np.ndarray, rings: list[Ring | None]) -> RoadGraph:
    W, H = cfg.width_px, cfg.height_px
    s_px = cfg.road_spacing_m / cfg.m_per_px
    g = _grid_graph(cfg, rng, angle)

    # tees and corners: remove street segments, never leaving a dead end
    for e in rng.permutation(len(g.edges)):
        E = g.edges[e]
        draw = rng.random()
        if (E.alive and E.road_class is RoadClass.STREET and draw < cfg.edge_removal_share
                and g.degree(E.a) >= 3 and g.degree(E.b) >= 3):
            g.kill_edge(int(e))
    # wyes: corner-cutting diagonals
    for n in rng.permutation(len(g.pos)):
        draw = rng.random()
        if draw < cfg.diagonal_share and g.node_alive[n] and _in_map(g.pos[n], W, H):
            _corner_diagonal(g, int(n), rng, cfg, s_px)
    # bends, then smooth curves
    for e in rng.permutation(len(g.edges)):
        draw = rng.random()
        if draw < cfg.bend_share and _eligible_street(g, int(e), 0.6 * s_px):
            _bend(g, int(e), rng)
    for e in rng.permutation(len(g.edges)):
        E = g.edges[e]
        draw = rng.random()
        if (draw < cfg.curve_share and E.alive and not E.modified
                and E.road_class in (RoadClass.STREET, RoadClass.AVENUE)):
            pa, pb = g.pos[E.a], g.pos[E.b]
            d = pb - pa
            n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
            dev = math.radians(rng.uniform(10.0, 20.0)) * (1 if rng.random() < 0.5 else -1)
            E.ctrl = 0.5 * (pa + pb) + n * 0.5 * g.chord(int(e)) * math.tan(dev)
            E.modified = True

    _cut_at_features(g, blocked, owner, rings, cfg)
    _ensure_kinds(g, cfg, rng, s_px, blocked)
    for n in range(len(g.pos)):
        if g.node_alive[n] and g.degree(n) == 0:
            g.kill_node(n)
    return g


def _cut_at_features(g: RoadGraph, blocked: np.ndarray, owner: np.ndarray,
                     rings: list[Ring | None], cfg: CityConfig) -> None:
    """Connect the street grid to the ring roads around features; rivers get bridges.

    An edge entering a feature's clearance zone is cut where it meets the feature's ring road and
    joined to it (a tee or wye on the ring); without a ring in reach it ends in a cul-de-sac (stubs
    shorter than 30 m are dropped). Nodes inside any zone are removed. Edges crossing a river with
    both ends on land stay (bridges); edges running along a river are removed.
    """
    mpp = cfg.m_per_px
    step = 2.0
    back = int(math.ceil(3.0 / mpp / step))
    min_stub = 30.0 / mpp
    join = 8.0 / mpp
    node_free = [g.node_alive[n] and _sample(blocked, g.pos[n][None])[0] == Blocked.FREE
                 for n in range(len(g.pos))]
    attach: dict[int, list[int]] = {i: [] for i, r in enumerate(rings) if r is not None}
    polys = [r.poly for r in rings if r is not None]
    ring_pts = np.concatenate(polys) if polys else np.zeros((0, 2))
    near_ring = 45.0 / mpp
    for e in g.alive_edges():
        E = g.edges[e]
        pts = g.polyline(e, step)
        codes = _sample(blocked, pts)
        along_river = np.mean(codes == Blocked.RIVER) > 0.5
        if (not along_river and not np.any(codes == Blocked.HARD)
                and node_free[E.a] and node_free[E.b]):
            continue
        g.kill_edge(e)
        if along_river:
            continue
        own = _sample(owner, pts)
        bad = np.nonzero(codes != Blocked.FREE)[0]
        for node, seq in ((E.a, np.arange(len(pts))), (E.b, np.arange(len(pts))[::-1])):
            if not node_free[node]:
                continue
            hits = np.nonzero(own[seq] != 0)[0]
            if hits.size and _meets_ring_squarely(_owned_ring(rings, int(own[seq[hits[0]]]) - 1),
                                                  g.pos[node], pts[int(seq[hits[0]])]):
                j = int(seq[hits[0]])
                ring_id = int(own[j]) - 1
                if float(np.hypot(*(pts[j] - g.pos[node]))) < join:
                    attach[ring_id].append(node)
                else:
                    end = g.add_node(pts[j])
                    node_free.append(True)
                    g.add_edge(node, end, E.width_m, E.road_class, modified=True)
                    attach[ring_id].append(end)
                continue
            idx = int(bad[0] - back) if node == E.a else int(bad[-1] + back)
            if idx < 0 or idx >= len(pts):
                continue
            if float(np.hypot(*(pts[idx] - g.pos[node]))) < min_stub or ring_pts.size and \
                    np.min(np.hypot(*(ring_pts - pts[idx]).T)) < near_ring:
                continue   # too short, or a dead end right next to a ring road: drop the road
            stub = g.add_node(pts[idx])
            node_free.append(True)
            g.add_edge(node, stub, E.width_m, E.road_class, modified=True)
    for n in range(len(g.pos)):
        if g.node_alive[n] and not node_free[n]:
            g.kill_node(n)
    for ring_id, nodes in attach.items():
        _close_ring(g, _owned_ring(rings, ring_id), ring_id, sorted(set(nodes)), owner, join)


def _owned_ring(rings: list[Ring | None], ring_id: int) -> Ring:
    """The ring road of owner-raster id ``ring_id + 1`` (only features with a ring own pixels)."""
    ring = rings[ring_id]
    assert ring is not None
    return ring


def _meets_ring_squarely(ring: Ring, start: np.ndarray, hit: np.ndarray,
                         min_angle_deg: float = 40.0) -> bool:
    """True if a road from ``start`` reaching the ring at ``hit`` is not grazing along it."""
    k = int(np.argmin(np.hypot(*(ring.poly - hit).T)))
    tangent = ring.poly[(k + 1) % len(ring.poly)] - ring.poly[k - 1]
    d = hit - start
    norm = float(np.hypot(*tangent) * np.hypot(*d))
    if norm < 1e-9:
        return True
    sin = abs(float(tangent[0] * d[1] - tangent[1] * d[0])) / norm
    return sin >= math.sin(math.radians(min_angle_deg))


def _close_ring(g: RoadGraph, ring: Ring, ring_id: int, nodes: list[int], owner: np.ndarray,
                join: float) -> None:
    """Add the ring road: its own vertices plus the attachment nodes, chained by angle."""
    att = np.array([g.pos[n] for n in nodes]) if nodes else np.zeros((0, 2))
    ids = list(nodes)
    for p in ring.poly:
        if att.size and np.min(np.hypot(*(att - p).T)) < join:
            continue
        ids.append(g.add_node(p))
    ang = [math.atan2(*(g.pos[n] - ring.centre)[::-1]) for n in ids]
    order = [ids[i] for i in np.argsort(ang, kind="stable")]
    for i, n in enumerate(order):
        m = order[(i + 1) % len(order)]
        pa, pb = g.pos[n], g.pos[m]
        t = np.linspace(0.0, 1.0, max(4, int(np.hypot(*(pb - pa)) / 2.0)))[:, None]
        own = _sample(owner, pa + t * (pb - pa))
        if np.any((own != 0) & (own != ring_id + 1)):
            continue
        g.add_edge(n, m, ring.width_m, RoadClass.STREET, modified=True)
    for n in ids:
        if g.node_alive[n] and g.degree(n) == 0:
            g.kill_node(n)


def _present_kinds(g: RoadGraph, W: int, H: int, margin: float) -> set[JunctionKind]:
    out = set()
    for n in range(len(g.pos)):
        if g.node_alive[n] and _in_map(g.pos[n], W, H, margin):
            k = g.kind(n)
            if k is not None:
                out.add(k)
    return out


def _ensure_kinds(g: RoadGraph, cfg: CityConfig, rng: np.random.Generator, s_px: float,
                  blocked: np.ndarray) -> None:
    """Make sure every junction kind occurs inside the map (small maps can miss some by chance)."""
    W, H = cfg.width_px, cfg.height_px
    margin = min(0.5 * s_px, 0.2 * min(W, H))
    for kind in (JunctionKind.TEE, JunctionKind.CORNER, JunctionKind.WYE, JunctionKind.BEND):
        if kind in _present_kinds(g, W, H, margin):
            continue
        nodes = [n for n in rng.permutation(len(g.pos)) if g.node_alive[n]
                 and _in_map(g.pos[n], W, H, margin) and g.degree(n) >= 3]
        done = False
        for n in nodes:
            n = int(n)
            if kind is JunctionKind.TEE and g.degree(n) == 4:
                for e in g.adj[n]:
                    if (g.edges[e].road_class is RoadClass.STREET
                            and g.degree(g.other(e, n)) >= 3):
                        g.kill_edge(e)
                        done = True
                        break
            elif kind is JunctionKind.CORNER and g.degree(n) in (3, 4):
                arms = sorted((g.arm_angle(e, n), e) for e in g.adj[n])
                # keep two arms roughly perpendicular, remove the rest
                for k in range(len(arms)):
                    (a1, e1), (a2, e2) = arms[k], arms[(k + 1) % len(arms)]
                    gap = (a2 - a1) % (2 * math.pi)
                    rest = [e for _, e in arms if e not in (e1, e2)]
                    if (math.radians(70) <= gap <= math.radians(110)
                            and all(g.edges[e].road_class is not RoadClass.AVENUE
                                    and g.degree(g.other(e, n)) >= 3 for e in rest)):
                        for e in rest:
                            g.kill_edge(e)
                        done = True
                        break
            elif kind is JunctionKind.WYE:
                done = _corner_diagonal(g, n, rng, cfg, s_px, blocked)
            elif kind is JunctionKind.BEND:
                for e in list(g.adj[n]):
                    other = g.other(e, n)
                    if (_eligible_street(g, e, 0.6 * s_px) and _in_map(g.pos[other], W, H, margin)
                            and _bend(g, e, rng, blocked)):
                        done = True
                        break
            if done:
                break
        if not done:
            log.debug("could not add a %s junction", kind.value)


def graph_junctions(g: RoadGraph, W: int, H: int) -> tuple[Junction, ...]:
    out = []
    for n in range(len(g.pos)):
        if not g.node_alive[n] or not _in_map(g.pos[n], W, H):
            continue
        kind = g.kind(n)
        if kind is not None:
            p = g.pos[n]
            out.append(Junction(u_px=round(float(p[0]), 3), v_px=round(float(p[1]), 3),
                                arms=g.degree(n), kind=kind))
    return tuple(out)
