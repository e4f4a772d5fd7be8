"""The paper's good/bad matching-area CNN (section 5.1) and a NumPy-facing classifier wrapper.

Architecture (the paper's Figure 5 / section 5.1, our exact reading; see docs/cnn.md):

    input 1 x P x P grayscale (P = 48 by default; the paper uses 200)
    conv 3x3, 64 kernels, 'valid' padding (the Keras default) + ReLU
    average-pool 2x2
    conv 3x3, 32 kernels, 'valid' padding + ReLU
    average-pool 2x2
    flatten
    fully connected 128 + ReLU  -> dropout 0.5      (fully connected layer 1, dropout layer 1)
    fully connected 64  + ReLU  -> dropout 0.5      (fully connected layer 2, dropout layer 2)
    output layer: 4 units with softmax               (the paper's "final output layer")

``SceneMatchNet.forward`` returns the 4 logits (cross-entropy on logits is softmax + log-loss);
``MatchClassifier.predict_proba`` applies the softmax.

Input normalisation: images are float32 grayscale in [0, 1]; inside the classifier they are
resized to P x P with ``cv2.INTER_AREA`` (any h, w; non-square inputs are stretched) and mapped
affinely with ``(x - INPUT_MEAN) / INPUT_STD`` = ``(x - 0.5) / 0.25``. No per-image
standardisation: the absolute contrast of a crop is part of what tells a flat lake from a junction.
"""

from __future__ import annotations

import logging
import pickle
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch import nn

from perception.cnn_spec import (
    CONV1_KERNELS,
    CONV2_KERNELS,
    DEFAULT_INPUT_PX,
    DROPOUT_P,
    FC1_UNITS,
    FC2_UNITS,
    INPUT_MEAN,
    INPUT_STD,
    KERNEL_PX,
    NUM_CLASSES,
    POOL_PX,
    MatchClass,
    check_input_px,
    feature_side_px,
)
from perception.shipped import DEFAULT_WEIGHTS_PATH, WEIGHTS_DIR  # noqa: F401  (re-exported)
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

DEFAULT_BATCH_SIZE = 16
"""Inference chunk: at 48 px, chunks of <= 16 crops stay in cache (~0.6 ms/crop on one core, ~1.3 ms at 32+)."""
RESIZE_BLOCK = 512
"""Crops resized per block in ``predict_proba`` (P x P float32 each, ~4.6 MB at 48 px)."""
WEIGHTS_FORMAT_VERSION = 1


class SceneMatchNet(nn.Module):
    """The paper's CNN (section 5.1). ``forward`` returns logits (N, 4); softmax is the output layer."""

    def __init__(self, input_px: int = DEFAULT_INPUT_PX) -> None:
        super().__init__()
        check_input_px(input_px)
        self.input_px = input_px
        side = feature_side_px(input_px)
        self.conv1 = nn.Conv2d(1, CONV1_KERNELS, KERNEL_PX)
        self.pool1 = nn.AvgPool2d(POOL_PX)
        self.conv2 = nn.Conv2d(CONV1_KERNELS, CONV2_KERNELS, KERNEL_PX)
        self.pool2 = nn.AvgPool2d(POOL_PX)
        self.flatten = nn.Flatten()
        self.fc1 = nn.Linear(CONV2_KERNELS * side * side, FC1_UNITS)
        self.dropout1 = nn.Dropout(DROPOUT_P)
        self.fc2 = nn.Linear(FC1_UNITS, FC2_UNITS)
        self.dropout2 = nn.Dropout(DROPOUT_P)
        self.output = nn.Linear(FC2_UNITS, NUM_CLASSES)
        self.relu = nn.ReLU()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.pool1(self.relu(self.conv1(x)))
        x = self.pool2(self.relu(self.conv2(x)))
        x = self.flatten(x)
        x = self.dropout1(self.relu(self.fc1(x)))
        x = self.dropout2(self.relu(self.fc2(x)))
        return self.output(x)

    def layer_table(self) -> list[tuple[str, str, tuple[int, ...], int]]:
        """(name, kind, output shape without batch, parameter count) for every layer, for docs/info."""
        rows: list[tuple[str, str, tuple[int, ...], int]] = []
        x = torch.zeros(1, 1, self.input_px, self.input_px)
        rows.append(("input", "grayscale", tuple(x.shape[1:]), 0))
        with torch.no_grad():
            for name in ("conv1", "relu", "pool1", "conv2", "relu", "pool2", "flatten", "fc1", "relu",
                         "dropout1", "fc2", "relu", "dropout2", "output"):
                mod = getattr(self, name)
                x = mod(x)
                n_par = sum(p.numel() for p in mod.parameters()) if name != "relu" else 0
                rows.append((name, type(mod).__name__, tuple(x.shape[1:]), n_par))
        rows.append(("softmax", "Softmax", (NUM_CLASSES,), 0))
        return rows


