"""The assistant map (paper 5.4, Figure 6): per-pixel probability of a true match.

``probability`` is float32 (H, W), the same size as the reference map: the probability that a capture
taken with the drone above that pixel gives a true match (= 1 - P(class 1, bad area)). NaN = unvisited
/ not classified. Stored as a compressed ``.npz`` (see docs/perception.md for the exact keys), rendered
as a PNG like Figure 6: black = false match expected (p < 0.5), white = true match expected
(p >= 0.5), grey = unvisited; an optional continuous mode shows p as a grey level and unvisited pixels
in blue.

``build_assistant_map`` fills a whole map offline by sliding a camera-footprint crop over the
reference with a stride and classifying the crops in batches (the classifier is injected); given a
``capture`` callable it classifies, per cell, the capture that callable renders over the cell centre
instead (``perception.map_cache``: nadir captures with relief on a world with a DSM).
"""

from __future__ import annotations

import datetime as _dt
import logging
import math
from enum import Enum, IntEnum
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from perception.decision import P_BAD_THRESHOLD, split_classifier_output
from perception.matchability import footprint_px
from scenenav.core.errors import UserError
from scenenav.core.formats.assistant_map_file import AssistantMapFile, read_assistant_map_file, write_assistant_map_file

log = logging.getLogger(__name__)

#: Figure 6 colours (8-bit grey levels).
GREY_FALSE = 0
GREY_TRUE = 255
GREY_UNVISITED = 128
#: Continuous mode: unvisited pixels in this RGB colour (p itself is the grey level).
RGB_UNVISITED_CONTINUOUS = (40, 70, 160)
_U8_MAX = 255.0

ClassifyBatch = Callable[[np.ndarray], np.ndarray]
Progress = Callable[[int, int], None]


class Cell(IntEnum):
    """Values of ``AssistantMap.binary()``."""

    UNVISITED = -1
    FALSE = 0
    TRUE = 1


class RenderMode(str, Enum):
    """PNG rendering of the assistant map."""

    BINARY = "binary"          # Figure 6: black / white / grey
    CONTINUOUS = "continuous"  # grey level = p_true, unvisited in blue


def _utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


