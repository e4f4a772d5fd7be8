"""Training of the paper's CNN (section 5.3) on a `scenenav dataset` folder.

Settings (the paper used Keras with an 80/20 split and reports Table 1; the rest is ours): Adam
(lr 1e-3, cosine decay to 0 over the epochs), cross-entropy on the softmax output, batch 32, 30
epochs, a random 90-degree rotation / mirror per training batch on top of the offline augmentation,
seeded and deterministic (``torch.manual_seed``, ``torch.use_deterministic_algorithms``, fixed thread
count).

Split: 80/20, seeded, stratified by class and GROUPED by spatial tile (all crops and augmented copies
of one footprint-sized tile of one world fall on the same side), so validation images are never
augmented copies of training images. Each group is assigned to the class most of its images have.

Reported per epoch, like Keras: training loss/accuracy = mean over the epoch's batches in training
mode (dropout on); validation loss/accuracy = evaluation mode on the validation split.

Outputs: the weights file (state_dict + metadata), ``training_record.json`` and
``confusion_matrix.png`` beside it (for a weights file not named ``default.pt`` the two are prefixed
with ``<stem>_``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import platform
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from perception.capture import CaptureSettings
from perception.cnn import MatchClassifier, SceneMatchNet, WeightsMeta, normalise, save_weights
from perception.cnn_spec import (
    BAD_THRESHOLD,
    NUM_CLASSES,
    PAPER_INPUT_PX,
    Labelling,
    MatchClass,
)
from perception.dataset_config import DatasetConfig
from perception.dataset_files import LoadedDataset, load_dataset, read_manifest
from perception.dataset_images import render_crop
from perception.dataset_samples import generate_world_data, select_base_samples
from perception.matchability import MatchabilityConfig, footprint_px, simulate_capture
from perception.training_config import CnnMode, CompareConfig, PositionSet, SplitMethod, TrainConfig
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

PAPER_TABLE1 = {"training": {"accuracy": 0.96, "loss": 0.08}, "validation": {"accuracy": 0.92, "loss": 0.10}}
RECORD_FORMAT_VERSION = 1
DEFAULT_STEM = "default"


@dataclass(frozen=True)
class TrainResult:
    weights_path: Path
    record_path: Path
    confusion_png: Path
    record: dict


def sidecar_paths(weights_path: Path) -> tuple[Path, Path]:
    """(training record, confusion-matrix PNG) written beside ``weights_path``."""
    prefix = "" if weights_path.stem == DEFAULT_STEM else f"{weights_path.stem}_"
    return (weights_path.with_name(f"{prefix}training_record.json"),
            weights_path.with_name(f"{prefix}confusion_matrix.png"))


def grouped_stratified_split(labels: np.ndarray, groups: np.ndarray, val_share: float,
                             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(train indices, validation indices): whole groups, about ``val_share`` of every class."""
    uniq, inv = np.unique(groups, return_inverse=True)
    major = np.array([np.bincount(labels[inv == g], minlength=NUM_CLASSES).argmax() for g in range(len(uniq))])
    sizes = np.bincount(inv, minlength=len(uniq))
    val_groups = np.zeros(len(uniq), dtype=bool)
    for c in range(NUM_CLASSES):
        gs = np.flatnonzero(major == c)
        if len(gs) < 2:
            continue
        gs = gs[rng.permutation(len(gs))]
        target = val_share * sizes[gs].sum()
        acc = 0
        for g in gs[:-1]:           # always keep at least one group of the class for training
            if acc >= target:
                break
            val_groups[g] = True
            acc += sizes[g]
    is_val = val_groups[inv]
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


def _to_input(images_u8: np.ndarray, input_px: int, chunk: int = 512) -> torch.Tensor:
    parts = [normalise(images_u8[i:i + chunk].astype(np.float32) / 255.0, input_px)
             for i in range(0, len(images_u8), chunk)]
    return torch.from_numpy(np.concatenate(parts))


def _evaluate(model: nn.Module, x: torch.Tensor, y: torch.Tensor, batch: int = 256) -> tuple[float, float, np.ndarray]:
    """(mean loss, accuracy, predictions) in evaluation mode."""
    model.eval()
    loss_fn = nn.CrossEntropyLoss(reduction="sum")
    total, correct, preds = 0.0, 0, []
    with torch.inference_mode():
        for i in range(0, len(x), batch):
            logits = model(x[i:i + batch])
            total += float(loss_fn(logits, y[i:i + batch]))
            p = logits.argmax(dim=1)
            correct += int((p == y[i:i + batch]).sum())
            preds.append(p.numpy())
    n = max(len(x), 1)
    return total / n, correct / n, (np.concatenate(preds) if preds else np.zeros(0, np.int64))


