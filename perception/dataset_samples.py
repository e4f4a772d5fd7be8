"""Where the base crops of a dataset are taken and how they are labelled (paper section 5.2).

Junction crops, bad-area crops, uniformly random positions (matchability labelling), equal class
quotas and the allocation of augmented copies; see ``perception.dataset`` for the whole procedure.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from enum import Enum

import cv2
import numpy as np

from perception.capture import CaptureScene
from perception.cnn_spec import MatchClass
from perception.dataset_arms import DEFAULT_ARM_COUNT, ArmCountConfig, ArmVerdict, arm_check
from perception.dataset_config import ArmLabels, DatasetConfig
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)


MATCHABLE_SHARE = 0.5
"""Matchability labelling: BAD when the share of true matches is below this."""


BAD_GRID_STRIDE_PX = 8


class CropSource(str, Enum):
    """Why a base crop was taken."""

    JUNCTION = "junction"
    BAD_AREA = "bad_area"
    RANDOM = "random"       # uniformly random position (matchability labelling only)


@dataclass
class BaseSample:
    """One base crop position (before augmentation)."""

    world_seed: int
    source: CropSource
    u_px: float
    v_px: float
    label: MatchClass
    arms: int = 0
    kind: str = ""
    cover: str = ""
    matchability: float = float("nan")
    visible_arms: int | None = None      # junction crops: arms the crop shows (perception.dataset_arms)
    arm_verdict: str = ""                # junction crops: ArmVerdict value at the crop centre
    anchor_uv_px: tuple[float, float] | None = None   # junction crops: the junction (before jitter)
    base_id: str = ""
    group: str = ""


@dataclass
class WorldData:
    """A training world: its capture scene (perception.capture), junctions and land cover."""

    seed: int
    scene: CaptureScene
    junctions: tuple
    landcover: np.ndarray

    def road_masks(self) -> tuple[np.ndarray, np.ndarray]:
        """(carriageway, squares + parking lots) uint8 masks of the land cover (cached)."""
        cached = getattr(self, "_masks", None)
        if cached is None:
            from worlds.landcover import LandCover
            road = (self.landcover == int(LandCover.ROAD)).astype(np.uint8)
            paved = np.isin(self.landcover, [int(LandCover.SQUARE), int(LandCover.PARKING)]).astype(np.uint8)
            cached = (road, paved)
            self._masks = cached
        return cached

    def check_arms(self, s: BaseSample, crop_px: int, cfg: ArmCountConfig = DEFAULT_ARM_COUNT) -> ArmVerdict:
        """Set ``s.visible_arms`` and ``s.arm_verdict`` for a junction crop centred at (s.u_px, s.v_px)."""
        road, paved = self.road_masks()
        verdict, seen = arm_check(s.arms, road, paved, s.u_px, s.v_px, crop_px, self.m_per_px, cfg)
        s.visible_arms, s.arm_verdict = seen, verdict.value
        return verdict

    @property
    def ortho_gray(self) -> np.ndarray:
        return self.scene.camera_gray

    @property
    def ref_gray(self) -> np.ndarray:
        return self.scene.reference_gray

    @property
    def m_per_px(self) -> float:
        return self.scene.m_per_px


def arm_class(arms: int) -> MatchClass | None:
    """Junction arm count -> class (>= 4 -> FOUR_ARM, 3 -> THREE_ARM, 2 -> TWO_ARM, else None)."""
    if arms >= 4:
        return MatchClass.FOUR_ARM
    if arms == 3:
        return MatchClass.THREE_ARM
    if arms == 2:
        return MatchClass.TWO_ARM
    return None


def generate_world_data(seed: int, cfg: DatasetConfig) -> WorldData:
    from worlds.generator import CityConfig, generate_world
    world = generate_world(CityConfig(seed=seed, width_px=cfg.world_width_px, height_px=cfg.world_height_px,
                                      m_per_px=cfg.m_per_px))
    if world.landcover is None or world.junctions is None:
        raise UserError(f"world seed {seed}: generated world has no land cover/junction ground truth")
    return WorldData(seed=seed, scene=CaptureScene.from_world(world, cfg.capture),
                     junctions=tuple(world.junctions), landcover=world.landcover)


def _inside(u: float, v: float, half: float, w: int, h: int) -> bool:
    return half <= u <= w - half and half <= v <= h - half


def _junction_candidates(wd: WorldData, crop_px: int, jitter: float, isolated: bool = False) -> list[BaseSample]:
    """Junctions whose crop (+ jitter) fits in the world; with ``isolated``, only those with no other
    junction inside their crop square (grown by the jitter)."""
    h, w = wd.landcover.shape
    out = []
    uv = np.array([[j.u_px, j.v_px] for j in wd.junctions], dtype=float).reshape(-1, 2)
    for k, j in enumerate(wd.junctions):
        cls = arm_class(int(j.arms))
        if cls is None or not _inside(j.u_px, j.v_px, crop_px / 2.0 + jitter, w, h):
            continue
        if isolated:
            cheb = np.max(np.abs(uv - uv[k]), axis=1)
            cheb[k] = np.inf
            if np.any(cheb <= crop_px / 2.0 + jitter):
                continue
        kind = j.kind.value if isinstance(j.kind, Enum) else str(j.kind)
        out.append(BaseSample(world_seed=wd.seed, source=CropSource.JUNCTION, u_px=float(j.u_px),
                              v_px=float(j.v_px), label=cls, arms=int(j.arms), kind=kind))
    return out


def _bad_candidates(wd: WorldData, crop_px: int, min_share: float) -> list[BaseSample]:
    """Grid positions whose footprint is dominated by bad covers and has no junction near the centre."""
    from worlds.landcover import BAD_MATCHING_COVERS
    lc = wd.landcover
    h, w = lc.shape
    half = crop_px // 2
    centres_u = np.arange(half, w - half, BAD_GRID_STRIDE_PX)
    centres_v = np.arange(half, h - half, BAD_GRID_STRIDE_PX)
    if len(centres_u) == 0 or len(centres_v) == 0:
        return []
    area = float(crop_px * crop_px)
    x0 = centres_u - half
    y0 = centres_v - half

    def box_share(mask: np.ndarray) -> np.ndarray:
        ii = cv2.integral(mask.astype(np.uint8))
        return (ii[np.ix_(y0 + crop_px, x0 + crop_px)] - ii[np.ix_(y0, x0 + crop_px)]
                - ii[np.ix_(y0 + crop_px, x0)] + ii[np.ix_(y0, x0)]) / area

    covers = sorted(BAD_MATCHING_COVERS, key=int)
    per_cover = np.stack([box_share(lc == int(c)) for c in covers])
    total = per_cover.sum(axis=0)
    dominant = np.argmax(per_cover, axis=0)
    ok = total >= min_share
    if wd.junctions:
        ju = np.array([j.u_px for j in wd.junctions])
        jv = np.array([j.v_px for j in wd.junctions])
        cu = centres_u[None, :, None] + 0.5
        cv = centres_v[:, None, None] + 0.5
        near = (np.abs(cu - ju[None, None, :]) < crop_px / 4.0) & (np.abs(cv - jv[None, None, :]) < crop_px / 4.0)
        ok &= ~near.any(axis=2)
    rows, cols = np.nonzero(ok)
    return [BaseSample(world_seed=wd.seed, source=CropSource.BAD_AREA, u_px=float(centres_u[c]) + 0.5,
                       v_px=float(centres_v[r]) + 0.5, label=MatchClass.BAD,
                       cover=covers[dominant[r, c]].name.lower()) for r, c in zip(rows, cols, strict=False)]


def _pick_bad(cands: list[BaseSample], quota: int, spacing: float, rng: np.random.Generator) -> list[BaseSample]:
    """Round-robin over dominant covers, greedy minimum spacing within a world."""
    by_cover: dict[str, list[BaseSample]] = {}
    for s in cands:
        by_cover.setdefault(s.cover, []).append(s)
    queues = {}
    for cover in sorted(by_cover):
        lst = by_cover[cover]
        queues[cover] = [lst[i] for i in rng.permutation(len(lst))]
    picked: list[BaseSample] = []
    taken: dict[int, list[tuple[float, float]]] = {}
    while len(picked) < quota and any(queues.values()):
        for cover in sorted(queues):
            q = queues[cover]
            while q:
                s = q.pop()
                near = taken.setdefault(s.world_seed, [])
                if all(abs(s.u_px - a) >= spacing or abs(s.v_px - b) >= spacing for a, b in near):
                    near.append((s.u_px, s.v_px))
                    picked.append(s)
                    break
            if len(picked) >= quota:
                break
    return picked


def _pick_junctions(cands: list[BaseSample], quota: int, max_per: int, jitter: float,
                    rng: np.random.Generator) -> list[BaseSample]:
    """``quota`` crops of one class: distinct junctions first, then repeats with new jitter."""
    if not cands:
        return []
    order = [cands[i] for i in rng.permutation(len(cands))]
    picked: list[BaseSample] = []
    for _rep in range(max_per):
        for s in order:
            if len(picked) >= quota:
                return picked
            du, dv = rng.uniform(-jitter, jitter, 2) if (jitter > 0) else (0.0, 0.0)
            picked.append(BaseSample(world_seed=s.world_seed, source=s.source, u_px=s.u_px + du,
                                     v_px=s.v_px + dv, label=s.label, arms=s.arms, kind=s.kind,
                                     anchor_uv_px=(s.u_px, s.v_px)))
    return picked


def select_base_samples(worlds: list[WorldData], cfg: DatasetConfig, crop_px: int,
                        rng: np.random.Generator, arm_stats: dict | None = None) -> list[BaseSample]:
    """Base crop positions with equal class quotas (deficits moved to the other classes).

    Intersection crops: every junction candidate's visible arms are checked at the junction
    (``WorldData.check_arms``); with ``cfg.arms`` VISIBLE only those that agree are kept. The
    verdict counts per graph class go to ``arm_stats`` (for the manifest); picked crops are checked
    again at their jittered centre (``BaseSample.visible_arms`` / ``arm_verdict``, in index.csv).
    """
    junctions = {c: [] for c in MatchClass if c is not MatchClass.BAD}
    bad: list[BaseSample] = []
    check = cfg.isolated_junctions_only()
    verdicts: dict[str, dict[str, int]] = {c.name: {} for c in junctions}
    by_seed = {wd.seed: wd for wd in worlds}
    for wd in worlds:
        for s in _junction_candidates(wd, crop_px, cfg.jitter_px(), cfg.isolated_junctions_only()):
            if check:
                v = wd.check_arms(s, crop_px).value
                verdicts[s.label.name][v] = verdicts[s.label.name].get(v, 0) + 1
                if cfg.arms is ArmLabels.VISIBLE and v != ArmVerdict.AGREE.value:
                    continue
            junctions[s.label].append(s)
        bad.extend(_bad_candidates(wd, crop_px, cfg.bad_min_share))
    if check and arm_stats is not None:
        n_all = sum(sum(d.values()) for d in verdicts.values())
        n_agree = sum(d.get(ArmVerdict.AGREE.value, 0) for d in verdicts.values())
        arm_stats.update({"candidates_by_graph_class": verdicts, "n_candidates": n_all,
                          "agree_share": n_agree / max(n_all, 1), "arm_count": asdict(DEFAULT_ARM_COUNT)})
        log.info("junction candidates by visible-arm verdict: %s (%.1f %% agree)", verdicts,
                 100.0 * n_agree / max(n_all, 1))
    avail = {c: len(v) * cfg.max_crops_per_junction for c, v in junctions.items()}
    avail[MatchClass.BAD] = len(bad)
    log.info("candidates: %s", {c.name: n for c, n in avail.items()})
    quotas = _share_quota(cfg.base_crops, avail)
    picked: list[BaseSample] = []
    picked += _pick_bad(bad, quotas[MatchClass.BAD], cfg.bad_min_spacing_px, rng)
    for c in (MatchClass.FOUR_ARM, MatchClass.THREE_ARM, MatchClass.TWO_ARM):
        picked += _pick_junctions(junctions[c], quotas[c], cfg.max_crops_per_junction, cfg.jitter_px(), rng)
    if check:
        for s in picked:
            if s.source is CropSource.JUNCTION:
                by_seed[s.world_seed].check_arms(s, crop_px)
    short = cfg.base_crops - len(picked)
    if short > 0:
        log.warning("only %d base crops available (asked %d): generate more worlds (--worlds)",
                    len(picked), cfg.base_crops)
    return picked


def assign_ids(samples: list[BaseSample], crop_px: int) -> None:
    """Base ids and split groups (spatial tiles of one crop side per world). A junction crop is
    grouped by its junction, not its jittered centre, so the up to ``max_crops_per_junction`` crops
    of one junction never straddle the training/validation split."""
    for i, s in enumerate(samples):
        s.base_id = f"w{s.world_seed}_{i:05d}"
        u, v = s.anchor_uv_px if s.anchor_uv_px is not None else (s.u_px, s.v_px)
        s.group = f"w{s.world_seed}_t{int(v // crop_px)}_{int(u // crop_px)}"


def random_positions(worlds: list[WorldData], n: int, crop_px: int, rng: np.random.Generator) -> list[BaseSample]:
    """``n`` uniformly random footprint centres spread evenly over the worlds (label set later)."""
    out: list[BaseSample] = []
    half = crop_px / 2.0
    for k, wd in enumerate(worlds):
        m = n // len(worlds) + (1 if k < n % len(worlds) else 0)
        h, w = wd.landcover.shape
        us = rng.uniform(half, w - half, m)
        vs = rng.uniform(half, h - half, m)
        out += [BaseSample(world_seed=wd.seed, source=CropSource.RANDOM, u_px=float(u), v_px=float(v),
                           label=MatchClass.BAD) for u, v in zip(us, vs, strict=False)]
    return out


def select_by_label(pool: list[BaseSample], total: int, rng: np.random.Generator) -> list[BaseSample]:
    """``total`` samples with equal label quotas (capped by availability), order kept."""
    by_label = {c: [i for i, s in enumerate(pool) if s.label == c] for c in MatchClass}
    quotas = _share_quota(total, {c: len(v) for c, v in by_label.items()})
    keep: list[int] = []
    for c, idx in by_label.items():
        if quotas[c]:
            keep += list(rng.choice(idx, size=quotas[c], replace=False))
    return [pool[i] for i in sorted(keep)]


def _share_quota(total: int, avail: dict[MatchClass, int]) -> dict[MatchClass, int]:
    """Equal shares, capped by availability; the remainder goes to classes with room left."""
    quotas = {c: 0 for c in MatchClass}
    left = total
    open_classes = [c for c in MatchClass if avail.get(c, 0) > 0]
    while left > 0 and open_classes:
        share = max(1, left // len(open_classes))
        for c in list(open_classes):
            give = min(share, avail[c] - quotas[c], left)
            quotas[c] += give
            left -= give
            if quotas[c] >= avail[c]:
                open_classes.remove(c)
            if left <= 0:
                break
    return quotas


def allocate_augmentation(labels: list[MatchClass], augment_to: int) -> np.ndarray:
    """Extra copies per class (water-filling: raise the smallest classes first), (n_classes,)."""
    counts = np.array([sum(1 for lab in labels if lab == c) for c in MatchClass], dtype=np.int64)
    extra = np.zeros(len(MatchClass), dtype=np.int64)
    left = augment_to - int(counts.sum())
    present = counts > 0
    while left > 0 and present.any():
        totals = counts + extra
        level = totals[present].min()
        idx = [i for i in np.flatnonzero(present) if totals[i] == level]
        for i in idx:
            if left <= 0:
                break
            extra[i] += 1
            left -= 1
    return extra


def relabel_by_matchability(samples: list[BaseSample], worlds: dict[int, WorldData], crop_px: int) -> None:
    for s in samples:
        if s.matchability < MATCHABLE_SHARE:
            s.label = MatchClass.BAD
        elif s.source is CropSource.JUNCTION:
            s.label = arm_class(s.arms) or MatchClass.TWO_ARM
        else:
            best, best_d = None, float("inf")
            for j in worlds[s.world_seed].junctions:
                du, dv = abs(j.u_px - s.u_px), abs(j.v_px - s.v_px)
                if max(du, dv) < crop_px / 2.0 and math.hypot(du, dv) < best_d and arm_class(int(j.arms)):
                    best, best_d = j, math.hypot(du, dv)
            s.label = arm_class(int(best.arms)) if best is not None else MatchClass.TWO_ARM
