"""Training (paper section 5.3), the split, the metrics of the labelling comparison, and the CLI."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import torch

from perception.cnn import DEFAULT_WEIGHTS_PATH, MatchClassifier, load_weights
from perception.cnn_spec import MatchClass
from perception.dataset import DatasetConfig, build_dataset
from perception.training import (
    TrainConfig,
    confusion_matrix,
    grouped_stratified_split,
    rejection_metrics,
    roc_auc,
    sidecar_paths,
    train,
)
from scenenav.core.errors import UserError


def _tiny_dataset(tmp_path_factory, name: str, seed: int, base_crops: int, augment_to: int):
    """A one-world dataset of a 700 px world (seconds to build)."""
    out = tmp_path_factory.mktemp(name) / "data"
    build_dataset(out, DatasetConfig(n_worlds=1, seed=seed, world_width_px=700, world_height_px=700,
                                     base_crops=base_crops, augment_to=augment_to, junction_jitter_px=10.0))
    return out


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    return _tiny_dataset(tmp_path_factory, "train", seed=4, base_crops=24, augment_to=40)


def test_one_epoch_writes_weights_and_record(tiny_data, tmp_path):
    weights = tmp_path / "tiny.pt"
    res = train(tiny_data, weights, TrainConfig(epochs=1, input_px=32, num_threads=1), command="pytest")
    assert weights.is_file()
    rec_path, png = sidecar_paths(weights)
    assert rec_path.name == "tiny_training_record.json" and png.name == "tiny_confusion_matrix.png"
    assert res.record_path == rec_path and rec_path.is_file() and png.is_file()
    rec = json.loads(rec_path.read_text())
    assert len(rec["epochs"]) == 1
    for key in ("train_loss", "train_accuracy", "val_loss", "val_accuracy"):
        assert np.isfinite(rec["epochs"][0][key])
    cm = np.array(rec["confusion_matrix"]["counts"])
    assert cm.shape == (4, 4) and cm.sum() == rec["split"]["val"]
    assert rec["split"]["train"] + rec["split"]["val"] == 40
    assert rec["torch_version"] == torch.__version__
    assert len(rec["data_manifest_sha256"]) == 64
    assert rec["command"] == "pytest"
    _, meta = load_weights(weights)
    assert meta.training_record_id == rec["record_id"] and meta.input_px == 32
    clf = MatchClassifier.from_file(weights, num_threads=1)
    assert clf.predict_proba(np.zeros((2, 217, 217), np.float32)).shape == (2, 4)


def test_training_is_deterministic(tiny_data, tmp_path):
    cfg = TrainConfig(epochs=1, input_px=32, num_threads=1, seed=3)
    a = train(tiny_data, tmp_path / "a.pt", cfg).record
    b = train(tiny_data, tmp_path / "b.pt", cfg).record
    assert a["epochs"][0]["train_loss"] == b["epochs"][0]["train_loss"]
    assert a["confusion_matrix"] == b["confusion_matrix"]
    wa, _ = load_weights(tmp_path / "a.pt")
    wb, _ = load_weights(tmp_path / "b.pt")
    for (ka, va), (kb, vb) in zip(wa.state_dict().items(), wb.state_dict().items(), strict=False):
        assert ka == kb and torch.equal(va, vb)


def test_training_user_errors(tiny_data, tmp_path):
    with pytest.raises(UserError, match="no such dataset folder"):
        train(tmp_path / "missing", tmp_path / "w.pt", TrainConfig(epochs=1))
    with pytest.raises(UserError, match=".pt"):
        train(tiny_data, tmp_path / "w.bin", TrainConfig(epochs=1))
    with pytest.raises(UserError, match="epochs"):
        train(tiny_data, tmp_path / "w.pt", TrainConfig(epochs=0))


@pytest.fixture(scope="module")
def tiny_other_worlds(tmp_path_factory):
    return _tiny_dataset(tmp_path_factory, "train_extra", seed=5, base_crops=16, augment_to=20)


def test_extra_training_data_keeps_the_validation_split(tiny_data, tiny_other_worlds, tmp_path):
    """--extra-train adds other worlds' images to training only; the validation images are the same."""
    cfg = TrainConfig(epochs=1, input_px=32, num_threads=1, seed=2)
    plain = train(tiny_data, tmp_path / "plain.pt", cfg).record
    more = train(tiny_data, tmp_path / "more.pt", cfg, extra_train=(tiny_other_worlds,)).record
    assert more["split"]["val"] == plain["split"]["val"]
    assert more["split"]["val_per_class"] == plain["split"]["val_per_class"]
    assert more["split"]["train_from_data"] == plain["split"]["train"]
    assert more["split"]["train_from_extra"] == 20 and more["split"]["train"] == plain["split"]["train"] + 20
    assert plain["extra_train_data"] == [] and more["extra_train_data"][0]["n_images"] == 20
    assert more["extra_train_data"][0]["world_seeds"] == [5001]
    assert more["record_id"] != plain["record_id"]
    _, meta = load_weights(tmp_path / "more.pt")
    assert meta.extra["extra_train_manifest_sha256"] == [more["extra_train_data"][0]["data_manifest_sha256"]]


def test_extra_training_data_from_the_same_worlds_is_refused(tiny_data, tmp_path):
    with pytest.raises(UserError, match="world seed 4001"):
        train(tiny_data, tmp_path / "w.pt", TrainConfig(epochs=1, input_px=32, num_threads=1),
              extra_train=(tiny_data,))
    with pytest.raises(UserError, match="no such dataset folder"):
        train(tiny_data, tmp_path / "w.pt", TrainConfig(epochs=1, input_px=32, num_threads=1),
              extra_train=(tmp_path / "missing",))


