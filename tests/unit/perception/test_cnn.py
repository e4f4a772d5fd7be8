"""The paper's CNN: structure (section 5.1), softmax output, weights files, the shipped model."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from perception.cnn import (
    DEFAULT_WEIGHTS_PATH,
    MatchClassifier,
    SceneMatchNet,
    WeightsMeta,
    load_weights,
    normalise,
    save_weights,
)
from perception.cnn_spec import NUM_CLASSES, MatchClass, feature_side_px
from scenenav.core.errors import UserError


@pytest.fixture(autouse=True)
def _threads():
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def _meta(px: int) -> WeightsMeta:
    return WeightsMeta(input_px=px, classes=tuple(c.name for c in MatchClass), labelling="paper",
                       training_record_id="test")


def test_classes_follow_the_paper_numbering():
    assert [c.name for c in MatchClass] == ["BAD", "FOUR_ARM", "THREE_ARM", "TWO_ARM"]
    assert [c.paper_class for c in MatchClass] == [1, 2, 3, 4]


def test_layer_structure_matches_the_paper():
    net = SceneMatchNet(48)
    convs = [m for m in net.modules() if isinstance(m, nn.Conv2d)]
    pools = [m for m in net.modules() if isinstance(m, nn.AvgPool2d)]
    drops = [m for m in net.modules() if isinstance(m, nn.Dropout)]
    linears = [m for m in net.modules() if isinstance(m, nn.Linear)]
    assert [c.out_channels for c in convs] == [64, 32]
    assert all(c.kernel_size == (3, 3) for c in convs)
    assert convs[0].in_channels == 1                      # grayscale input
    assert len(pools) == 2 and all(p.kernel_size == 2 for p in pools)
    assert len(drops) == 2
    # two fully connected layers + the 4-unit softmax output layer
    hidden = [m for m in linears if m is not net.output]
    assert len(hidden) == 2
    assert net.output.out_features == NUM_CLASSES
    assert hidden[0].in_features == 32 * feature_side_px(48) ** 2
    kinds = [row[1] for row in net.layer_table()]
    assert kinds[-1] == "Softmax"


def test_feature_side_for_valid_convolutions():
    assert feature_side_px(48) == 10      # 48 -> 46 -> 23 -> 21 -> 10
    assert feature_side_px(200) == 48     # 200 -> 198 -> 99 -> 97 -> 48


def test_output_shape_and_softmax_rows():
    torch.manual_seed(0)
    clf = MatchClassifier(SceneMatchNet(32), _meta(32))
    rng = np.random.default_rng(1)
    batch = rng.random((5, 217, 217), dtype=np.float32)
    p = clf.predict_proba(batch)
    assert p.shape == (5, NUM_CLASSES)
    assert np.allclose(p.sum(axis=1), 1.0, atol=1e-5)
    assert np.all(p >= 0)
    assert clf.p_bad(batch).shape == (5,)
    assert np.allclose(clf.p_bad(batch), p[:, MatchClass.BAD])
    # any h, w; a single image; uint8
    assert clf.predict_proba(rng.random((2, 90, 130), dtype=np.float32)).shape == (2, NUM_CLASSES)
    assert clf.predict_proba(batch[0]).shape == (1, NUM_CLASSES)
    u8 = (batch * 255).astype(np.uint8)
    assert np.allclose(clf.predict_proba(u8), p, atol=0.02)


def test_chunked_batches_equal_one_pass():
    torch.manual_seed(0)
    net = SceneMatchNet(32)
    rng = np.random.default_rng(2)
    batch = rng.random((7, 40, 40), dtype=np.float32)
    a = MatchClassifier(net, _meta(32), batch_size=3).predict_proba(batch)
    b = MatchClassifier(net, _meta(32), batch_size=64).predict_proba(batch)
    assert np.allclose(a, b, atol=1e-6)


def test_eval_mode_is_deterministic():
    torch.manual_seed(0)
    clf = MatchClassifier(SceneMatchNet(32), _meta(32))
    x = np.random.default_rng(3).random((4, 32, 32), dtype=np.float32)
    assert np.array_equal(clf.predict_proba(x), clf.predict_proba(x))   # dropout off


def test_normalisation_is_documented_affine():
    x = np.full((1, 48, 48), 0.75, np.float32)
    assert np.allclose(normalise(x, 48), 1.0)      # (0.75 - 0.5) / 0.25
    assert normalise(np.zeros((3, 100, 100), np.float32), 48).shape == (3, 1, 48, 48)


def test_weights_round_trip(tmp_path):
    torch.manual_seed(0)
    net = SceneMatchNet(32)
    path = save_weights(net, tmp_path / "w.pt", _meta(32))
    model, meta = load_weights(path)
    assert meta.input_px == 32 and meta.labelling == "paper" and meta.training_record_id == "test"
    x = torch.rand(2, 1, 32, 32)
    net.eval()
    with torch.no_grad():
        assert torch.allclose(net(x), model(x))


def test_bad_weights_files_are_user_errors(tmp_path):
    with pytest.raises(UserError, match="no such weights file"):
        load_weights(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(UserError):
        load_weights(junk)
    other = tmp_path / "other.pt"
    torch.save({"weights": 1}, other)
    with pytest.raises(UserError, match="state_dict"):
        load_weights(other)


def test_shipped_weights_are_small_and_load():
    assert DEFAULT_WEIGHTS_PATH.is_file(), "perception/weights/default.pt must be shipped"
    assert DEFAULT_WEIGHTS_PATH.stat().st_size <= 10 * 1024 * 1024
    clf = MatchClassifier.default()
    assert clf.meta.classes == tuple(c.name for c in MatchClass)
    assert not clf.model.training


def test_shipped_model_separates_water_forest_from_a_cross_junction():
    """Behavioural check: P(bad) higher on water/forest crops than on four-arm junction crops."""
    from perception.alignment import to_gray_float32 as to_gray
    from perception.dataset_images import render_crop
    from perception.matchability import footprint_px
    from worlds.generator import CityConfig, generate_world
    from worlds.landcover import LandCover

    world = generate_world(CityConfig(seed=9001, width_px=1200, height_px=1200, m_per_px=0.53))
    gray = to_gray(world.orthophoto)
    crop = footprint_px(100.0, 60.0, world.manifest.m_per_px)
    half = crop / 2.0
    h, w = gray.shape
    crosses = [j for j in world.junctions if j.arms >= 4 and half <= j.u_px <= w - half and half <= j.v_px <= h - half]
    assert crosses, "the evaluation world has no four-arm junction away from the border"
    good = np.stack([render_crop(gray, j.u_px, j.v_px, crop, 200) for j in crosses[:8]])

    lc = world.landcover
    flat = np.isin(lc, [int(LandCover.WATER), int(LandCover.FOREST)]).astype(np.float32)
    import cv2
    share = cv2.boxFilter(flat, -1, (crop, crop), normalize=True)
    share[: int(half) + 1] = 0
    share[-int(half) - 1:] = 0
    share[:, : int(half) + 1] = 0
    share[:, -int(half) - 1:] = 0
    vs, us = np.nonzero(share >= 0.8)
    assert len(vs), "the evaluation world has no water/forest area of a camera footprint"
    pick = np.linspace(0, len(vs) - 1, 8).astype(int)
    bad = np.stack([render_crop(gray, us[i] + 0.5, vs[i] + 0.5, crop, 200) for i in pick])

    clf = MatchClassifier.default(num_threads=1)
    p_bad_bad = clf.p_bad(bad)
    p_bad_good = clf.p_bad(good)
    assert p_bad_bad.mean() > p_bad_good.mean() + 0.3
    assert np.median(p_bad_bad) > 0.5 > np.median(p_bad_good)
