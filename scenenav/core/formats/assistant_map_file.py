"""The assistant-map file (``.npz``): per-pixel probability of a true match, plus metadata.

Written by perception (``perception.assistant_map.AssistantMap.save``, the ``scenenav
assistant-map build`` command, the perception node at the end of a run), read by perception and by
guidance (the planner). Keys (docs/perception.md):

* ``probability``: float32 (H, W), the size of the reference map; NaN = unvisited;
* ``format_version`` (int, 1), ``width_px``, ``height_px``, ``stride_px`` (int), ``m_per_px``
  (float), ``world_name``, ``created_utc``, ``method``, ``model_id`` (str).

A whole-world map is built with a stride (the spacing of the cells the CNN rates) chosen in metres
of ground, ``stride_m``, and converted per world to whole map pixels (:func:`stride_px_for`): every
world gets the same ground spacing whatever its m/px; the file keeps the pixel stride used.

Two readers: :func:`read_assistant_map_file` for files written by :func:`write_assistant_map_file`
(every key required, sizes checked), and :func:`read_probability_map` for any ``.npz`` holding a
``probability`` grid (metadata optional: the planner accepts grids made by other tools). Errors are
one-line :class:`scenenav.core.errors.UserError`.
"""

from __future__ import annotations

import logging
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenenav.core.config import check, is_finite_number
from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import WorldManifest
from scenenav.core.frames import metres_to_whole_px

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
PROBABILITY_KEY = "probability"
_META_STR = ("world_name", "created_utc", "method", "model_id")
_META_INT = ("width_px", "height_px", "stride_px", "format_version")
_META_FLOAT = ("m_per_px",)
# Relative tolerance when comparing m_per_px of the map metadata and of the world manifest.
_SCALE_RTOL = 1e-6

# Stride of a whole-world map, metres of ground. The defaults are the pixel strides used before the
# stride was a ground distance, times the default world's 0.53 m/px (worlds.city_config.CityConfig),
# so the default world keeps its pixel strides, its cached maps and their cache keys:
WORLD_MAP_STRIDE_M = 5.3    # 10 px: the cached map guidance plans over (perception.map_cache)
BUILD_STRIDE_M = 2.65       # 5 px: `scenenav assistant-map build`
# A sanity bound: the camera footprint is ~115 m at 100 m height, 1155 m at the builder's 1000 m
# limit; cells farther apart than that rate little of the world.
MAX_STRIDE_M = 1000.0


def check_stride_m(stride_m: float, key: str = "stride_m") -> None:
    """One-line error (``ConfigError``, a ``UserError``) unless ``stride_m`` is a usable stride."""
    check(is_finite_number(stride_m) and 0.0 < stride_m <= MAX_STRIDE_M, key, stride_m,
          f"a ground distance in metres, > 0 and at most {MAX_STRIDE_M:g}")


def stride_px_for(stride_m: float, m_per_px: float, key: str = "stride_m") -> int:
    """The stride in whole pixels of a world at ``m_per_px``: the nearest, at least 1 px (5.3 m at
    0.53 m/px -> 10 px; at 0.25 m/px -> 21 px). ``key`` names the value in the error."""
    check_stride_m(stride_m, key)
    return metres_to_whole_px(stride_m, m_per_px)


@dataclass(frozen=True)
class AssistantMapFile:
    """The content of an assistant-map file (``probability`` is float32 (H, W), NaN = unvisited)."""

    probability: np.ndarray
    m_per_px: float
    world_name: str = ""
    method: str = ""
    stride_px: int = 0
    model_id: str = ""
    created_utc: str = ""

    @property
    def width_px(self) -> int:
        """Map width (columns)."""
        return int(self.probability.shape[1])

    @property
    def height_px(self) -> int:
        """Map height (rows)."""
        return int(self.probability.shape[0])


def write_assistant_map_file(path: str | Path, amap: AssistantMapFile) -> Path:
    """Write a compressed .npz (``.npz`` appended when missing). Returns the path written."""
    p = Path(path)
    if p.suffix != ".npz":
        p = p.with_suffix(p.suffix + ".npz") if p.suffix else p.with_suffix(".npz")
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            p, probability=amap.probability, format_version=np.int64(FORMAT_VERSION),
            world_name=np.str_(amap.world_name), width_px=np.int64(amap.width_px),
            height_px=np.int64(amap.height_px), m_per_px=np.float64(amap.m_per_px),
            created_utc=np.str_(amap.created_utc), method=np.str_(amap.method),
            stride_px=np.int64(amap.stride_px), model_id=np.str_(amap.model_id))
    except OSError as exc:
        raise UserError(f"{p}: cannot write the assistant map ({exc.strerror or exc})") from None
    return p


