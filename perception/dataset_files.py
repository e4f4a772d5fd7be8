"""A dataset folder on disk: ``manifest.json``, ``index.csv`` and ``images/<CLASS>/<id>.png``.

Written by ``perception.dataset.build_dataset``, read here (``load_dataset``) for training.
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from perception.cnn_spec import PAPER_INPUT_PX, Labelling, MatchClass
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)


DATASET_VERSION = 1


MANIFEST_FILE = "manifest.json"


INDEX_FILE = "index.csv"


IMAGES_DIR = "images"


INDEX_COLUMNS = ("file", "label", "label_name", "group", "world_seed", "source", "u_px", "v_px",
                 "arms", "kind", "cover", "visible_arms", "arm_verdict", "base_id", "aug_id",
                 "matchability")


OPTIONAL_INDEX_COLUMNS = ("visible_arms", "arm_verdict")
"""Columns added later (junction crops' visible arms); older datasets without them still load."""


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
    missing_cols = set(INDEX_COLUMNS) - set(OPTIONAL_INDEX_COLUMNS) - set(rows[0])
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