def test_split_keeps_groups_together_and_is_stratified():
    rng = np.random.default_rng(0)
    labels = np.repeat(np.arange(4), 50)
    groups = np.array([f"g{i // 5}" for i in range(200)])       # 5 images per group, one class each
    tr, va = grouped_stratified_split(labels, groups, 0.2, rng)
    assert len(np.intersect1d(tr, va)) == 0 and len(tr) + len(va) == 200
    assert not set(groups[tr]) & set(groups[va])
    for c in range(4):
        assert (labels[va] == c).sum() == 10


def test_confusion_matrix_rows_are_true_classes():
    cm = confusion_matrix(np.array([0, 0, 1, 3]), np.array([0, 1, 1, 2]))
    assert cm[0, 0] == 1 and cm[0, 1] == 1 and cm[1, 1] == 1 and cm[3, 2] == 1 and cm.sum() == 4


def test_roc_auc_hand_cases():
    assert roc_auc(np.array([0.1, 0.2, 0.8, 0.9]), np.array([0, 0, 1, 1])) == 1.0
    assert roc_auc(np.array([0.9, 0.8, 0.2, 0.1]), np.array([0, 0, 1, 1])) == 0.0
    assert roc_auc(np.array([0.5, 0.5, 0.5, 0.5]), np.array([0, 1, 0, 1])) == 0.5
    assert roc_auc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == 0.75
    assert np.isnan(roc_auc(np.array([0.1, 0.2]), np.array([0, 0])))


def test_rejection_metrics_of_the_paper_rule():
    p_bad = np.array([0.9, 0.7, 0.2, 0.6, 0.1])
    is_false = np.array([True, False, True, True, False])
    m = rejection_metrics(p_bad, is_false)
    # rejected: 0, 1, 3 -> TP = 2 (0, 3), FP = 1 (1), FN = 1 (2)
    assert m["precision"] == pytest.approx(2 / 3) and m["recall"] == pytest.approx(2 / 3)
    assert m["reject_rate"] == pytest.approx(0.6)
    assert m["false_match_rate_after_rejection"] == pytest.approx(0.5)
    assert m["false_match_rate"] == pytest.approx(0.6)


def _parser() -> argparse.ArgumentParser:
    from scenenav.app.commands.perception import register
    p = argparse.ArgumentParser(prog="scenenav")
    sub = p.add_subparsers(dest="command")
    register(sub)
    return p


def test_cli_registers_commands_and_reports_user_errors(tmp_path, capsys):
    p = _parser()
    args = p.parse_args(["train", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "w.pt"), "--quiet"])
    with pytest.raises(UserError, match="no such dataset folder"):
        args.func(args)
    args = p.parse_args(["cnn", "info", str(tmp_path / "none.pt")])
    with pytest.raises(UserError, match="no such weights file"):
        args.func(args)
    args = p.parse_args(["dataset", "--out", str(tmp_path / "d"), "--seed", "9", "--worlds", "3"])
    with pytest.raises(UserError, match="reserved"):
        args.func(args)
    args = p.parse_args(["cnn", "compare", "--paper-data", str(tmp_path / "a"), "--matchability-data",
                         str(tmp_path / "b"), "--out", str(tmp_path / "r")])
    with pytest.raises(UserError, match="no such dataset folder"):
        args.func(args)
    with pytest.raises(SystemExit):
        p.parse_args(["train", "--data", "x", "--out", "w.pt", "--epochs", "0"])
    args = p.parse_args(["train", "--data", "x", "--out", "w.pt", "--extra-train", "a", "--extra-train", "b"])
    assert args.extra_train == ["a", "b"]
    args = p.parse_args(["train", "--data", "x", "--out", "w.pt"])
    assert args.extra_train is None


def test_cli_info_on_the_shipped_weights(capsys):
    p = _parser()
    args = p.parse_args(["cnn", "info", str(DEFAULT_WEIGHTS_PATH)])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "conv1" in out and "dropout2" in out and "Softmax" in out
    assert MatchClass.BAD.name in out


def test_shipped_intersection_model_matches_its_record():
    """perception/weights/intersection.pt (docs/cnn.md, Table 1 on intersection crops) and its record agree."""
    import hashlib

    from perception.shipped import WEIGHTS_DIR
    pt = WEIGHTS_DIR / "intersection.pt"
    record = json.loads((WEIGHTS_DIR / "intersection_training_record.json").read_text())
    clf = MatchClassifier.from_file(pt)
    assert clf.meta.training_record_id == record["record_id"]
    assert record["weights"]["sha256"] == hashlib.sha256(pt.read_bytes()).hexdigest()
    assert clf.input_px == record["config"]["input_px"] == 48
    assert record["dataset"]["crop_px"] == 94 and record["config"]["epochs"] == 30
    assert record["final"]["val_accuracy"] > 0.92          # the paper's Table 1 validation figure
    extra_seeds = {s for e in record["extra_train_data"] for s in e["world_seeds"]}
    assert len(record["extra_train_data"]) == 3 and not extra_seeds & set(record["dataset"]["world_seeds"])
    assert max(extra_seeds) < 9000                          # no held-out world in training
    proba = clf.predict_proba(np.zeros((2, 200, 200), np.float32))
    assert proba.shape == (2, 4) and np.allclose(proba.sum(axis=1), 1.0)