def normalise(batch: np.ndarray, input_px: int) -> np.ndarray:
    """(N, h, w) or (h, w) float in [0, 1] -> (N, 1, P, P) float32 network input (resize + affine)."""
    arr = np.asarray(batch)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"expected an (N, h, w) grayscale batch, got shape {arr.shape}")
    if arr.dtype == np.uint8:
        arr = arr.astype(np.float32) / 255.0
    n, h, w = arr.shape
    if (h, w) == (input_px, input_px):
        out = arr.astype(np.float32, copy=True)
    else:
        out = np.empty((n, input_px, input_px), np.float32)
        interp = cv2.INTER_AREA if (h >= input_px and w >= input_px) else cv2.INTER_LINEAR
        for i in range(n):
            out[i] = cv2.resize(np.ascontiguousarray(arr[i], dtype=np.float32), (input_px, input_px),
                                interpolation=interp)
    out -= INPUT_MEAN
    out /= INPUT_STD
    return out[:, None]


@dataclass(frozen=True)
class WeightsMeta:
    """Metadata stored beside the state_dict in a weights file."""

    input_px: int
    classes: tuple[str, ...]
    labelling: str
    training_record_id: str
    format_version: int = WEIGHTS_FORMAT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"input_px": self.input_px, "classes": list(self.classes), "labelling": self.labelling,
                "training_record_id": self.training_record_id, "format_version": self.format_version,
                "extra": dict(self.extra)}


def save_weights(model: SceneMatchNet, path: str | Path, meta: WeightsMeta) -> Path:
    """Write ``{"state_dict", "meta"}`` to ``path`` (loadable with ``torch.load(weights_only=True)``)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().clone().contiguous() for k, v in model.state_dict().items()}
    torch.save({"state_dict": state, "meta": meta.to_dict()}, p)
    return p


def load_weights(path: str | Path) -> tuple[SceneMatchNet, WeightsMeta]:
    """Read a weights file written by ``save_weights``; one-line UserError on any problem."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such weights file (expected a .pt written by `scenenav train`)")
    try:
        blob = torch.load(p, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError, EOFError, pickle.UnpicklingError) as exc:
        raise UserError(f"{p}: not a readable weights file ({type(exc).__name__})") from None
    if not isinstance(blob, dict) or "state_dict" not in blob or "meta" not in blob:
        raise UserError(f"{p}: expected a dict with 'state_dict' and 'meta' (a `scenenav train` output)")
    m = blob["meta"]
    try:
        meta = WeightsMeta(input_px=int(m["input_px"]), classes=tuple(m["classes"]),
                           labelling=str(m["labelling"]), training_record_id=str(m["training_record_id"]),
                           format_version=int(m.get("format_version", WEIGHTS_FORMAT_VERSION)),
                           extra=dict(m.get("extra", {})))
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{p}: weights metadata is incomplete ({exc})") from None
    if meta.classes != tuple(c.name for c in MatchClass):
        raise UserError(f"{p}: classes {list(meta.classes)}: expected {[c.name for c in MatchClass]}")
    model = SceneMatchNet(meta.input_px)
    try:
        model.load_state_dict(blob["state_dict"])
    except RuntimeError as exc:
        first = str(exc).splitlines()[0]
        raise UserError(f"{p}: state_dict does not fit the paper CNN at {meta.input_px} px ({first})") from None
    model.eval()
    return model, meta


