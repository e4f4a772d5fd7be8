"""Dataset builder (paper section 5.2), augmentation and the matchability simulation."""

from __future__ import annotations

import csv
import json
import math

import cv2
import numpy as np
import pytest

from perception.capture import CaptureScene
from perception.cnn_spec import Labelling, MatchClass
from perception.dataset import build_dataset
from perception.dataset_config import (
    EVAL_WORLD_SEEDS,
    AugmentRecipe,
    CropGeometry,
    DatasetConfig,
    training_world_seeds,
)
from perception.dataset_files import INDEX_FILE, MANIFEST_FILE, load_dataset, read_manifest
from perception.dataset_images import augment_image, render_crop
from perception.dataset_samples import BaseSample, CropSource, allocate_augmentation, arm_class
from perception.matchability import (
    GLOBAL_SEARCH,
    CaptureNoise,
    MatchabilityConfig,
    footprint_px,
    matchability,
    ncc_peak,
    render_camera,
)
from scenenav.core.errors import UserError

# one tiny world (seed 4 -> world seed 4001); what it contains is up to the generator
TINY = dict(n_worlds=1, seed=4, world_width_px=700, world_height_px=700, base_crops=16, augment_to=28,
            junction_jitter_px=10.0)


def test_footprint_is_217_px_for_the_paper_camera():
    assert footprint_px(100.0, 60.0, 0.53) == 217


def test_arm_count_to_class():
    assert arm_class(4) is MatchClass.FOUR_ARM
    assert arm_class(5) is MatchClass.FOUR_ARM
    assert arm_class(3) is MatchClass.THREE_ARM
    assert arm_class(2) is MatchClass.TWO_ARM
    assert arm_class(1) is None


def test_training_world_seeds_avoid_the_evaluation_worlds():
    seeds = training_world_seeds(0, 8)
    assert seeds == tuple(range(1, 9))
    assert not set(seeds) & set(EVAL_WORLD_SEEDS)
    with pytest.raises(UserError, match="reserved"):
        build_dataset("/nonexistent-never-created", DatasetConfig(seed=9, n_worlds=5))


def test_render_crop_is_a_north_up_footprint():
    img = np.zeros((300, 300), np.float32)
    img[100:110, 150:160] = 1.0           # a bright block north of the centre (u 150..160, v 100..110)
    crop = render_crop(img, 155.0, 150.0, 100, 100)
    ys, xs = np.nonzero(crop > 0.5)
    assert abs(xs.mean() - 49.5) < 1.0 and abs(ys.mean() - 0.0 - 4.5) < 1.5   # top-centre of the crop
    rot = render_crop(img, 155.0, 150.0, 100, 100, angle_rad=math.pi)
    ys2, _ = np.nonzero(rot > 0.5)
    assert ys2.mean() > 90                 # rotated by 180 degrees: now at the bottom


def test_augmentation_keeps_the_label_and_centre():
    """A bright cross stays centred (and is still a cross) under every augmentation."""
    img = np.zeros((400, 400), np.float32)
    img[195:205, 50:350] = 1.0
    img[50:350, 195:205] = 1.0
    s = BaseSample(world_seed=1, source=CropSource.JUNCTION, u_px=200.0, v_px=200.0, label=MatchClass.FOUR_ARM,
                   arms=4)
    rng = np.random.default_rng(0)
    for _ in range(10):
        out, params = augment_image(CaptureScene.flat(img, img, 0.53), s, 217, 200, AugmentRecipe(), rng)
        assert out.shape == (200, 200) and out.dtype == np.float32
        assert 0.0 <= out.min() and out.max() <= 1.0
        assert out[95:105, 95:105].mean() > out.mean()       # the crossing is still at the centre
        # four arms: bright pixels on a ring around the centre come in 4 runs
        ang = np.linspace(0, 2 * np.pi, 360, endpoint=False)
        ring = out[(100 + 70 * np.sin(ang)).astype(int), (100 + 70 * np.cos(ang)).astype(int)]
        on = ring > (ring.max() + ring.min()) / 2
        runs = int(np.sum(on & ~np.roll(on, 1)))
        assert runs == 4, params
    assert s.label is MatchClass.FOUR_ARM


