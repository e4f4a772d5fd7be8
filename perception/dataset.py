"""Labelled dataset of good/bad matching areas built from generated worlds (paper section 5.2).

The paper cropped 1500 images from Google Maps (intersections and bad areas), converted them to
grayscale, resized them to 200 x 200 and augmented them to 3920. We do the same from generated
worlds, whose ground truth (road-graph junctions, land cover) replaces the manual labelling:

* base crops are camera footprints (``footprint_px``: 217 px at 0.53 m/px for 100 m altitude and
  a 60 degree field of view), north-up, taken from the ORTHOPHOTO (what the camera sees);
* junction crops are centred on a junction (+- ``junction_jitter_px``), class by arm count:
  >= 4 arms -> FOUR_ARM (stars count as four), 3 -> THREE_ARM (tee and wye), 2 -> TWO_ARM (corner
  and bend);
* bad crops are centred where covers in ``BAD_MATCHING_COVERS`` (water, forest, grass, squares,
  uniform roofs) fill at least ``bad_min_share`` of the footprint and no junction lies within a
  quarter footprint of the centre; they are drawn round-robin over the dominant cover type so that
  squares and roofs are not swamped by forest;
* class quotas are equal (base_crops / 4); a junction may give up to ``max_crops_per_junction``
  crops (different jitter) when a class is short; a remaining deficit goes to the other classes.

Labelling (``Labelling``):

* ``paper``: the class above;
* ``matchability``: labels from the simulated NCC success rate (``perception.matchability``, 8
  noisy captures per position matched against the REFERENCE map). Candidate positions are the
  paper's positions above plus ``matchability_extra_positions`` (2000) uniformly random positions;
  each is BAD if its matchability < 0.5, else the class of its own junction (junction positions)
  or of the nearest junction inside its footprint (other positions), TWO_ARM when there is none.
  ``base_crops`` are then drawn with equal label quotas, as for the paper labelling. Only P(BAD)
  is used downstream; the three good classes are kept so that both labellings train the same
  4-class network. The soft score is stored per image (``index.csv``: ``matchability``) and the
  candidate pool statistics in the manifest.

Augmentation (to ``augment_to`` images): every augmented copy is re-rendered from the world at the
base crop's centre (no border artefacts) with a random rotation, a mirror flip (p = 0.5), scale
jitter, then gamma, gain/offset, blur and noise; labels are kept (rotation, mirroring and
photometry do not change an arm count). Copies are allocated to even out the class counts
(water-filling), then round-robin over the base crops of each class.

On disk (``DIR``): ``images/<CLASS_NAME>/<id>.png`` (200 x 200 8-bit grey), ``index.csv`` (one row
per image: label, spatial group, world seed, centre, source, augmentation, matchability) and
``manifest.json`` (counts, seeds, crop size, recipe, labelling, version).

World seeds: training worlds are ``1 + 1000 * seed + i`` (i < n_worlds); ``EVAL_WORLD_SEEDS``
(9001, 9002) are reserved for the held-out evaluation and refused here.
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from perception.cnn import PAPER_INPUT_PX, Labelling, MatchClass
from perception.matchability import (MatchabilityConfig, footprint_px, matchability, to_gray,
                                     validate_windowed)
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

DATASET_VERSION = 1
MANIFEST_FILE = "manifest.json"
INDEX_FILE = "index.csv"
IMAGES_DIR = "images"
EVAL_WORLD_SEEDS: tuple[int, ...] = (9001, 9002)
"""World seeds reserved for held-out evaluation (``scenenav cnn compare``); never used for training."""
WORLD_SEEDS_PER_DATASET_SEED = 1000
MATCHABLE_SHARE = 0.5
"""Matchability labelling: BAD when the share of true matches is below this."""
BAD_GRID_STRIDE_PX = 8
INDEX_COLUMNS = ("file", "label", "label_name", "group", "world_seed", "source", "u_px", "v_px",
                 "arms", "kind", "cover", "base_id", "aug_id", "matchability")


class CropSource(str, Enum):
    """Why a base crop was taken."""

    JUNCTION = "junction"
    BAD_AREA = "bad_area"
    RANDOM = "random"       # uniformly random position (matchability labelling only)


@dataclass(frozen=True)
class AugmentRecipe:
    """Random transforms of one augmented copy (uniform ranges)."""

    rotation_deg: tuple[float, float] = (0.0, 360.0)
    flip_probability: float = 0.5
    scale: tuple[float, float] = (0.9, 1.1)
    log_gamma: tuple[float, float] = (-0.3, 0.3)
    gain: tuple[float, float] = (0.75, 1.25)
    offset: tuple[float, float] = (-0.08, 0.08)
    blur_sigma_px: tuple[float, float] = (0.0, 1.2)
    noise_sigma: tuple[float, float] = (0.0, 0.03)


@dataclass(frozen=True)
class DatasetConfig:
    """Everything that determines a dataset (stored in its manifest)."""

    n_worlds: int = 12
    seed: int = 0
    labelling: Labelling = Labelling.PAPER
    base_crops: int = 1500
    augment_to: int = 3920
    world_width_px: int = 2000
    world_height_px: int = 2000
    m_per_px: float = 0.53
    altitude_m: float = 100.0
    fov_deg: float = 60.0
    image_px: int = PAPER_INPUT_PX
    bad_min_share: float = 0.6
    junction_jitter_px: float = 40.0
    max_crops_per_junction: int = 3
    bad_min_spacing_px: int = 24
    validate_global_n: int = 16
    matchability_extra_positions: int = 2000
    augment: AugmentRecipe = field(default_factory=AugmentRecipe)
    matchability: MatchabilityConfig = field(default_factory=MatchabilityConfig)

    def world_seeds(self) -> tuple[int, ...]:
        return training_world_seeds(self.seed, self.n_worlds)


def training_world_seeds(seed: int, n_worlds: int) -> tuple[int, ...]:
    """World seeds used for a dataset built with ``--seed seed --worlds n_worlds``."""
    return tuple(1 + WORLD_SEEDS_PER_DATASET_SEED * seed + i for i in range(n_worlds))


def check_config(cfg: DatasetConfig) -> None:
    """One-line UserError for out-of-range settings."""
    if cfg.n_worlds < 1 or cfg.n_worlds >= WORLD_SEEDS_PER_DATASET_SEED:
        raise UserError(f"--worlds = {cfg.n_worlds}: expected an integer in [1, {WORLD_SEEDS_PER_DATASET_SEED - 1}]")
    if cfg.seed < 0:
        raise UserError(f"--seed = {cfg.seed}: expected an integer >= 0")
    clash = sorted(set(cfg.world_seeds()) & set(EVAL_WORLD_SEEDS))
    if clash:
        raise UserError(f"--seed {cfg.seed} --worlds {cfg.n_worlds}: world seed {clash[0]} is reserved for "
                        f"held-out evaluation (use another --seed)")
    if cfg.base_crops < len(MatchClass):
        raise UserError(f"--base-crops = {cfg.base_crops}: expected at least {len(MatchClass)}")
    if cfg.augment_to < cfg.base_crops:
        raise UserError(f"--augment-to = {cfg.augment_to}: expected >= --base-crops ({cfg.base_crops})")
    crop = footprint_px(cfg.altitude_m, cfg.fov_deg, cfg.m_per_px)
    if min(cfg.world_width_px, cfg.world_height_px) < crop + 2 * cfg.junction_jitter_px + 8:
        raise UserError(f"world size {cfg.world_width_px}x{cfg.world_height_px} px: expected both sides > "
                        f"{crop + 2 * cfg.junction_jitter_px + 8:.0f} px (the camera footprint is {crop} px)")


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
    base_id: str = ""
    group: str = ""


@dataclass
class WorldData:
    seed: int
    ortho_gray: np.ndarray
    ref_gray: np.ndarray
    m_per_px: float
    junctions: tuple
    landcover: np.ndarray


def arm_class(arms: int) -> MatchClass | None:
    """Junction arm count -> class (>= 4 -> FOUR_ARM, 3 -> THREE_ARM, 2 -> TWO_ARM, else None)."""
    if arms >= 4:
        return MatchClass.FOUR_ARM
    if arms == 3:
        return MatchClass.THREE_ARM
    if arms == 2:
        return MatchClass.TWO_ARM
    return None


def render_crop(gray: np.ndarray, u: float, v: float, crop_px: int, out_px: int, angle_rad: float = 0.0,
                scale: float = 1.0, flip: bool = False) -> np.ndarray:
    """Square crop of side ``crop_px * scale`` centred on continuous (u, v), rotated by ``angle_rad``,
    optionally mirrored, resampled to ``out_px`` x ``out_px`` (one bilinear warp; reflecting border)."""
    g = crop_px * scale / out_px
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    a = g * np.array([[c, -s], [s, c]])
    if flip:
        a = a @ np.array([[-1.0, 0.0], [0.0, 1.0]])
    c_out = np.array([(out_px - 1) / 2.0, (out_px - 1) / 2.0])
    c_src = np.array([u - 0.5, v - 0.5])
    m = np.hstack([a, (c_src - a @ c_out)[:, None]])
    src = gray
    if g > 1.3:  # anti-alias a real downscale
        src = cv2.GaussianBlur(gray, (0, 0), 0.5 * math.sqrt(g * g - 1.0), borderType=cv2.BORDER_REFLECT_101)
    return cv2.warpAffine(src, m, (out_px, out_px), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT_101)


def augment_image(world_gray: np.ndarray, sample: BaseSample, crop_px: int, out_px: int,
                  recipe: AugmentRecipe, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """One augmented copy of a base crop, re-rendered from the world; returns (image, parameters)."""
    angle = math.radians(rng.uniform(*recipe.rotation_deg))
    flip = bool(rng.random() < recipe.flip_probability)
    scale = rng.uniform(*recipe.scale)
    img = render_crop(world_gray, sample.u_px, sample.v_px, crop_px, out_px, angle, scale, flip)
    img = apply_photometry(img, rng, recipe)
    return img, {"rotation_deg": math.degrees(angle), "flip": flip, "scale": scale}


def apply_photometry(img: np.ndarray, rng: np.random.Generator, recipe: AugmentRecipe) -> np.ndarray:
    """Gamma, gain/offset, blur and additive noise on a float image in [0, 1]."""
    gamma = math.exp(rng.uniform(*recipe.log_gamma))
    out = np.power(np.clip(img, 0.0, 1.0), gamma).astype(np.float32)
    out = out * np.float32(rng.uniform(*recipe.gain)) + np.float32(rng.uniform(*recipe.offset))
    sigma = rng.uniform(*recipe.blur_sigma_px)
    if sigma > 0.2:
        out = cv2.GaussianBlur(out, (0, 0), sigma, borderType=cv2.BORDER_REFLECT_101)
    noise = rng.uniform(*recipe.noise_sigma)
    if noise > 0.0:
        out = out + rng.normal(0.0, noise, out.shape).astype(np.float32)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def generate_world_data(seed: int, cfg: DatasetConfig) -> WorldData:
    from worlds.generator import CityConfig, generate_world
    world = generate_world(CityConfig(seed=seed, width_px=cfg.world_width_px, height_px=cfg.world_height_px,
                                      m_per_px=cfg.m_per_px))
    if world.landcover is None or world.junctions is None:
        raise UserError(f"world seed {seed}: generated world has no land cover/junction ground truth")
    return WorldData(seed=seed, ortho_gray=to_gray(world.orthophoto), ref_gray=to_gray(world.reference),
                      m_per_px=world.manifest.m_per_px, junctions=tuple(world.junctions),
                      landcover=world.landcover)


def _inside(u: float, v: float, half: float, w: int, h: int) -> bool:
    return half <= u <= w - half and half <= v <= h - half


def _junction_candidates(wd: WorldData, crop_px: int, jitter: float) -> list[BaseSample]:
    h, w = wd.landcover.shape
    out = []
    for j in wd.junctions:
        cls = arm_class(int(j.arms))
        if cls is None or not _inside(j.u_px, j.v_px, crop_px / 2.0 + jitter, w, h):
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
                       cover=covers[dominant[r, c]].name.lower()) for r, c in zip(rows, cols)]


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
    for rep in range(max_per):
        for s in order:
            if len(picked) >= quota:
                return picked
            du, dv = rng.uniform(-jitter, jitter, 2) if (jitter > 0) else (0.0, 0.0)
            picked.append(BaseSample(world_seed=s.world_seed, source=s.source, u_px=s.u_px + du,
                                     v_px=s.v_px + dv, label=s.label, arms=s.arms, kind=s.kind))
    return picked


def select_base_samples(worlds: list[WorldData], cfg: DatasetConfig, crop_px: int,
                        rng: np.random.Generator) -> list[BaseSample]:
    """Base crop positions with equal class quotas (deficits moved to the other classes)."""
    junctions = {c: [] for c in MatchClass if c is not MatchClass.BAD}
    bad: list[BaseSample] = []
    for wd in worlds:
        for s in _junction_candidates(wd, crop_px, cfg.junction_jitter_px):
            junctions[s.label].append(s)
        bad.extend(_bad_candidates(wd, crop_px, cfg.bad_min_share))
    avail = {c: len(v) * cfg.max_crops_per_junction for c, v in junctions.items()}
    avail[MatchClass.BAD] = len(bad)
    log.info("candidates: %s", {c.name: n for c, n in avail.items()})
    quotas = _share_quota(cfg.base_crops, avail)
    picked: list[BaseSample] = []
    picked += _pick_bad(bad, quotas[MatchClass.BAD], cfg.bad_min_spacing_px, rng)
    for c in (MatchClass.FOUR_ARM, MatchClass.THREE_ARM, MatchClass.TWO_ARM):
        picked += _pick_junctions(junctions[c], quotas[c], cfg.max_crops_per_junction, cfg.junction_jitter_px, rng)
    short = cfg.base_crops - len(picked)
    if short > 0:
        log.warning("only %d base crops available (asked %d): generate more worlds (--worlds)",
                    len(picked), cfg.base_crops)
    return picked


def assign_ids(samples: list[BaseSample], crop_px: int) -> None:
    """Base ids and split groups (spatial tiles of one footprint per world)."""
    for i, s in enumerate(samples):
        s.base_id = f"w{s.world_seed}_{i:05d}"
        s.group = f"w{s.world_seed}_t{int(s.v_px // crop_px)}_{int(s.u_px // crop_px)}"


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
                           label=MatchClass.BAD) for u, v in zip(us, vs)]
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


def _relabel_by_matchability(samples: list[BaseSample], worlds: dict[int, WorldData], crop_px: int) -> None:
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


def build_dataset(out_dir: str | Path, cfg: DatasetConfig, progress: bool = False, command: str = "") -> dict:
    """Generate worlds, select/label/augment crops and write ``out_dir``; returns the manifest.

    ``command`` (the command line, if any) is stored in the manifest for provenance.
    """
    check_config(cfg)
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise UserError(f"{out}: folder exists and is not empty (expected a new or empty folder)")
    t0 = time.perf_counter()
    crop_px = footprint_px(cfg.altitude_m, cfg.fov_deg, cfg.m_per_px)
    seeds = cfg.world_seeds()
    worlds: list[WorldData] = []
    for seed in tqdm(seeds, desc="worlds", unit="world", disable=not progress):
        worlds.append(generate_world_data(seed, cfg))
    t_worlds = time.perf_counter() - t0
    by_seed = {wd.seed: wd for wd in worlds}
    rng = np.random.default_rng([cfg.seed, 7001])
    samples = select_base_samples(worlds, cfg, crop_px, rng)
    if not samples:
        raise UserError(f"worlds {list(seeds)}: no junction or bad-area crop fits (expected bigger worlds)")

    validation = {}
    pool_info = {}
    t_m0 = time.perf_counter()
    if cfg.labelling is Labelling.MATCHABILITY:
        mcfg = cfg.matchability
        pool = samples + random_positions(worlds, cfg.matchability_extra_positions, crop_px, rng)
        bar = tqdm(total=len(pool), desc="matchability", unit="pos", disable=not progress)
        for wd in worlds:
            idx = [i for i, s in enumerate(pool) if s.world_seed == wd.seed]
            if not idx:
                continue
            pos = np.array([[pool[i].u_px, pool[i].v_px] for i in idx])
            res = matchability(wd.ortho_gray, wd.ref_gray, pos, wd.m_per_px, mcfg,
                               np.random.default_rng([cfg.seed, wd.seed, 7002]))
            for i, score in zip(idx, res.score):
                pool[i].matchability = float(score)
            bar.update(len(idx))
        bar.close()
        _relabel_by_matchability(pool, by_seed, crop_px)
        pool_info = {"n_positions": len(pool),
                     "labels": {c.name: sum(1 for s in pool if s.label == c) for c in MatchClass},
                     "unmatchable_by_source": {src.value: sum(1 for s in pool if s.source is src and
                                                               s.label == MatchClass.BAD) for src in CropSource},
                     "mean_score_by_source": {src.value: float(np.mean([s.matchability for s in pool if s.source is src]))
                                              for src in CropSource if any(s.source is src for s in pool)}}
        samples = select_by_label(pool, cfg.base_crops, rng)
        if cfg.validate_global_n > 0:
            validation = _validate_subset(samples, worlds, mcfg, cfg, rng)
            log.info("windowed vs global search: %s", validation)
    t_match = time.perf_counter() - t_m0

    assign_ids(samples, crop_px)
    labels = [s.label for s in samples]
    extra = allocate_augmentation(labels, cfg.augment_to)
    per_sample_extra = np.zeros(len(samples), dtype=np.int64)
    for c in MatchClass:
        idx = [i for i, s in enumerate(samples) if s.label == c]
        if not idx:
            continue
        order = rng.permutation(idx)
        for k in range(int(extra[c])):
            per_sample_extra[order[k % len(order)]] += 1

    for c in MatchClass:
        (out / IMAGES_DIR / c.name).mkdir(parents=True, exist_ok=True)
    rows = []
    total = len(samples) + int(per_sample_extra.sum())
    bar = tqdm(total=total, desc="crops", unit="img", disable=not progress)
    for i, s in enumerate(samples):
        wd = by_seed[s.world_seed]
        srng = np.random.default_rng([cfg.seed, s.world_seed, i, 7003])
        images = [(render_crop(wd.ortho_gray, s.u_px, s.v_px, crop_px, cfg.image_px), {})]
        for _ in range(int(per_sample_extra[i])):
            images.append(augment_image(wd.ortho_gray, s, crop_px, cfg.image_px, cfg.augment, srng))
        for a, (img, _params) in enumerate(images):
            rel = f"{IMAGES_DIR}/{s.label.name}/{s.base_id}_a{a}.png"
            u8 = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
            if not cv2.imwrite(str(out / rel), u8):
                raise UserError(f"{out / rel}: cannot write PNG (check the folder is writable)")
            rows.append({"file": rel, "label": int(s.label), "label_name": s.label.name, "group": s.group,
                         "world_seed": s.world_seed, "source": s.source.value, "u_px": f"{s.u_px:.2f}",
                         "v_px": f"{s.v_px:.2f}", "arms": s.arms, "kind": s.kind, "cover": s.cover,
                         "base_id": s.base_id, "aug_id": a,
                         "matchability": "" if math.isnan(s.matchability) else f"{s.matchability:.4f}"})
            bar.update(1)
    bar.close()
    with open(out / INDEX_FILE, "w", newline="", encoding="utf-8") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(INDEX_COLUMNS))
        wr.writeheader()
        wr.writerows(rows)

    counts = {c.name: sum(1 for r in rows if r["label"] == int(c)) for c in MatchClass}
    base_counts = {c.name: sum(1 for s in samples if s.label == c) for c in MatchClass}
    source_counts = {src.value: sum(1 for s in samples if s.source is src) for src in CropSource}
    cover_counts: dict[str, int] = {}
    for s in samples:
        if s.source is CropSource.BAD_AREA:
            cover_counts[s.cover] = cover_counts.get(s.cover, 0) + 1
    scores = np.array([s.matchability for s in samples])
    manifest = {
        "dataset_version": DATASET_VERSION,
        "created_by": "scenenav dataset",
        "command": command,
        "labelling": cfg.labelling.value,
        "classes": [c.name for c in MatchClass],
        "n_images": len(rows),
        "n_base_crops": len(samples),
        "counts": counts,
        "base_counts": base_counts,
        "base_sources": source_counts,
        "bad_area_covers": cover_counts,
        "world_seeds": list(seeds),
        "world_generator_sha256": _generator_digest(),
        "reserved_eval_world_seeds": list(EVAL_WORLD_SEEDS),
        "world_size_px": [cfg.world_width_px, cfg.world_height_px],
        "m_per_px": cfg.m_per_px,
        "crop_px": crop_px,
        "crop_m": crop_px * cfg.m_per_px,
        "image_px": cfg.image_px,
        "image_format": "8-bit grayscale PNG, images/<CLASS>/<base_id>_a<k>.png (a0 = base crop)",
        "augmentation": {"augment_to": cfg.augment_to, "recipe": asdict(cfg.augment),
                         "allocation": "water-filling per class, round-robin over base crops",
                         "extra_per_class": {c.name: int(extra[c]) for c in MatchClass}},
        "split_groups": f"spatial tiles of {crop_px} px per world (column 'group' in {INDEX_FILE})",
        "config": _config_dict(cfg),
        "matchability": None if cfg.labelling is Labelling.PAPER else {
            "config": asdict(cfg.matchability),
            "threshold": MATCHABLE_SHARE,
            "mean_score": float(np.nanmean(scores)),
            "score_by_source": {src.value: float(np.nanmean([s.matchability for s in samples if s.source is src]))
                                for src in CropSource if any(s.source is src for s in samples)},
            "candidate_pool": pool_info,
            "windowed_vs_global": validation,
            "approximation": f"windowed NCC search +-{cfg.matchability.search_radius_px} px around the truth",
        },
        "wall_time_s": {"worlds": round(t_worlds, 2), "matchability": round(t_match, 2),
                        "total": round(time.perf_counter() - t0, 2)},
    }
    text = json.dumps(manifest, indent=2) + "\n"
    (out / MANIFEST_FILE).write_text(text, encoding="utf-8")
    manifest = json.loads(text)
    log.info("dataset %s: %d images %s in %.1f s", out, len(rows), counts, time.perf_counter() - t0)
    return manifest


def _validate_subset(samples: list[BaseSample], worlds: list[WorldData], mcfg: MatchabilityConfig,
                     cfg: DatasetConfig, rng: np.random.Generator) -> dict:
    """Windowed vs global NCC search on ``validate_global_n`` random base positions (weighted mean)."""
    pick = rng.choice(len(samples), size=min(cfg.validate_global_n, len(samples)), replace=False)
    per_world = []
    for wd in worlds:
        sel = [samples[i] for i in pick if samples[i].world_seed == wd.seed]
        if sel:
            per_world.append(validate_windowed(wd.ortho_gray, wd.ref_gray, np.array([[s.u_px, s.v_px] for s in sel]),
                                               wd.m_per_px, mcfg, seed=cfg.seed * 7919 + wd.seed))
    if not per_world:
        return {}
    n = sum(r["n_positions"] for r in per_world)
    out = {"n_positions": n, "n_captures": sum(r["n_captures"] for r in per_world)}
    for key in per_world[0]:
        if key not in out:
            out[key] = sum(r[key] * r["n_positions"] for r in per_world) / n
    return out


def _generator_digest() -> dict[str, str]:
    """sha256 (first 16 hex) of the world generator sources, for provenance."""
    import worlds.generator
    import worlds.reference
    out = {}
    for mod in (worlds.generator, worlds.reference):
        path = Path(mod.__file__)
        out[path.name] = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    return out


def _config_dict(cfg: DatasetConfig) -> dict:
    d = asdict(cfg)
    d["labelling"] = cfg.labelling.value
    return d


@dataclass(frozen=True)
class LoadedDataset:
    """A dataset folder in memory. ``images`` (N, P, P) uint8 at ``image_px`` or resized."""

    images: np.ndarray
    labels: np.ndarray
    groups: np.ndarray
    rows: tuple[dict, ...]
    manifest: dict
    manifest_sha256: str


def read_manifest(data_dir: str | Path) -> tuple[dict, str]:
    """(manifest, sha256 of its bytes); UserError for a missing or malformed manifest."""
    d = Path(data_dir)
    if not d.is_dir():
        raise UserError(f"{d}: no such dataset folder (expected the output of `scenenav dataset`)")
    mp = d / MANIFEST_FILE
    if not mp.is_file():
        raise UserError(f"{mp}: missing (expected the manifest written by `scenenav dataset`)")
    raw = mp.read_bytes()
    try:
        man = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{mp}: not valid JSON ({exc})") from None
    if not isinstance(man, dict):
        raise UserError(f"{mp}: expected a JSON object")
    if man.get("dataset_version") != DATASET_VERSION:
        raise UserError(f"{mp}: dataset_version = {man.get('dataset_version')!r}: expected {DATASET_VERSION}")
    if man.get("classes") != [c.name for c in MatchClass]:
        raise UserError(f"{mp}: classes = {man.get('classes')!r}: expected {[c.name for c in MatchClass]}")
    if man.get("labelling") not in {lab.value for lab in Labelling}:
        raise UserError(f"{mp}: labelling = {man.get('labelling')!r}: expected paper or matchability")
    return man, hashlib.sha256(raw).hexdigest()


def load_dataset(data_dir: str | Path, resize_px: int | None = None, progress: bool = False) -> LoadedDataset:
    """Read manifest, index and images (resized with INTER_AREA to ``resize_px`` when given)."""
    d = Path(data_dir)
    man, digest = read_manifest(d)
    ip = d / INDEX_FILE
    if not ip.is_file():
        raise UserError(f"{ip}: missing (expected the image index written by `scenenav dataset`)")
    with open(ip, newline="", encoding="utf-8") as fh:
        rows = tuple(csv.DictReader(fh))
    if not rows:
        raise UserError(f"{ip}: no images listed")
    missing_cols = set(INDEX_COLUMNS) - set(rows[0])
    if missing_cols:
        raise UserError(f"{ip}: missing column(s) {sorted(missing_cols)}")
    side = resize_px or int(man.get("image_px", PAPER_INPUT_PX))
    images = np.empty((len(rows), side, side), np.uint8)
    labels = np.empty(len(rows), np.int64)
    for i, r in enumerate(tqdm(rows, desc="loading", unit="img", disable=not progress, leave=False)):
        p = d / r["file"]
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise UserError(f"{p}: missing or unreadable image (listed in {INDEX_FILE})")
        if img.shape != (side, side):
            img = cv2.resize(img, (side, side), interpolation=cv2.INTER_AREA)
        images[i] = img
        try:
            lab = int(r["label"])
            MatchClass(lab)
        except ValueError:
            raise UserError(f"{ip}: row {i + 2}: label {r['label']!r}: expected 0..{len(MatchClass) - 1}") from None
        labels[i] = lab
    groups = np.array([r["group"] or r["base_id"] for r in rows])
    return LoadedDataset(images=images, labels=labels, groups=groups, rows=rows, manifest=man,
                         manifest_sha256=digest)