def confusion_matrix(y_true: np.ndarray, y_pred: np.ndarray) -> np.ndarray:
    """(n_classes, n_classes) counts, rows = true class, columns = predicted class."""
    cm = np.zeros((NUM_CLASSES, NUM_CLASSES), dtype=np.int64)
    np.add.at(cm, (np.asarray(y_true, int), np.asarray(y_pred, int)), 1)
    return cm


def format_confusion(cm: np.ndarray) -> str:
    names = [c.name for c in MatchClass]
    w = max(len(n) for n in names) + 2
    lines = ["true \\ predicted".ljust(w + 2) + "".join(n.rjust(w) for n in names)]
    for i, n in enumerate(names):
        lines.append(n.ljust(w + 2) + "".join(str(int(v)).rjust(w) for v in cm[i]))
    return "\n".join(lines)


def plot_confusion(cm: np.ndarray, path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [c.name for c in MatchClass]
    fig, ax = plt.subplots(figsize=(5.2, 4.6), dpi=110)
    norm = cm / np.maximum(cm.sum(axis=1, keepdims=True), 1)
    ax.imshow(norm, cmap="Blues", vmin=0.0, vmax=1.0)
    for i in range(NUM_CLASSES):
        for j in range(NUM_CLASSES):
            ax.text(j, i, f"{int(cm[i, j])}\n{norm[i, j]:.2f}", ha="center", va="center", fontsize=8,
                    color="white" if norm[i, j] > 0.6 else "black")
    ax.set_xticks(range(NUM_CLASSES), names, rotation=30, ha="right")
    ax.set_yticks(range(NUM_CLASSES), names)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def record_id_for(manifest_sha256: str, cfg: TrainConfig, extra_manifest_sha256: tuple[str, ...] = ()) -> str:
    """Record id of a training run: the data (and any training-only extra data) and the config."""
    key: dict = {"data": manifest_sha256, "cfg": asdict(cfg)}
    if extra_manifest_sha256:          # absent without extra data: earlier record ids stay valid
        key["extra_train_data"] = list(extra_manifest_sha256)
    blob = json.dumps(key, sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


EXTRA_DATA_MUST_MATCH = ("labelling", "crop_px", "image_px")
"""Manifest fields in which a training-only extra dataset must agree with the main one."""


def load_extra_training_data(main: LoadedDataset, extra_dirs: tuple[str | Path, ...],
                             progress: bool = False) -> list[tuple[str, LoadedDataset]]:
    """Load ``--extra-train`` datasets: training-only images from other worlds.

    Refuses a dataset that shares a world seed with the main dataset (its crops could sit next to
    validation crops) or with another extra dataset, or differs in labelling, crop size or image size.
    """
    seen_seeds = {int(s): str(main.manifest.get("command") or "--data") for s in main.manifest.get("world_seeds") or ()}
    out = []
    for d in extra_dirs:
        ds = load_dataset(d, progress=progress)
        for k in EXTRA_DATA_MUST_MATCH:
            if ds.manifest.get(k) != main.manifest.get(k):
                raise UserError(f"--extra-train {d}: {k} = {ds.manifest.get(k)!r}, but the --data dataset has "
                                f"{main.manifest.get(k)!r}")
        seeds = [int(s) for s in ds.manifest.get("world_seeds") or ()]
        if not seeds:
            raise UserError(f"--extra-train {d}: its manifest lists no world seeds")
        clash = sorted(set(seeds) & set(seen_seeds))
        if clash:
            raise UserError(f"--extra-train {d}: world seed {clash[0]} is also in another dataset of this run "
                            f"(extra training data must come from other worlds, or it leaks into validation)")
        seen_seeds.update({s: str(d) for s in seeds})
        out.append((str(d), ds))
    return out


def train(data_dir: str | Path, out_path: str | Path, cfg: TrainConfig | None = None, progress: bool = False,
          command: str = "", data: LoadedDataset | None = None,
          extra_train: tuple[str | Path, ...] = ()) -> TrainResult:
    """Train on ``data_dir`` and write weights, training record and confusion-matrix PNG.

    ``extra_train``: dataset folders of other worlds added to the training side only; the split of
    ``data_dir`` (hence the validation set) is the same as without them.

    Torch's process-wide thread count and deterministic-algorithms flag are restored afterwards.
    """
    cfg = cfg or TrainConfig()
    cfg.check()
    out = Path(out_path)
    if out.suffix != ".pt":
        raise UserError(f"--out {out}: expected a .pt file name")
    threads, determ = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    try:
        torch.set_num_threads(cfg.num_threads)
        torch.manual_seed(cfg.seed)
        torch.use_deterministic_algorithms(True)
        return _train(data_dir, out, cfg, progress, command, data, tuple(extra_train))
    finally:
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(determ)


def _train(data_dir: str | Path, out: Path, cfg: TrainConfig, progress: bool, command: str,
           data: LoadedDataset | None, extra_train: tuple[str | Path, ...] = ()) -> TrainResult:
    t0 = time.perf_counter()
    ds = data if data is not None else load_dataset(data_dir, progress=progress)
    extras = load_extra_training_data(ds, extra_train, progress=progress)
    rng = np.random.default_rng([cfg.seed, 8001])
    groups = ds.groups if cfg.split == SplitMethod.GROUPED.value else np.arange(len(ds.labels)).astype(str)
    tr_idx, va_idx = grouped_stratified_split(ds.labels, groups, cfg.val_share, rng)
    if len(va_idx) == 0 or len(tr_idx) == 0:
        raise UserError(f"{data_dir}: too few images/groups for an {1 - cfg.val_share:.0%}/{cfg.val_share:.0%} split")
    x_all = _to_input(ds.images, cfg.input_px)
    y_all = torch.from_numpy(ds.labels.astype(np.int64))
    x_tr, y_tr, x_va, y_va = x_all[tr_idx], y_all[tr_idx], x_all[va_idx], y_all[va_idx]
    if extras:
        x_tr = torch.cat([x_tr] + [_to_input(e.images, cfg.input_px) for _, e in extras])
        y_tr = torch.cat([y_tr] + [torch.from_numpy(e.labels.astype(np.int64)) for _, e in extras])
    n_extra = sum(len(e.labels) for _, e in extras)
    t_load = time.perf_counter() - t0

    model = SceneMatchNet(cfg.input_px)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.learning_rate, weight_decay=cfg.weight_decay)
    loss_fn = nn.CrossEntropyLoss()
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.epochs) if cfg.cosine_lr else None
    gen = torch.Generator().manual_seed(cfg.seed)
    history = []
    bar = tqdm(range(1, cfg.epochs + 1), desc="epochs", unit="epoch", disable=not progress)
    for epoch in bar:
        te = time.perf_counter()
        model.train()
        perm = torch.randperm(len(x_tr), generator=gen)
        loss_sum, correct, seen = 0.0, 0, 0
        for i in range(0, len(perm), cfg.batch_size):
            b = perm[i:i + cfg.batch_size]
            xb, yb = x_tr[b], y_tr[b]
            if cfg.online_dihedral:
                k = int(torch.randint(0, 8, (1,), generator=gen))
                xb = torch.rot90(xb, k % 4, dims=(2, 3))
                if k >= 4:
                    xb = torch.flip(xb, dims=(3,))
            opt.zero_grad(set_to_none=True)
            logits = model(xb)
            loss = loss_fn(logits, yb)
            loss.backward()
            opt.step()
            loss_sum += loss.item() * len(b)
            correct += int((logits.argmax(dim=1) == yb).sum())
            seen += len(b)
        if sched is not None:
            sched.step()
        va_loss, va_acc, _ = _evaluate(model, x_va, y_va)
        row = {"epoch": epoch, "train_loss": loss_sum / seen, "train_accuracy": correct / seen,
               "val_loss": va_loss, "val_accuracy": va_acc, "seconds": time.perf_counter() - te}
        history.append(row)
        msg = (f"epoch {epoch:3d}/{cfg.epochs}: train loss {row['train_loss']:.4f} acc {row['train_accuracy']:.4f}"
               f" | val loss {va_loss:.4f} acc {va_acc:.4f} ({row['seconds']:.1f} s)")
        log.info(msg)
        if progress:
            tqdm.write(msg)
            bar.set_postfix(val_acc=f"{va_acc:.3f}")
    bar.close()

    va_loss, va_acc, va_pred = _evaluate(model, x_va, y_va)
    tr_loss_eval, tr_acc_eval, _ = _evaluate(model, x_tr, y_tr)
    cm = confusion_matrix(y_va.numpy(), va_pred)
    y_va_np = y_va.numpy()
    bad_true = y_va_np == MatchClass.BAD
    bad_pred = va_pred == MatchClass.BAD
    per_class = {}
    for c in MatchClass:
        tp = int(cm[c, c])
        per_class[c.name] = {"precision": tp / max(int(cm[:, c].sum()), 1), "recall": tp / max(int(cm[c].sum()), 1),
                             "n_val": int(cm[c].sum())}
    rid = record_id_for(ds.manifest_sha256, cfg, tuple(e.manifest_sha256 for _, e in extras))
    extra_summary = [{"data_dir": d, "data_manifest_sha256": e.manifest_sha256, "n_images": int(len(e.labels)),
                      "command": e.manifest.get("command"), "world_seeds": e.manifest.get("world_seeds"),
                      "counts": e.manifest.get("counts")} for d, e in extras]
    meta_extra = {"data_manifest_sha256": ds.manifest_sha256, "epochs": cfg.epochs, "seed": cfg.seed,
                  "val_accuracy": round(va_acc, 4), "val_loss": round(va_loss, 4)}
    if extras:
        meta_extra["extra_train_manifest_sha256"] = [e.manifest_sha256 for _, e in extras]
    meta = WeightsMeta(input_px=cfg.input_px, classes=tuple(c.name for c in MatchClass),
                       labelling=str(ds.manifest.get("labelling")), training_record_id=rid,
                       extra=meta_extra)
    save_weights(model, out, meta)
    wall = time.perf_counter() - t0
    record_path, png_path = sidecar_paths(out)
    last = history[-1]
    record = {
        "record_format_version": RECORD_FORMAT_VERSION,
        "record_id": rid,
        "command": command,
        "data_dir": str(data_dir),
        "data_manifest_sha256": ds.manifest_sha256,
        "labelling": ds.manifest.get("labelling"),
        "dataset": {k: ds.manifest.get(k) for k in ("command", "n_images", "n_base_crops", "counts", "world_seeds",
                                                      "world_size_px", "crop_px", "image_px", "dataset_version",
                                                      "world_generator_sha256")},
        "config": asdict(cfg),
        "extra_train_data": extra_summary,
        "split": {"train": int(len(tr_idx)) + n_extra, "train_from_data": int(len(tr_idx)),
                  "train_from_extra": n_extra, "val": int(len(va_idx)),
                  "val_per_class": {c.name: int((y_va_np == c).sum()) for c in MatchClass},
                  "method": f"{cfg.split} stratified, seeded"},
        "epochs": history,
        "final": {"train_accuracy": last["train_accuracy"], "train_loss": last["train_loss"],
                  "train_accuracy_eval_mode": tr_acc_eval, "train_loss_eval_mode": tr_loss_eval,
                  "val_accuracy": va_acc, "val_loss": va_loss,
                  "val_bad_vs_good_accuracy": float(np.mean(bad_true == bad_pred)) if len(va_pred) else 0.0},
        "paper_table1": PAPER_TABLE1,
        "confusion_matrix": {"rows_true_cols_pred": [c.name for c in MatchClass], "counts": cm.tolist()},
        "per_class": per_class,
        "weights": {"file": out.name, "bytes": out.stat().st_size,
                    "sha256": hashlib.sha256(out.read_bytes()).hexdigest()},
        "wall_time_s": {"load": round(t_load, 2), "total": round(wall, 2)},
        "torch_version": torch.__version__,
        "numpy_version": np.__version__,
        "python": platform.python_version(),
        "threads": torch.get_num_threads(),
    }
    record_path.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    plot_confusion(cm, png_path, f"validation confusion ({ds.manifest.get('labelling')} labelling), "
                                 f"acc {va_acc:.3f}")
    log.info("wrote %s, %s, %s (%.1f s)", out, record_path, png_path, wall)
    return TrainResult(weights_path=out, record_path=record_path, confusion_png=png_path, record=record)