def test_augmentation_allocation_evens_out_classes():
    labels = [MatchClass.BAD] * 10 + [MatchClass.FOUR_ARM] * 2 + [MatchClass.THREE_ARM] * 6 + [MatchClass.TWO_ARM] * 2
    extra = allocate_augmentation(labels, 40)
    assert int(extra.sum()) == 20
    totals = np.array([10, 2, 6, 2]) + extra
    assert totals.max() - totals.min() <= 1


def test_bad_area_candidates_need_dominant_bad_cover_and_no_junction():
    from perception.dataset_samples import WorldData, _bad_candidates
    from worlds.landcover import Junction, JunctionKind, LandCover
    lc = np.full((600, 600), int(LandCover.BUILDING_TEXTURED), np.uint8)
    lc[:, :300] = int(LandCover.WATER)                 # west half: a lake
    junctions = (Junction(450.0, 300.0, 4, JunctionKind.CROSS), Junction(150.0, 150.0, 3, JunctionKind.TEE))
    gray = np.zeros((600, 600), np.float32)
    wd = WorldData(seed=1, scene=CaptureScene.flat(gray, gray, 0.53), junctions=junctions, landcover=lc)
    cands = _bad_candidates(wd, 217, 0.6)
    assert cands
    for c in cands:
        assert c.cover == "water" and c.label is MatchClass.BAD and c.source is CropSource.BAD_AREA
        assert c.u_px < 300 - 217 * 0.1                 # footprint at least 60 % water
        assert not (abs(c.u_px - 150) < 217 / 4 and abs(c.v_px - 150) < 217 / 4)   # not on the tee


def test_intersection_crops_hold_one_junction_each():
    """The paper's way of cutting crops: a square around one junction with no other one inside it."""
    from perception.dataset_samples import WorldData, _junction_candidates
    from worlds.landcover import Junction, JunctionKind, LandCover
    lc = np.full((600, 600), int(LandCover.ROAD), np.uint8)
    junctions = (Junction(200.0, 200.0, 4, JunctionKind.CROSS), Junction(250.0, 210.0, 3, JunctionKind.TEE),
                 Junction(450.0, 400.0, 3, JunctionKind.TEE))
    gray = np.zeros((600, 600), np.float32)
    wd = WorldData(seed=1, scene=CaptureScene.flat(gray, gray, 0.53), junctions=junctions, landcover=lc)
    cfg = DatasetConfig(crop=CropGeometry.INTERSECTION, intersection_crop_m=50.0, intersection_jitter_px=10.0)
    crop = cfg.crop_px()
    assert crop == round(50.0 / 0.53)
    isolated = _junction_candidates(wd, crop, cfg.jitter_px(), isolated=True)
    assert [(c.u_px, c.arms) for c in isolated] == [(450.0, 3)]       # the two 50 px apart share a crop
    assert len(_junction_candidates(wd, crop, cfg.jitter_px(), isolated=False)) == 3
    footprint = DatasetConfig()
    assert footprint.crop_px() == 217 and footprint.jitter_px() == footprint.junction_jitter_px
    with pytest.raises(UserError, match="matchability"):
        build_dataset("/nonexistent-never-created", DatasetConfig(crop=CropGeometry.INTERSECTION,
                                                                  labelling=Labelling.MATCHABILITY))


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "paper"
    man = build_dataset(out, DatasetConfig(**TINY))
    return out, man