class AssistantMap:
    """Probability of a true match per reference-map pixel (NaN = unvisited)."""

    def __init__(self, width_px: int, height_px: int, m_per_px: float, *, world_name: str = "",
                 method: str = "", stride_px: int = 0, model_id: str = "",
                 probability: np.ndarray | None = None, created_utc: str | None = None) -> None:
        if int(width_px) < 1 or int(height_px) < 1:
            raise ValueError(f"assistant map size {width_px}x{height_px}: expected positive")
        if not (math.isfinite(m_per_px) and m_per_px > 0.0):
            raise ValueError(f"m_per_px = {m_per_px!r}: expected a positive number")
        self.width_px = int(width_px)
        self.height_px = int(height_px)
        self.m_per_px = float(m_per_px)
        self.world_name = str(world_name)
        self.method = str(method)
        self.stride_px = int(stride_px)
        self.model_id = str(model_id)
        self.created_utc = created_utc or _utc_now()
        if probability is None:
            self.probability = np.full((self.height_px, self.width_px), np.nan, dtype=np.float32)
        else:
            if probability.shape != (self.height_px, self.width_px):
                raise ValueError(f"probability shape {probability.shape}: expected "
                                 f"({self.height_px}, {self.width_px})")
            self.probability = np.ascontiguousarray(probability, dtype=np.float32)

    @classmethod
    def empty(cls, width_px: int, height_px: int, m_per_px: float, **metadata: str | int) -> AssistantMap:
        """An all-unvisited map (keyword metadata: world_name, method, stride_px, model_id)."""
        return cls(width_px, height_px, m_per_px, **metadata)

    def copy(self) -> AssistantMap:
        """An independent copy (probabilities and metadata), e.g. to fly the same map twice."""
        return AssistantMap(self.width_px, self.height_px, self.m_per_px, world_name=self.world_name,
                            method=self.method, stride_px=self.stride_px, model_id=self.model_id,
                            probability=self.probability.copy(), created_utc=self.created_utc)

    # ------------------------------------------------------------------------------ access
    def _index(self, u: float, v: float) -> tuple[int, int] | None:
        if not (math.isfinite(u) and math.isfinite(v)):
            return None
        c, r = int(math.floor(u)), int(math.floor(v))
        if 0 <= c < self.width_px and 0 <= r < self.height_px:
            return c, r
        return None

    def lookup(self, u: float, v: float) -> float:
        """p_true at continuous pixel (u, v); NaN when unvisited or outside the map."""
        idx = self._index(u, v)
        if idx is None:
            return float("nan")
        return float(self.probability[idx[1], idx[0]])

    def write_patch(self, u: float, v: float, side_px: float, prob: float) -> None:
        """Write ``prob`` (p_true) over a square patch of ``side_px`` (rounded, >= 1) centred on the
        pixel containing (u, v), clipped to the map. Overwrites earlier values (paper 5.4: overlaying
        is a recalculation from the newer classification)."""
        if not (math.isfinite(prob) and 0.0 <= prob <= 1.0):
            raise ValueError(f"prob = {prob!r}: expected a probability in [0, 1]")
        if not (math.isfinite(u) and math.isfinite(v)):
            return
        side = max(1, int(round(side_px))) if math.isfinite(side_px) else 1
        c, r = int(math.floor(u)), int(math.floor(v))
        c0, r0 = c - side // 2, r - side // 2
        x0, y0 = max(0, c0), max(0, r0)
        x1, y1 = min(self.width_px, c0 + side), min(self.height_px, r0 + side)
        if x1 > x0 and y1 > y0:
            self.probability[y0:y1, x0:x1] = prob

    def coverage(self) -> float:
        """Fraction of pixels with a value (0..1)."""
        return float(np.count_nonzero(~np.isnan(self.probability))) / self.probability.size

    def binary(self, threshold: float = P_BAD_THRESHOLD) -> np.ndarray:
        """int8 map of ``Cell`` values: TRUE where p >= threshold, FALSE below, UNVISITED where NaN."""
        p = self.probability
        out = np.full(p.shape, Cell.UNVISITED, dtype=np.int8)
        known = ~np.isnan(p)
        out[known] = np.where(p[known] >= threshold, Cell.TRUE, Cell.FALSE)
        return out

    # ------------------------------------------------------------------------------ files
    def save(self, path: str | Path) -> Path:
        """Write a compressed .npz (``probability`` + metadata; the format is
        ``scenenav.core.formats.assistant_map_file``). Returns the path written."""
        p = write_assistant_map_file(path, self.to_file())
        log.info("assistant map %s written (%dx%d, coverage %.1f %%)", p, self.width_px,
                 self.height_px, 100.0 * self.coverage())
        return p

    def to_file(self) -> AssistantMapFile:
        """The file content of this map."""
        return AssistantMapFile(probability=self.probability, m_per_px=self.m_per_px,
                                world_name=self.world_name, method=self.method,
                                stride_px=self.stride_px, model_id=self.model_id,
                                created_utc=self.created_utc)

    @classmethod
    def load(cls, path: str | Path, width_px: int | None = None, height_px: int | None = None,
             m_per_px: float | None = None) -> AssistantMap:
        """Read a map written by ``save``. One-line UserError on a missing/wrong file, and when the
        size (or resolution) differs from the expected reference map's."""
        f = read_assistant_map_file(path, width_px, height_px, m_per_px)
        return cls(f.width_px, f.height_px, f.m_per_px, world_name=f.world_name, method=f.method,
                   stride_px=f.stride_px, model_id=f.model_id, probability=f.probability,
                   created_utc=f.created_utc or None)

    def render_image(self, mode: RenderMode = RenderMode.BINARY,
                     threshold: float = P_BAD_THRESHOLD) -> np.ndarray:
        """BINARY: uint8 (H, W) grey levels of Figure 6. CONTINUOUS: uint8 RGB (H, W, 3)."""
        p = self.probability
        known = ~np.isnan(p)
        if mode is RenderMode.BINARY:
            img = np.full(p.shape, GREY_UNVISITED, dtype=np.uint8)
            img[known] = np.where(p[known] >= threshold, GREY_TRUE, GREY_FALSE)
            return img
        img = np.empty(p.shape + (3,), dtype=np.uint8)
        img[:] = np.asarray(RGB_UNVISITED_CONTINUOUS, dtype=np.uint8)
        grey = np.clip(np.rint(p[known] * _U8_MAX), 0, _U8_MAX).astype(np.uint8)
        img[known] = grey[:, None]
        return img

    def render_png(self, path: str | Path, mode: RenderMode = RenderMode.BINARY,
                   threshold: float = P_BAD_THRESHOLD) -> Path:
        """Write the rendering (see ``render_image``) as a PNG."""
        p = Path(path)
        img = self.render_image(mode, threshold)
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{p}: cannot create the directory ({exc.strerror or exc})") from None
        if not cv2.imwrite(str(p), img):
            raise UserError(f"{p}: cannot write the PNG (expected a writable path ending in .png)")
        return p


