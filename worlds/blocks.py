"""Blocks and buildings: the free ground between roads and features, filled by block kind.

:func:`layout_blocks` labels the connected pieces of free ground and fills each by its kind:
perimeter blocks with courtyards, detached houses, a large flat roof, industrial halls with
identical roofs (uniform-roof districts), parking lots, small parks, trees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, IntEnum

import cv2
import numpy as np

from worlds.city_config import CityConfig
from worlds.drawing import fill_convex, rect, stroke
from worlds.features import Feature, FeatureKind
from worlds.materials import FLAT_TONES, FLAT_WEIGHTS, GABLE_TONES, GABLE_WEIGHTS, UNIFORM_TONES, Material


class BlockKind(IntEnum):
    """How a block is filled (see :func:`layout_blocks`)."""

    YARD = 0
    PERIMETER = 1
    DETACHED = 2
    BIG = 3
    PARK = 4
    PARKING = 5
    INDUSTRIAL = 6


class BuildingKind(str, Enum):
    """What a building is; it decides its height range (:data:`HEIGHT_RANGE_M`) and its walls."""

    HOUSE = "house"               # detached house, garden
    OUTBUILDING = "outbuilding"   # garage, shed, workshop in a courtyard
    PERIMETER = "perimeter"       # terraced building of a perimeter block along the street
    TOWER = "tower"               # office or residential tower (a few flat-roofed buildings)
    LARGE = "large_flat"          # large flat roof: shopping centre, school, office block
    BOX = "uniform_box"           # large box with a uniform roof: supermarket, depot
    HALL = "hall"                 # industrial hall of a uniform-roof district


#: Height (metres above the ground, to the ridge for pitched roofs) per building kind: uniform in
#: [low, high]. Basis: storeys of ~3 m (residential 2.7-3.0 m floor to floor, commercial ~3.5-4 m;
#: Neufert, Architects' Data, 4th ed., ch. "Dimensions"); detached houses 2-3 storeys + roof,
#: Central-European perimeter blocks 4-7 storeys (Munich/Berlin Gruenderzeit blocks: eaves at
#: 15-22 m, ridge up to 24 m), towers 8-13 storeys, large flat-roofed buildings 3-5 storeys, single-
#: storey commercial boxes and industrial halls with 6-10 m clear height.
HEIGHT_RANGE_M: dict[BuildingKind, tuple[float, float]] = {
    BuildingKind.HOUSE: (6.0, 12.0),
    BuildingKind.OUTBUILDING: (3.0, 6.0),
    BuildingKind.PERIMETER: (12.0, 24.0),
    BuildingKind.TOWER: (24.0, 40.0),
    BuildingKind.LARGE: (10.0, 20.0),
    BuildingKind.BOX: (8.0, 14.0),
    BuildingKind.HALL: (7.0, 11.0),
}
#: Share of the flat-roofed large buildings and of the flat-roofed perimeter buildings that are
#: towers instead ("a few": about one tower per 4 ha of city on the default map).
TOWER_SHARE_LARGE = 0.35
TOWER_SHARE_PERIMETER = 0.06


class RoofStyle(IntEnum):
    """Roof shapes, as rendered."""

    FLAT = 1      # textured: parapet, HVAC boxes
    GABLE = 2     # two facets and a ridge
    HIP = 3       # four facets
    UNIFORM = 4   # one flat tone, no details


@dataclass
class Building:
    """One building: footprint, kind, height, roof style and tone, roof boxes (continuous px).

    ``height_m`` is the top of the building above the ground (the ridge of a pitched roof);
    ``roof_rise_m`` is the ridge above the eaves (0 for flat roofs), set by
    :func:`worlds.surface.finish_buildings` with the wall colour ``facade``.
    """

    corners: np.ndarray         # (4, 2) continuous px; corners[0] -> corners[1] is the long side
    height_m: float
    style: RoofStyle
    tone: tuple[float, ...]
    hvac: np.ndarray            # (k, 4, 2) roof boxes
    hvac_height_m: float = 2.0
    kind: BuildingKind = BuildingKind.PERIMETER
    roof_rise_m: float = 0.0
    facade: tuple[float, float, float] = (150.0, 150.0, 150.0)


class Block:
    """One connected piece of free ground between roads and features."""

    def __init__(self, mask: np.ndarray, x0: int, y0: int, setback_px: float) -> None:
        self.mask = mask
        self.x0, self.y0 = x0, y0
        padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        dist = cv2.distanceTransform(padded, cv2.DIST_L2, 3)[1:-1, 1:-1]
        self.inner = (dist > setback_px).astype(np.uint8)
        self.occ = np.zeros_like(mask)

    def try_place(self, corners: np.ndarray, max_bad: float = 0.04,
                  claim: np.ndarray | None = None) -> bool:
        """Claim a convex polygon (local coords) if it lies inside the block and is free.

        ``claim`` (a larger polygon around ``corners``) is marked occupied instead, to keep gaps.
        """
        h, w = self.mask.shape
        lo = np.floor(corners.min(axis=0)).astype(int) - 1
        hi = np.ceil(corners.max(axis=0)).astype(int) + 2
        if lo[0] < 0 or lo[1] < 0 or hi[0] > w or hi[1] > h:
            return False
        sub = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), dtype=np.uint8)
        fill_convex(sub, corners, 1, int(lo[0]), int(lo[1]))
        area = int(np.count_nonzero(sub))
        if area < 4:
            return False
        win = (slice(lo[1], hi[1]), slice(lo[0], hi[0]))
        bad = np.count_nonzero(sub & ((1 - self.inner[win]) | self.occ[win]))
        if bad > max_bad * area:
            return False
        if claim is None:
            self.occ[win] |= sub
        else:
            fill_convex(self.occ, claim, 1)
        return True

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float] | None:
        """Centre, long axis, short axis and extents of the minimum-area rectangle of the block."""
        cnts, _ = cv2.findContours(self.inner, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not cnts or sum(cv2.contourArea(c) for c in cnts) < 20:
            return None
        pts = np.concatenate(cnts)
        (cx, cy), (w, h), ang = cv2.minAreaRect(pts)
        box = cv2.boxPoints(((cx, cy), (w, h), ang))
        e1, e2 = box[1] - box[0], box[2] - box[1]
        l1, l2 = float(np.hypot(*e1)), float(np.hypot(*e2))
        if l1 < 1.0 or l2 < 1.0:
            return None
        a, b = e1 / l1, e2 / l2
        if l1 < l2:
            a, b, l1, l2 = b, a, l2, l1
        return np.array([cx + 0.5, cy + 0.5]), a, b, l1 + 1.0, l2 + 1.0


class Layout:
    """Block-filling rules; buildings are kept in global continuous pixel coordinates."""

    def __init__(self, cfg: CityConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.rng = rng
        self.ppm = 1.0 / cfg.m_per_px
        self.buildings: list[Building] = []
        self.spots: list[np.ndarray] = []   # parking stalls: (u, v, dir_u, dir_v)
        self.crowns: list[tuple[float, float, float]] = []   # garden trees: (u, v, radius) px

    def m(self, metres: float) -> float:
        return metres * self.ppm

    def _tone(self, tones, weights) -> tuple[float, ...]:
        base = np.array(tones[int(self.rng.choice(len(tones), p=np.array(weights) / sum(weights)))],
                        dtype=float)
        return tuple(float(x) for x in np.clip(base * self.rng.uniform(0.9, 1.1), 0, 255))

    def height(self, kind: BuildingKind) -> float:
        return float(self.rng.uniform(*HEIGHT_RANGE_M[kind]))

    def add(self, blk: Block, corners: np.ndarray, style: RoofStyle, kind: BuildingKind,
            tone: tuple[float, ...] | None = None, height_m: float | None = None) -> None:
        rng = self.rng
        if height_m is None:
            height_m = self.height(kind)
        if tone is None:
            tone = self._tone(GABLE_TONES, GABLE_WEIGHTS) if style in (RoofStyle.GABLE, RoofStyle.HIP) \
                else self._tone(FLAT_TONES, FLAT_WEIGHTS)
        glob = corners + np.array([blk.x0, blk.y0], dtype=float)
        hvac = np.zeros((0, 4, 2))
        if style is RoofStyle.FLAT:
            a = glob[1] - glob[0]
            b = glob[3] - glob[0]
            la, lb = float(np.hypot(*a)), float(np.hypot(*b))
            a, b = a / la, b / lb
            area_m2 = la * lb / self.ppm ** 2
            k = min(12, 1 + int(rng.poisson(area_m2 / 150.0)))
            boxes = []
            inset = self.m(1.5)
            for _ in range(k):
                sa, sb = self.m(rng.uniform(1.5, 4.0)), self.m(rng.uniform(1.5, 3.0))
                if la - 2 * inset - sa <= 0 or lb - 2 * inset - sb <= 0:
                    break
                ta = rng.uniform(inset, la - inset - sa)
                tb = rng.uniform(inset, lb - inset - sb)
                c = glob[0] + a * (ta + sa / 2) + b * (tb + sb / 2)
                boxes.append(rect(c, a, b, sa, sb))
            if boxes:
                hvac = np.array(boxes)
        self.buildings.append(Building(glob, float(height_m), style, tone, hvac,
                                        float(rng.uniform(1.2, 2.5)), kind))

    # -- block kinds --------------------------------------------------------------------------

    def perimeter(self, blk: Block) -> None:
        rng = self.rng
        cnts, _ = cv2.findContours(blk.inner, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        depth = self.m(rng.uniform(10.0, 16.0))
        gable_share = rng.uniform(0.2, 0.7)
        for cnt in sorted(cnts, key=lambda c: -cv2.contourArea(c)):
            if cv2.contourArea(cnt) < self.m(12.0) ** 2:
                continue
            poly = cv2.approxPolyDP(cnt, self.m(1.5), True)[:, 0, :].astype(float) + 0.5
            for i in range(len(poly)):
                p0, p1 = poly[i], poly[(i + 1) % len(poly)]
                e = p1 - p0
                length = float(np.hypot(*e))
                if length < self.m(8.0):
                    continue
                e /= length
                nrm = np.array([-e[1], e[0]])
                mid = 0.5 * (p0 + p1)
                if not _inside(blk.inner, mid + nrm * self.m(3.0)):
                    nrm = -nrm
                    if not _inside(blk.inner, mid + nrm * self.m(3.0)):
                        continue
                front = p0 + nrm * self.m(1.0)
                t = rng.uniform(0.0, self.m(2.0))
                while t < length - self.m(6.0):
                    f = min(self.m(rng.uniform(9.0, 26.0)), length - t)
                    if f < self.m(6.0):
                        break
                    c = [front + e * t, front + e * (t + f), front + e * (t + f) + nrm * depth,
                         front + e * t + nrm * depth]
                    corners = np.array(c)
                    if blk.try_place(corners):
                        style = RoofStyle.GABLE if rng.random() < gable_share else RoofStyle.FLAT
                        corners = _long_first(corners)
                        self.add(blk, corners, style, BuildingKind.PERIMETER)
                        t += f + (0.0 if rng.random() < 0.6 else self.m(rng.uniform(1.0, 4.0)))
                    else:
                        t += self.m(2.0)
        # big courtyards get outbuildings; very big blocks (next to features) get houses inside
        free_m2 = np.count_nonzero(blk.inner & (1 - blk.occ)) / self.ppm ** 2
        if free_m2 > 6000.0:
            self.detached(blk)
        elif free_m2 > 1500.0 and rng.random() < 0.5:
            self.detached(blk, (6.0, 12.0), (5.0, 9.0), (22.0, 26.0), RoofStyle.FLAT, BuildingKind.OUTBUILDING)

    def detached(self, blk: Block, size_a=(8.0, 13.0), size_b=(7.0, 11.0), pitch=(16.0, 22.0),
                 style: RoofStyle | None = None, kind: BuildingKind = BuildingKind.HOUSE) -> None:
        rng = self.rng
        fr = blk.frame()
        if fr is None:
            return
        c, a, b, la, lb = fr
        pa, pb = self.m(rng.uniform(*pitch)), self.m(rng.uniform(*pitch))
        na, nb = max(1, int(la // pa)), max(1, int(lb // pb))
        for ia in range(na):
            for ib in range(nb):
                ta = (ia - (na - 1) / 2) * pa + self.m(rng.normal(0, 0.8))
                tb = (ib - (nb - 1) / 2) * pb + self.m(rng.normal(0, 0.8))
                sa, sb = self.m(rng.uniform(*size_a)), self.m(rng.uniform(*size_b))
                corners = rect(c + a * ta + b * tb, a, b, sa, sb)
                if blk.try_place(corners):
                    st = style if style is not None else (
                        RoofStyle.GABLE if rng.random() < 0.5 else
                        (RoofStyle.HIP if rng.random() < 0.6 else RoofStyle.FLAT))
                    self.add(blk, corners, st, kind)

    def big(self, blk: Block, uniform_tone: tuple[float, ...] | None = None) -> None:
        """One large building (flat roof with HVAC, or a uniform roof), houses around it."""
        rng = self.rng
        fr = blk.frame()
        if fr is None:
            return
        c, a, b, la, lb = fr
        fa, fb = rng.uniform(0.55, 0.85), rng.uniform(0.55, 0.85)
        uniform = rng.random() < 0.4 or uniform_tone is not None
        for _ in range(5):
            corners = rect(c, a, b, la * fa, lb * fb)
            if blk.try_place(corners):
                if uniform:
                    tone = uniform_tone or self._tone(UNIFORM_TONES, (1, 1, 1))
                    self.add(blk, corners, RoofStyle.UNIFORM, BuildingKind.BOX, tone)
                else:
                    self.add(blk, corners, RoofStyle.FLAT, BuildingKind.LARGE)
                break
            fa *= 0.85
            fb *= 0.85
        self.detached(blk, (8.0, 14.0), (7.0, 12.0), (18.0, 24.0), None, BuildingKind.HOUSE)

    def halls(self, blk: Block, spec: tuple[float, float, float, tuple[float, ...]]) -> bool:
        """Pack identical halls row by row (greedy scan in the block's rectangle frame)."""
        length, width, height, tone = spec
        fr = blk.frame()
        if fr is None:
            return False
        c, a0, b0, la0, lb0 = fr
        for a, b, la, lb in ((a0, b0, la0, lb0), (b0, a0, lb0, la0)):
            if self._pack_halls(blk, c, a, b, la, lb, length, width, height, tone):
                return True
        return False

    def _pack_halls(self, blk: Block, c, a, b, la: float, lb: float, length: float, width: float,
                    height: float, tone: tuple[float, ...]) -> bool:
        gap_a, gap_b = self.m(10.0), self.m(12.0)
        ha, hb = self.m(length), self.m(width)
        step = self.m(2.5)
        count = 0
        tb = -lb / 2 + hb / 2
        while tb <= lb / 2 - hb / 2 + 1e-9:
            placed = False
            ta = -la / 2 + ha / 2
            while ta <= la / 2 - ha / 2 + 1e-9:
                centre = c + a * ta + b * tb
                outer = rect(centre, a, b, ha + gap_a, hb + gap_b)
                hall = rect(centre, a, b, ha, hb)
                if (all(_inside(blk.inner, q) for q in hall) and not _inside(blk.occ, centre)
                        and blk.try_place(hall, max_bad=0.01, claim=outer)):
                    self.add(blk, hall, RoofStyle.UNIFORM, BuildingKind.HALL, tone, height)
                    placed = True
                    count += 1
                    ta += ha + gap_a
                else:
                    ta += step
            tb += hb + gap_b if placed else step
        return count > 0

    def parking(self, blk: Block, material_win: np.ndarray) -> None:
        fr = blk.frame()
        area = blk.inner.astype(bool)
        material_win[area] = Material.PARKING
        if fr is None:
            return
        c, a, b, la, lb = fr
        stall_w, stall_d, aisle = self.m(2.5), self.m(5.0), self.m(6.5)
        period = 2 * stall_d + aisle
        lines = np.zeros_like(blk.mask)
        segs = []
        n_rows = int(lb // period) + 1
        for r in range(n_rows):
            row0 = -lb / 2 + self.m(1.0) + r * period
            for side, rb in ((0, row0), (1, row0 + stall_d)):
                for k in range(int(la // stall_w) + 1):
                    ta = -la / 2 + k * stall_w
                    p = c + a * ta + b * rb
                    segs.append(np.array([p, p + b * stall_d]))
                    centre = c + a * (ta + stall_w / 2) + b * (rb + stall_d / 2)
                    corners = rect(centre, a, b, stall_w * 0.9, stall_d * 0.9)
                    if all(_inside(blk.inner, q) for q in corners):
                        direction = b if side == 0 else -b
                        self.spots.append(np.array([centre[0] + blk.x0, centre[1] + blk.y0,
                                                    direction[0], direction[1]]))
        stroke(lines, segs, 1, 1)
        material_win[(lines > 0) & area] = Material.PARKING_LINE


def _inside(mask: np.ndarray, p: np.ndarray) -> bool:
    u, v = int(math.floor(p[0])), int(math.floor(p[1]))
    return 0 <= v < mask.shape[0] and 0 <= u < mask.shape[1] and bool(mask[v, u])


def _long_first(corners: np.ndarray) -> np.ndarray:
    if np.hypot(*(corners[1] - corners[0])) < np.hypot(*(corners[3] - corners[0])):
        return corners[[1, 2, 3, 0]]
    return corners


def _trees(material_win: np.ndarray, region: np.ndarray, rng: np.random.Generator, ppm: float,
           per_m2: float, x0: int, y0: int, crowns: list[tuple[float, float, float]]) -> None:
    """Garden trees: crowns (FOREST) on ``region``; each crown's (u, v, radius) in continuous global
    px is appended to ``crowns`` (the surface model gives it a dome, ``worlds/surface.py``)."""
    ys, xs = np.nonzero(region)
    n = int(rng.poisson(len(ys) / ppm ** 2 * per_m2))
    if n == 0 or len(ys) == 0:
        return
    canopy = np.zeros_like(region, dtype=np.uint8)
    idx = rng.integers(len(ys), size=n)
    for i in idx:
        r = rng.uniform(2.0, 4.5) * ppm
        rad = max(1, int(r))
        cv2.circle(canopy, (int(xs[i]), int(ys[i])), rad, 1, -1)
        crowns.append((float(xs[i]) + x0 + 0.5, float(ys[i]) + y0 + 0.5, float(rad) + 0.5))
    material_win[(canopy > 0) & region] = Material.FOREST


def layout_blocks(material: np.ndarray, features: list[Feature], cfg: CityConfig,
                   rng: np.random.Generator) -> Layout:
    mpp = cfg.m_per_px
    ppm = 1.0 / mpp
    lay = Layout(cfg, rng)
    free = (material == Material.GROUND).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(free, connectivity=4)
    del free
    area_px = stats[:, cv2.CC_STAT_AREA]
    ids = [k for k in range(1, n) if area_px[k] * mpp ** 2 >= 40.0]
    districts = [f for f in features if f.kind is FeatureKind.DISTRICT]
    hall_specs = []
    for _ in districts:
        hall_specs.append((cfg.hall_length_m * rng.uniform(0.9, 1.1),
                           cfg.hall_width_m * rng.uniform(0.9, 1.1), rng.uniform(*HEIGHT_RANGE_M[BuildingKind.HALL]),
                           tuple(float(x) for x in UNIFORM_TONES[int(rng.integers(len(UNIFORM_TONES)))])))

    # district blocks: nearest to the district centre first, until they cover ~60 % of its disc
    member: dict[int, int] = {}
    if districts and ids:
        ids_arr = np.array(ids)
        for i, f in enumerate(districts):
            dist = np.hypot(*(cents[ids_arr] + 0.5 - f.centre).T)
            want = 0.6 * math.pi * f.radius_px ** 2
            got = 0.0
            for k in ids_arr[np.argsort(dist, kind="stable")]:
                if got >= want or np.hypot(*(cents[k] + 0.5 - f.centre)) > 1.5 * f.radius_px:
                    break
                if int(k) in member or area_px[k] * mpp ** 2 < 1500.0:
                    continue
                member[int(k)] = i
                got += float(area_px[k])

    def district_of(k: int) -> int:
        return member.get(k, -1)

    kinds: dict[int, BlockKind] = {}
    budget = cfg.parking_share * cfg.area_m2
    for k in rng.permutation(ids):
        a = area_px[k] * mpp ** 2
        if 700.0 <= a <= min(12000.0, 1.5 * budget) and district_of(int(k)) < 0:
            kinds[int(k)] = BlockKind.PARKING
            budget -= 0.8 * a
    kind_list = (BlockKind.PERIMETER, BlockKind.DETACHED, BlockKind.BIG, BlockKind.PARK)
    kind_p = np.array([0.55, 0.25, 0.14, 0.06])
    setback = 1.5 * ppm
    for k in ids:
        x, y, w, h = (int(v) for v in stats[k, :4])
        a_m2 = area_px[k] * mpp ** 2
        d = district_of(k)
        if k in kinds:
            kind = kinds[k]
        elif d >= 0:
            kind = BlockKind.INDUSTRIAL
        elif a_m2 < 350.0:
            kind = BlockKind.YARD
        else:
            kind = kind_list[int(rng.choice(len(kind_list), p=kind_p))]
            if kind is BlockKind.PARK and a_m2 > 5000.0:   # big open areas are the features' job
                kind = BlockKind.PERIMETER
        mask = (labels[y:y + h, x:x + w] == k).astype(np.uint8)
        blk = Block(mask, x, y, setback)
        win = material[y:y + h, x:x + w]
        first = len(lay.buildings)
        grass_yard = False
        tree_density = 0.0
        if kind is BlockKind.PERIMETER:
            lay.perimeter(blk)
            grass_yard = rng.random() < cfg.courtyard_grass_share
            tree_density = 1.0 / 250.0 if grass_yard else 1.0 / 900.0
        elif kind is BlockKind.DETACHED:
            lay.detached(blk)
            grass_yard = rng.random() < 0.35
            tree_density = 1.0 / 250.0
        elif kind is BlockKind.BIG:
            lay.big(blk)
            tree_density = 1.0 / 1500.0
        elif kind is BlockKind.INDUSTRIAL:
            if not lay.halls(blk, hall_specs[d]):
                lay.big(blk, uniform_tone=hall_specs[d][3])
        elif kind is BlockKind.PARKING:
            lay.parking(blk, win)
        elif kind is BlockKind.PARK:
            grass_yard = True
            tree_density = 1.0 / 120.0
        else:
            grass_yard = rng.random() < 0.5
        block_px = mask.astype(bool)
        yard = block_px & (win == Material.GROUND)
        if grass_yard:
            win[yard] = Material.GRASS
        if tree_density > 0:
            _trees(win, yard & (blk.occ == 0), rng, ppm, tree_density, x, y, lay.crowns)
        for bld in lay.buildings[first:]:
            mat = Material.ROOF_UNIFORM if bld.style is RoofStyle.UNIFORM else Material.ROOF_TEXTURED
            fill_convex(material, bld.corners, int(mat))
    return lay