class MatchClassifier:
    """Inference wrapper: NumPy grayscale crops in, class probabilities out (eval mode, inference_mode).

    ``num_threads`` calls ``torch.set_num_threads`` (process-wide in torch) when given.
    """

    def __init__(self, model: SceneMatchNet, meta: WeightsMeta, num_threads: int | None = None,
                 batch_size: int = DEFAULT_BATCH_SIZE) -> None:
        if num_threads is not None:
            if num_threads < 1:
                raise UserError(f"num_threads = {num_threads}: expected a positive integer")
            torch.set_num_threads(num_threads)
        if batch_size < 1:
            raise UserError(f"batch_size = {batch_size}: expected a positive integer")
        self.model = model.eval()
        self.meta = meta
        self.batch_size = batch_size

    @property
    def input_px(self) -> int:
        return self.meta.input_px

    @classmethod
    def from_file(cls, path: str | Path, num_threads: int | None = None,
                  batch_size: int = DEFAULT_BATCH_SIZE) -> "MatchClassifier":
        model, meta = load_weights(path)
        log.info("loaded CNN weights %s (input %d px, labelling %s, record %s)", path, meta.input_px,
                 meta.labelling, meta.training_record_id)
        return cls(model, meta, num_threads=num_threads, batch_size=batch_size)

    @classmethod
    def default(cls, num_threads: int | None = None,
                batch_size: int = DEFAULT_BATCH_SIZE) -> "MatchClassifier":
        """The shipped weights, ``perception/weights/default.pt``."""
        return cls.from_file(DEFAULT_WEIGHTS_PATH, num_threads=num_threads, batch_size=batch_size)

    def predict_proba(self, batch: np.ndarray) -> np.ndarray:
        """(N, h, w) float32 grayscale in [0, 1] (or a single (h, w)) -> (N, 4) softmax probabilities.

        Rows follow ``MatchClass`` order; processed in chunks of ``batch_size``.
        """
        arr = np.asarray(batch)
        if arr.ndim == 2:
            arr = arr[None]
        n = arr.shape[0]
        out = np.empty((n, NUM_CLASSES), np.float32)
        bs = self.batch_size
        with torch.inference_mode():
            # Resize a block first, then run the network on small chunks: big crops streaming through
            # the cache between network chunks would double the per-crop time.
            for start in range(0, n, RESIZE_BLOCK):
                x = torch.from_numpy(normalise(arr[start:start + RESIZE_BLOCK], self.input_px))
                for k in range(0, x.shape[0], bs):
                    out[start + k:start + k + bs] = torch.softmax(self.model(x[k:k + bs]), dim=1).numpy()
        return out

    def p_bad(self, batch: np.ndarray) -> np.ndarray:
        """(N,) probability of ``MatchClass.BAD`` (the paper's class 1)."""
        return self.predict_proba(batch)[:, MatchClass.BAD]

    def predict(self, batch: np.ndarray) -> np.ndarray:
        """(N,) most likely ``MatchClass`` index."""
        return np.argmax(self.predict_proba(batch), axis=1)


def benchmark(classifier: MatchClassifier, crop_px: int = 217, n_batch: int = 1000, repeats: int = 3,
              seed: int = 0) -> dict[str, float]:
    """Inference timings: one image (median of 50 calls) and a batch of ``n_batch`` random crops of
    ``crop_px`` (resize inside included; best and median of ``repeats`` passes, the machine is shared)."""
    rng = np.random.default_rng(seed)
    one = rng.random((1, crop_px, crop_px), dtype=np.float32)
    for _ in range(5):
        classifier.predict_proba(one)
    times = []
    for _ in range(50):
        t0 = time.perf_counter()
        classifier.predict_proba(one)
        times.append(time.perf_counter() - t0)
    batch = rng.random((n_batch, crop_px, crop_px), dtype=np.float32)
    passes = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        classifier.predict_proba(batch)
        passes.append(time.perf_counter() - t0)
    best, med = min(passes), float(np.median(passes))
    return {"single_image_ms": float(np.median(times) * 1000.0), "batch_n": float(n_batch),
            "batch_ms_per_image": best / n_batch * 1000.0, "batch_ms_per_image_median": med / n_batch * 1000.0,
            "projected_36k_crops_s": best / n_batch * 36000.0,
            "projected_36k_crops_s_median": med / n_batch * 36000.0,
            "threads": float(torch.get_num_threads())}