# ---------------------------------------------------------------------------------- builder
def build_assistant_map(reference_gray: np.ndarray, classify_batch: ClassifyBatch, m_per_px: float,
                        altitude_m: float = 100.0, fov_deg: float = 60.0, stride_px: int = 5,
                        batch_size: int = 64, progress: Progress | None = None, *,
                        cnn_input_px: int = 200, fill_edges: bool = False, world_name: str = "",
                        model_id: str = "", method: str = "offline",
                        capture: Callable[[float, float], np.ndarray] | None = None) -> AssistantMap:
    """Classify every stride cell of the reference and fill an assistant map.

    The map is cut into ``stride_px`` x ``stride_px`` cells. For each cell, the camera footprint at
    ``altitude_m`` (side ``floor(2 h tan(fov/2) / m_per_px)`` px, north-up) centred on the cell centre is
    cropped from the reference, resized to ``cnn_input_px`` and classified; the cell's pixels get
    p_true = 1 - P(bad). Cells whose footprint does not fit inside the map (a band of about half a
    footprint along the edges) stay NaN, or with ``fill_edges`` take the value of the nearest
    classified cell. ``classify_batch`` gets (N, cnn_input_px, cnn_input_px) float32 grey in [0, 1]
    and returns (N,) P(bad) or (N, K) class probabilities (column 0 = bad).
    ``progress(done, total)`` is called after each batch. ``capture(u, v)``, when given, returns the
    (cnn_input_px, cnn_input_px) float32 grey image classified for the cell centred on continuous
    pixel (u, v) in place of the reference crop (the same cells are classified).
    """
    if not isinstance(reference_gray, np.ndarray) or reference_gray.ndim != 2:
        raise ValueError("reference_gray: expected a 2-D grey image")
    if reference_gray.dtype not in (np.uint8, np.float32):
        raise ValueError(f"reference_gray dtype {reference_gray.dtype}: expected uint8 or float32")
    if int(stride_px) < 1 or int(batch_size) < 1 or int(cnn_input_px) < 1:
        raise ValueError("stride_px, batch_size and cnn_input_px must be positive integers")
    h, w = reference_gray.shape
    stride = int(stride_px)
    fp = footprint_px(altitude_m, fov_deg, m_per_px)
    n_rows, n_cols = math.ceil(h / stride), math.ceil(w / stride)
    cells = np.full((n_rows, n_cols), np.nan, dtype=np.float32)

    # Cell centres (continuous pixels, the clipped last cell included) and their footprint corners.
    cu = np.minimum(np.arange(n_cols) * stride + stride / 2.0,
                    (np.arange(n_cols) * stride + w) / 2.0)
    cv = np.minimum(np.arange(n_rows) * stride + stride / 2.0,
                    (np.arange(n_rows) * stride + h) / 2.0)
    x0s = np.rint(cu - fp / 2.0).astype(np.int64)
    y0s = np.rint(cv - fp / 2.0).astype(np.int64)
    cols = np.nonzero((x0s >= 0) & (x0s + fp <= w))[0]
    rows = np.nonzero((y0s >= 0) & (y0s + fp <= h))[0]
    total = int(cols.size * rows.size)
    if total == 0:
        log.warning("footprint %d px does not fit in the %dx%d map: assistant map left empty", fp, w, h)
    to_unit = np.float32(1.0 / 255.0) if reference_gray.dtype == np.uint8 else np.float32(1.0)
    interp = cv2.INTER_AREA if fp >= cnn_input_px else cv2.INTER_LINEAR
    batch = np.empty((int(batch_size), cnn_input_px, cnn_input_px), dtype=np.float32)
    where: list[tuple[int, int]] = []
    done = 0

    def flush() -> None:
        nonlocal done
        n = len(where)
        if n == 0:
            return
        p_bad, _ = split_classifier_output(classify_batch(batch[:n]), n)
        for (r, c), pb in zip(where, p_bad, strict=False):
            cells[r, c] = 1.0 - pb
        done += n
        where.clear()
        if progress is not None:
            progress(done, total)

    for r in rows:
        y0 = int(y0s[r])
        for c in cols:
            x0 = int(x0s[c])
            if capture is not None:
                batch[len(where)] = capture(float(cu[c]), float(cv[r]))
            else:
                crop = reference_gray[y0:y0 + fp, x0:x0 + fp]
                if fp != cnn_input_px:
                    crop = cv2.resize(crop, (cnn_input_px, cnn_input_px), interpolation=interp)
                np.multiply(crop, to_unit, out=batch[len(where)], casting="unsafe")
            where.append((int(r), int(c)))
            if len(where) == batch.shape[0]:
                flush()
    flush()

    if fill_edges and total:
        from scipy.ndimage import distance_transform_edt

        idx = distance_transform_edt(np.isnan(cells), return_distances=False, return_indices=True)
        cells = cells[tuple(idx)]
    prob = np.repeat(np.repeat(cells, stride, axis=0), stride, axis=1)[:h, :w]
    amap = AssistantMap(w, h, m_per_px, world_name=world_name, method=method, stride_px=stride,
                        model_id=model_id, probability=np.ascontiguousarray(prob))
    log.info("assistant map built: %d crops of %d px, stride %d px, coverage %.1f %%", total, fp,
             stride, 100.0 * amap.coverage())
    return amap