# ----------------------------------------------------------------------------------------------------
# Labelling comparison (`scenenav cnn compare`)
# ----------------------------------------------------------------------------------------------------

def roc_auc(scores: np.ndarray, positives: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` for boolean ``positives`` (Mann-Whitney, ties averaged)."""
    s = np.asarray(scores, float)
    pos = np.asarray(positives, bool)
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    order = np.argsort(s, kind="mergesort")
    ranks = np.empty(len(s))
    sorted_s = s[order]
    i = 0
    while i < len(s):
        j = i
        while j + 1 < len(s) and sorted_s[j + 1] == sorted_s[i]:
            j += 1
        ranks[order[i:j + 1]] = (i + j) / 2.0 + 1.0
        i = j + 1
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def rejection_metrics(p_bad: np.ndarray, is_false: np.ndarray, threshold: float = BAD_THRESHOLD) -> dict:
    """AUC and the paper's rule "reject when P(bad) > threshold" scored against true false matches."""
    p = np.asarray(p_bad, float)
    f = np.asarray(is_false, bool)
    rej = p > threshold
    tp = int((rej & f).sum())
    fp = int((rej & ~f).sum())
    fn = int((~rej & f).sum())
    acc = ~rej
    return {
        "n": int(len(p)),
        "false_match_rate": float(f.mean()) if len(f) else float("nan"),
        "auc": roc_auc(p, f),
        "precision": tp / (tp + fp) if tp + fp else float("nan"),
        "recall": tp / (tp + fn) if tp + fn else float("nan"),
        "reject_rate": float(rej.mean()) if len(p) else float("nan"),
        "false_match_rate_after_rejection": float(f[acc].mean()) if acc.any() else float("nan"),
        "true_matches_kept": float((~rej & ~f).sum() / max(int((~f).sum()), 1)),
    }


def _eval_positions(wd, crop_px: int, cfg: CompareConfig, dcfg, rng: np.random.Generator) -> dict:
    h, w = wd.ref_gray.shape
    half = crop_px / 2.0
    uni = np.column_stack([rng.uniform(half, w - half, cfg.uniform_positions_per_world),
                           rng.uniform(half, h - half, cfg.uniform_positions_per_world)])
    pcfg = replace(dcfg, base_crops=cfg.paper_positions_per_world, max_crops_per_junction=1)
    samples = select_base_samples([wd], pcfg, crop_px, rng)
    pap = np.array([[s.u_px, s.v_px] for s in samples]).reshape(-1, 2)
    return {PositionSet.UNIFORM: uni, PositionSet.PAPER: pap}


def compare_labellings(paper_data: str | Path, matchability_data: str | Path, out_dir: str | Path,
                       cfg: CompareConfig | None = None, paper_weights: str | Path | None = None,
                       matchability_weights: str | Path | None = None, progress: bool = False) -> dict:
    """Train (or load) one model per labelling and score P(bad) against simulated false matches on
    held-out worlds; writes ``compare_report.json`` and ``compare_report.md`` to ``out_dir``."""
    cfg = cfg or CompareConfig()
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    manifests = {}
    for lab, d in ((Labelling.PAPER, paper_data), (Labelling.MATCHABILITY, matchability_data)):
        man, _ = read_manifest(d)
        if man["labelling"] != lab.value:
            raise UserError(f"{d}: labelling = {man['labelling']!r}: expected {lab.value!r} here")
        clash = sorted(set(man.get("world_seeds", [])) & set(cfg.eval_world_seeds))
        if clash:
            raise UserError(f"--eval-worlds: seed {clash[0]} was used to build {d} (expected held-out seeds)")
        manifests[lab] = man
    classifiers = {}
    for lab, data, weights in ((Labelling.PAPER, paper_data, paper_weights),
                               (Labelling.MATCHABILITY, matchability_data, matchability_weights)):
        if weights is None:
            weights = out / f"{lab.value}.pt"
            train(data, weights, TrainConfig(epochs=cfg.epochs, seed=cfg.seed, input_px=cfg.input_px,
                                             num_threads=cfg.num_threads), progress=progress,
                  command=f"compare: train {lab.value}")
        classifiers[lab] = MatchClassifier.from_file(weights, num_threads=cfg.num_threads)

    man = manifests[Labelling.PAPER]
    w_px, h_px = man["world_size_px"]
    # Captures as the paper dataset was built (datasets older than the capture settings are flat).
    cap = man.get("config", {}).get("capture") or {"relief": False}
    dcfg = DatasetConfig(world_width_px=int(w_px), world_height_px=int(h_px), m_per_px=float(man["m_per_px"]),
                         capture=CaptureSettings(**cap))
    mcfg = MatchabilityConfig()
    crop_px = footprint_px(mcfg.altitude_m, mcfg.fov_deg, dcfg.m_per_px)
    # per position set: lists of per-capture arrays
    acc: dict = {ps: {"is_false": [], "error_m": [], "world": [],
                      **{(lab, mode): [] for lab in Labelling for mode in CnnMode}} for ps in PositionSet}
    for seed in tqdm(cfg.eval_world_seeds, desc="eval worlds", unit="world", disable=not progress):
        wd = generate_world_data(seed, dcfg)
        rng = np.random.default_rng([cfg.seed, seed, 9101])
        sets = _eval_positions(wd, crop_px, cfg, dcfg, rng)
        for ps, pos in sets.items():
            cams, refs, errs = [], [], []
            for u, v in tqdm(pos, desc=f"world {seed} {ps.value}", unit="pos", leave=False, disable=not progress):
                ref_crop = render_crop(wd.ref_gray, u, v, crop_px, PAPER_INPUT_PX)
                for _ in range(cfg.captures_per_position):
                    o = simulate_capture(wd.scene, u, v, mcfg, rng)
                    cams.append(o.camera_image)
                    refs.append(ref_crop)
                    errs.append(o.error_m)
            if not errs:
                continue
            cams_a, refs_a, errs_a = np.stack(cams), np.stack(refs), np.array(errs)
            acc[ps]["is_false"].append(errs_a > mcfg.tolerance_m)
            acc[ps]["error_m"].append(errs_a)
            acc[ps]["world"].append(np.full(len(errs_a), seed))
            for lab, clf in classifiers.items():
                acc[ps][(lab, CnnMode.ONLINE)].append(clf.p_bad(cams_a))
                acc[ps][(lab, CnnMode.ASSISTANT_MAP)].append(clf.p_bad(refs_a))

    results: dict = {}
    for ps in PositionSet:
        if not acc[ps]["is_false"]:
            continue
        f = np.concatenate(acc[ps]["is_false"])
        results[ps.value] = {"n_captures": int(len(f)), "false_match_rate": float(f.mean()), "models": {}}
        for lab in Labelling:
            results[ps.value]["models"][lab.value] = {
                mode.value: rejection_metrics(np.concatenate(acc[ps][(lab, mode)]), f) for mode in CnnMode}
    report = {
        "eval_world_seeds": list(cfg.eval_world_seeds),
        "training_world_seeds": {lab.value: manifests[lab].get("world_seeds") for lab in Labelling},
        "weights": {lab.value: {"labelling": c.meta.labelling, "record_id": c.meta.training_record_id,
                                "input_px": c.meta.input_px} for lab, c in classifiers.items()},
        "ground_truth": (f"per capture: simulated noisy capture (perception.matchability, {cfg.captures_per_position} "
                         f"per position) matched with TM_CCOEFF_NORMED in a +-{mcfg.search_radius_px} px window is "
                         f"false when it lands > {mcfg.tolerance_m} m from the truth"),
        "decision_rule": f"reject when P(bad) > {BAD_THRESHOLD}; positive class = false match",
        "config": {**asdict(cfg), "eval_world_seeds": list(cfg.eval_world_seeds)},
        "results": results,
        "wall_time_s": round(time.perf_counter() - t0, 1),
    }
    (out / "compare_report.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    (out / "compare_report.md").write_text(format_compare_markdown(report), encoding="utf-8")
    return report


def _f(x: float) -> str:
    return "n/a" if x is None or (isinstance(x, float) and np.isnan(x)) else f"{x:.3f}"


def format_compare_markdown(report: dict) -> str:
    lines = ["# CNN labelling comparison: paper vs matchability", "",
             f"Held-out worlds (seeds): {report['eval_world_seeds']}; training worlds: "
             f"{report['training_world_seeds']}.", "",
             f"Ground truth: {report['ground_truth']}.", f"Decision: {report['decision_rule']}.", ""]
    for ps, res in report["results"].items():
        lines += [f"## Positions: {ps} ({res['n_captures']} captures, false-match rate {res['false_match_rate']:.3f})",
                  "", "| labelling | CNN input | AUC | precision | recall | reject rate | false-match rate after |"
                  " true matches kept |", "|---|---|---|---|---|---|---|---|"]
        for lab, modes in res["models"].items():
            for mode, m in modes.items():
                lines.append(f"| {lab} | {mode} | {_f(m['auc'])} | {_f(m['precision'])} | {_f(m['recall'])} | "
                             f"{_f(m['reject_rate'])} | {_f(m['false_match_rate_after_rejection'])} | "
                             f"{_f(m['true_matches_kept'])} |")
        lines.append("")
    lines.append(f"Wall time: {report['wall_time_s']} s.")
    return "\n".join(lines) + "\n"
