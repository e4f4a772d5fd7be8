"""Labelled dataset of good/bad matching areas built from generated worlds (paper section 5.2).

The paper cropped 1500 images from Google Maps (intersections and bad areas), converted them to
grayscale, resized them to 200 x 200 and augmented them to 3920. We do the same from generated
worlds, whose ground truth (road-graph junctions, land cover) replaces the manual labelling:

* base crops are camera footprints (``footprint_px``: 217 px at 0.53 m/px for 100 m altitude and
  a 60 degree field of view), north-up, taken from the ORTHOPHOTO (what the camera sees); on a world
  with a surface model they are nadir captures rendered with relief (``DatasetConfig.capture``,
  ``perception.capture.CaptureScene.footprint_image``; ``relief: false`` gives today's flat crops);
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

Modules: ``dataset_config`` (DatasetConfig, checks), ``dataset_samples`` (positions, labels, quotas),
``dataset_images`` (crop rendering, photometry), ``dataset_files`` (the folder format, loading),
this one (``build_dataset``: the whole procedure).

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
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from perception.cnn_spec import Labelling, MatchClass
from perception.dataset_config import EVAL_WORLD_SEEDS, DatasetConfig, check_config
from perception.dataset_files import DATASET_VERSION, IMAGES_DIR, INDEX_COLUMNS, INDEX_FILE, MANIFEST_FILE
from perception.dataset_images import augment_image
from perception.dataset_samples import (
    MATCHABLE_SHARE,
    BaseSample,
    CropSource,
    WorldData,
    allocate_augmentation,
    assign_ids,
    generate_world_data,
    random_positions,
    relabel_by_matchability,
    select_base_samples,
    select_by_label,
)
from perception.matchability import MatchabilityConfig, matchability, validate_windowed
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)


def build_dataset(out_dir: str | Path, cfg: DatasetConfig, progress: bool = False, command: str = "") -> dict:
    """Generate worlds, select/label/augment crops and write ``out_dir``; returns the manifest.

    ``command`` (the command line, if any) is stored in the manifest for provenance.
    """
    check_config(cfg)
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()):
        raise UserError(f"{out}: folder exists and is not empty (expected a new or empty folder)")
    t0 = time.perf_counter()
    crop_px = cfg.crop_px()
    seeds = cfg.world_seeds()
    worlds: list[WorldData] = []
    for seed in tqdm(seeds, desc="worlds", unit="world", disable=not progress):
        worlds.append(generate_world_data(seed, cfg))
    t_worlds = time.perf_counter() - t0
    by_seed = {wd.seed: wd for wd in worlds}
    rng = np.random.default_rng([cfg.seed, 7001])
    arm_stats: dict = {}
    samples = select_base_samples(worlds, cfg, crop_px, rng, arm_stats)
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
            res = matchability(wd.scene, pos, mcfg, np.random.default_rng([cfg.seed, wd.seed, 7002]))
            for i, score in zip(idx, res.score, strict=False):
                pool[i].matchability = float(score)
            bar.update(len(idx))
        bar.close()
        relabel_by_matchability(pool, by_seed, crop_px)
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
        images = [(wd.scene.footprint_image(s.u_px, s.v_px, crop_px, cfg.image_px, cfg.crop_fov_deg()), {})]
        for _ in range(int(per_sample_extra[i])):
            images.append(augment_image(wd.scene, s, crop_px, cfg.image_px, cfg.augment, srng, cfg.crop_fov_deg()))
        for a, (img, _params) in enumerate(images):
            rel = f"{IMAGES_DIR}/{s.label.name}/{s.base_id}_a{a}.png"
            u8 = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
            if not cv2.imwrite(str(out / rel), u8):
                raise UserError(f"{out / rel}: cannot write PNG (check the folder is writable)")
            rows.append({"file": rel, "label": int(s.label), "label_name": s.label.name, "group": s.group,
                         "world_seed": s.world_seed, "source": s.source.value, "u_px": f"{s.u_px:.2f}",
                         "v_px": f"{s.v_px:.2f}", "arms": s.arms, "kind": s.kind, "cover": s.cover,
                         "visible_arms": "" if s.visible_arms is None else s.visible_arms,
                         "arm_verdict": s.arm_verdict, "base_id": s.base_id, "aug_id": a,
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
        "crop": cfg.crop.value,
        "crop_px": crop_px,
        "crop_fov_deg": cfg.crop_fov_deg(),
        "junction_arms": {"labels": cfg.arms.value, **arm_stats},
        "crop_m": crop_px * cfg.m_per_px,
        "image_px": cfg.image_px,
        "image_format": "8-bit grayscale PNG, images/<CLASS>/<base_id>_a<k>.png (a0 = base crop)",
        "captures": {"relief": cfg.capture.relief, "reference": cfg.capture.reference.value,
                     "worlds_with_relief": [wd.seed for wd in worlds if wd.scene.relief],
                     "reference_kinds": sorted({wd.scene.reference_kind.value for wd in worlds})},
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
            per_world.append(validate_windowed(wd.scene, np.array([[s.u_px, s.v_px] for s in sel]),
                                               mcfg, seed=cfg.seed * 7919 + wd.seed))
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
    d["crop"] = cfg.crop.value
    d["capture"] = {"relief": cfg.capture.relief, "reference": cfg.capture.reference.value}
    return d