def test_dataset_builder_writes_manifest_folders_and_counts(tiny_dataset):
    out, man = tiny_dataset
    on_disk = json.loads((out / MANIFEST_FILE).read_text())
    assert on_disk == man
    assert man["labelling"] == "paper"
    assert man["crop_px"] == 217 and man["image_px"] == 200
    assert man["world_seeds"] == [4001]
    assert man["n_images"] == TINY["augment_to"]
    assert 4 <= man["n_base_crops"] <= TINY["base_crops"]
    for c in MatchClass:
        files = sorted((out / "images" / c.name).glob("*.png"))
        assert len(files) == man["counts"][c.name]
    assert sum(man["counts"].values()) == man["n_images"]
    assert sum(1 for v in man["counts"].values() if v > 0) >= 2
    with open(out / INDEX_FILE, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == man["n_images"]
    by_base = {}
    for r in rows:
        assert r["file"].split("/")[1] == r["label_name"] == MatchClass(int(r["label"])).name
        by_base.setdefault(r["base_id"], set()).add(r["label"])
        img = cv2.imread(str(out / r["file"]), cv2.IMREAD_UNCHANGED)
        assert img.shape == (200, 200) and img.dtype == np.uint8
    assert all(len(labels) == 1 for labels in by_base.values())     # augmented copies keep the label
    assert any(r["aug_id"] != "0" for r in rows)


def test_dataset_loads_and_rejects_bad_folders(tiny_dataset, tmp_path):
    out, man = tiny_dataset
    ds = load_dataset(out, resize_px=48)
    assert ds.images.shape == (man["n_images"], 48, 48)
    assert set(np.unique(ds.labels)) <= {int(c) for c in MatchClass}
    with pytest.raises(UserError, match="no such dataset folder"):
        read_manifest(tmp_path / "nope")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / MANIFEST_FILE).write_text("{not json")
    with pytest.raises(UserError, match="not valid JSON"):
        read_manifest(tmp_path / "bad")
    with pytest.raises(UserError, match="not empty"):
        build_dataset(out, DatasetConfig(**TINY))


def test_matchability_labelling_stores_the_soft_score(tmp_path):
    cfg = DatasetConfig(**TINY, labelling=Labelling.MATCHABILITY,
                        matchability=MatchabilityConfig(n_captures=2), validate_global_n=2,
                        matchability_extra_positions=6)
    man = build_dataset(tmp_path / "m", cfg)
    assert man["labelling"] == "matchability"
    assert man["matchability"]["threshold"] == 0.5
    assert man["matchability"]["windowed_vs_global"]["n_positions"] == 2
    assert man["matchability"]["candidate_pool"]["n_positions"] >= 6
    with open(tmp_path / "m" / INDEX_FILE, newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        score = float(r["matchability"])
        assert 0.0 <= score <= 1.0
        assert (int(r["label"]) == MatchClass.BAD) == (score < 0.5)


# ---- matchability simulation on hand-made maps ------------------------------------------------------

def _texture(seed: int, size: int = 500) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((size, size), dtype=np.float32), (0, 0), 3.0)
    return cv2.normalize(img, None, 0.0, 1.0, cv2.NORM_MINMAX)


def test_ncc_peak_finds_an_exact_template():
    ref = _texture(0)
    tpl = ref[140:240, 200:300]                 # centre (250, 190) in continuous pixels
    eu, ev, peak = ncc_peak(ref, tpl, 250.0, 190.0, 30)
    assert (eu, ev) == (250.0, 190.0) and peak > 0.999
    eu, ev, _ = ncc_peak(ref, tpl, 250.0, 190.0, GLOBAL_SEARCH)
    assert (eu, ev) == (250.0, 190.0)


def test_camera_heading_convention():
    """Heading 90 deg (east): image-up shows what lies east of the drone."""
    img = np.zeros((400, 400), np.float32)
    img[190:210, 260:280] = 1.0                  # east of (200, 200)
    cam = render_camera(img, 200.0, 200.0, math.pi / 2, 100.0, 60.0, 0.53, 200)
    ys, xs = np.nonzero(cam > 0.5)
    assert ys.mean() < 80 and abs(xs.mean() - 99.5) < 5


def test_matchability_textured_vs_flat_map():
    textured = _texture(1)
    cfg = MatchabilityConfig(n_captures=4, noise=CaptureNoise(noise_sigma=0.01))
    pos = np.array([[250.5, 250.5]])
    good = matchability(CaptureScene.flat(textured, textured, 0.53), pos, cfg, np.random.default_rng(0))
    assert good.score[0] == 1.0
    flat = np.full((500, 500), 0.5, np.float32) + np.random.default_rng(2).normal(0, 0.01, (500, 500)).astype(np.float32)
    other_day = np.full((500, 500), 0.5, np.float32) + np.random.default_rng(3).normal(0, 0.01, (500, 500)).astype(np.float32)
    bad = matchability(CaptureScene.flat(flat, other_day, 0.53), pos, cfg, np.random.default_rng(0))
    assert bad.score[0] <= 0.25