def read_assistant_map_file(path: str | Path, width_px: int | None = None,
                            height_px: int | None = None,
                            m_per_px: float | None = None) -> AssistantMapFile:
    """Read a file written by :func:`write_assistant_map_file`. One-line UserError on a missing or
    wrong file, and when the size (or resolution) differs from the expected reference map's."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such file (expected an assistant map .npz)")
    try:
        with np.load(p, allow_pickle=False) as data:
            fields = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise UserError(f"{p}: not a readable .npz assistant map ({type(exc).__name__})") from None
    missing = [k for k in (PROBABILITY_KEY, *_META_INT, *_META_FLOAT) if k not in fields]
    if missing:
        raise UserError(f"{p}: not an assistant map (missing '{missing[0]}'; expected the keys "
                        f"written by AssistantMap.save)")
    try:
        ints = {k: int(fields[k]) for k in _META_INT}
        scale = float(fields["m_per_px"])
        strs = {k: str(fields[k]) if k in fields else "" for k in _META_STR}
    except (TypeError, ValueError):
        raise UserError(f"{p}: assistant map metadata is malformed") from None
    if ints["format_version"] != FORMAT_VERSION:
        raise UserError(f"{p}: assistant map format_version {ints['format_version']}: expected "
                        f"{FORMAT_VERSION}")
    prob = fields[PROBABILITY_KEY]
    if prob.ndim != 2 or prob.dtype != np.float32:
        raise UserError(f"{p}: probability is {prob.dtype} {prob.shape}: expected float32 (H, W)")
    h, w = prob.shape
    if (w, h) != (ints["width_px"], ints["height_px"]):
        raise UserError(f"{p}: probability is {w}x{h} px but the metadata says "
                        f"{ints['width_px']}x{ints['height_px']} px")
    if (width_px is not None and w != width_px) or (height_px is not None and h != height_px):
        raise UserError(f"{p}: assistant map is {w}x{h} px: expected {width_px}x{height_px} px "
                        f"(the size of the reference map)")
    if m_per_px is not None and not math.isclose(scale, m_per_px, rel_tol=1e-6):
        raise UserError(f"{p}: assistant map resolution {scale} m/px: expected "
                        f"{m_per_px} m/px (the reference map's)")
    known = prob[~np.isnan(prob)]
    if known.size and (known.min() < 0.0 or known.max() > 1.0):
        raise UserError(f"{p}: probability values outside [0, 1]")
    return AssistantMapFile(probability=prob, m_per_px=scale, world_name=strs["world_name"],
                            method=strs["method"], stride_px=ints["stride_px"],
                            model_id=strs["model_id"], created_utc=strs["created_utc"])


@dataclass(frozen=True)
class ProbabilityMap:
    """A probability grid from any ``.npz`` (key ``probability``) and the scalar metadata found
    beside it (may be empty; e.g. ``width_px``/``width``, ``m_per_px``, ``world_name``)."""

    probability: np.ndarray
    metadata: dict[str, object] = field(default_factory=dict)


def _scalar(value: np.ndarray) -> object:
    arr = np.asarray(value)
    if arr.ndim == 0:
        return arr.item()
    return None


def read_probability_map(path: str | Path) -> ProbabilityMap:
    """Read any ``.npz`` with a 2-D float ``probability`` array (the planner's input)."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"--assistant-map {p}: no such file; expected an assistant map .npz")
    try:
        with np.load(p, allow_pickle=False) as npz:
            if PROBABILITY_KEY not in npz.files:
                raise UserError(f"{p}: no 'probability' array (found {', '.join(npz.files) or 'nothing'}); "
                                "expected an assistant map .npz")
            prob = npz[PROBABILITY_KEY]
            meta = {k: _scalar(npz[k]) for k in npz.files if k != PROBABILITY_KEY}
    except UserError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise UserError(f"{p}: cannot read as .npz ({type(exc).__name__}: {exc}); "
                        "expected an assistant map written by numpy.savez") from None
    if prob.ndim != 2:
        raise UserError(f"{p}: probability has shape {prob.shape}; expected a 2-D H x W array")
    if not np.issubdtype(prob.dtype, np.floating):
        raise UserError(f"{p}: probability has dtype {prob.dtype}; expected float32 with NaN = unvisited")
    return ProbabilityMap(probability=prob, metadata={k: v for k, v in meta.items() if v is not None})


def check_map_matches_world(amap: ProbabilityMap, world: WorldManifest, map_path: str | Path) -> None:
    """The map must have the world's size (and scale, if its metadata says)."""
    h, w = amap.probability.shape
    if (w, h) != (world.width_px, world.height_px):
        raise UserError(f"--assistant-map {map_path}: probability is {w}x{h} px (W x H) but world "
                        f"'{world.name}' is {world.width_px}x{world.height_px} px; expected a map of this world")
    meta = amap.metadata
    for key, want in (("width", world.width_px), ("height", world.height_px)):
        value = meta.get(key)
        if isinstance(value, (int, float)) and int(value) != want:
            raise UserError(f"--assistant-map {map_path}: metadata {key} = {value} but world "
                            f"'{world.name}' has {want} px; expected a map of this world")
    scale = meta.get("m_per_px")
    if isinstance(scale, (int, float)) and not math.isclose(float(scale), world.m_per_px, rel_tol=_SCALE_RTOL):
        raise UserError(f"--assistant-map {map_path}: m_per_px = {scale} but world '{world.name}' has "
                        f"{world.m_per_px}; expected a map of this world")
    name = meta.get("world_name")
    if isinstance(name, str) and name and name != world.name:
        log.warning("assistant map says world_name=%r, world manifest says %r", name, world.name)
