"""World files: a folder with a manifest, the orthophoto, the reference map and ground truth.

Layout of a world folder (see docs/worlds.md)::

    manifest.json    WorldManifest (format version, size, resolution, geodetic origin, provenance)
    orthophoto.png   (H, W, 3) 8-bit RGB: the ground the drone camera sees
    reference.png    (H, W, 3) 8-bit RGB: the reference map, same area "on another day"
    landcover.png    (H, W) 8-bit grey, LandCover values (only when has_landcover)
    junctions.json   list of {u_px, v_px, arms, kind} (only when has_junctions)

Loading raises :class:`scenenav.errors.UserError` with a one-line message for anything missing or
malformed.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path

import cv2
import numpy as np

from scenenav.errors import UserError
from worlds import frames
from worlds.landcover import Junction, LandCover

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
MANIFEST_FILE = "manifest.json"
ORTHOPHOTO_FILE = "orthophoto.png"
REFERENCE_FILE = "reference.png"
LANDCOVER_FILE = "landcover.png"
JUNCTIONS_FILE = "junctions.json"

#: PNG zlib level: 1 keeps 8000x8000 saves fast; files are still lossless.
PNG_COMPRESSION_LEVEL = 1

CONVENTIONS = (
    "pixels: continuous (u, v) = (column, row), pixel (c, r) covers [c, c+1) x [r, r+1), row 0 north; "
    "world: ENU metres, origin at map centre (u, v) = (W/2, H/2), x = (u - W/2) * m_per_px, "
    "y = (H/2 - v) * m_per_px; geodetic origin (origin_lat_deg, origin_lon_deg) at the map centre, "
    "WGS-84 local tangent plane; images RGB uint8; landcover uint8 LandCover values"
)


class WorldSource(str, Enum):
    """Where a world came from."""

    GENERATED = "generated"
    IMPORTED = "imported"


class GroundTruth(str, Enum):
    """Names used in ``WorldManifest.missing_ground_truth``."""

    LANDCOVER = "landcover"
    JUNCTIONS = "junctions"
    GEODETIC_ORIGIN = "geodetic_origin"


@dataclass(frozen=True)
class WorldManifest:
    """Metadata of a world folder (``manifest.json``)."""

    format_version: int
    name: str
    width_px: int
    height_px: int
    m_per_px: float
    origin_lat_deg: float
    origin_lon_deg: float
    source: str
    seed: int | None
    has_landcover: bool
    has_junctions: bool
    missing_ground_truth: tuple[str, ...] = ()
    conventions: str = CONVENTIONS
    # generator parameters (generated worlds only); not part of the hash
    generator: dict = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "missing_ground_truth", tuple(self.missing_ground_truth))

    def to_dict(self) -> dict:
        data = asdict(self)
        data["missing_ground_truth"] = list(self.missing_ground_truth)
        return data

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=False) + "\n"

    @classmethod
    def from_json(cls, text: str, where: str = MANIFEST_FILE) -> "WorldManifest":
        """Parse and validate; raises UserError naming ``where`` and the offending key."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise UserError(f"{where}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
        if not isinstance(data, dict):
            raise UserError(f"{where}: expected a JSON object at the top level")
        return cls.from_dict(data, where)

    @classmethod
    def from_dict(cls, data: dict, where: str = MANIFEST_FILE) -> "WorldManifest":
        def need(key: str, kinds: tuple[type, ...], expected: str):
            if key not in data:
                raise UserError(f"{where}: missing key '{key}' (expected {expected})")
            value = data[key]
            if isinstance(value, bool) and bool not in kinds:
                raise UserError(f"{where}: {key} = {value!r}: expected {expected}")
            if not isinstance(value, kinds):
                raise UserError(f"{where}: {key} = {value!r}: expected {expected}")
            return value

        version = need("format_version", (int,), "an integer")
        if version != FORMAT_VERSION:
            raise UserError(f"{where}: format_version = {version}: expected {FORMAT_VERSION}")
        name = need("name", (str,), "a string")
        width = need("width_px", (int,), "a positive integer")
        height = need("height_px", (int,), "a positive integer")
        if width <= 0 or height <= 0:
            raise UserError(f"{where}: width_px/height_px = {width}x{height}: expected positive integers")
        m_per_px = float(need("m_per_px", (int, float), "a positive number"))
        if not (math.isfinite(m_per_px) and m_per_px > 0):
            raise UserError(f"{where}: m_per_px = {m_per_px!r}: expected a positive number")
        lat = float(need("origin_lat_deg", (int, float), "a latitude in degrees"))
        lon = float(need("origin_lon_deg", (int, float), "a longitude in degrees"))
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise UserError(f"{where}: origin = {lat}, {lon}: expected latitude in [-90, 90] "
                            f"and longitude in [-180, 180] degrees")
        source = need("source", (str,), "'generated' or 'imported'")
        if source not in {s.value for s in WorldSource}:
            raise UserError(f"{where}: source = {source!r}: expected 'generated' or 'imported'")
        seed = data.get("seed")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise UserError(f"{where}: seed = {seed!r}: expected an integer or null")
        has_lc = need("has_landcover", (bool,), "true or false")
        has_jn = need("has_junctions", (bool,), "true or false")
        missing = data.get("missing_ground_truth", [])
        if not isinstance(missing, list) or not all(isinstance(m, str) for m in missing):
            raise UserError(f"{where}: missing_ground_truth = {missing!r}: expected a list of strings")
        conventions = data.get("conventions", CONVENTIONS)
        if not isinstance(conventions, str):
            raise UserError(f"{where}: conventions: expected a string")
        generator = data.get("generator", {})
        if not isinstance(generator, dict):
            raise UserError(f"{where}: generator: expected an object")
        return cls(format_version=version, name=name, width_px=width, height_px=height,
                   m_per_px=m_per_px, origin_lat_deg=lat, origin_lon_deg=lon, source=source,
                   seed=seed, has_landcover=has_lc, has_junctions=has_jn,
                   missing_ground_truth=tuple(missing), conventions=conventions,
                   generator=generator)


@dataclass(eq=False)
class World:
    """An orthophoto, its reference map and (for generated worlds) ground truth."""

    manifest: WorldManifest
    orthophoto: np.ndarray
    reference: np.ndarray
    landcover: np.ndarray | None = None
    junctions: tuple[Junction, ...] | None = None

    def __post_init__(self) -> None:
        shape = (self.manifest.height_px, self.manifest.width_px)
        for label, img in (("orthophoto", self.orthophoto), ("reference", self.reference)):
            if img.dtype != np.uint8 or img.shape != shape + (3,):
                raise ValueError(f"{label}: expected uint8 {shape + (3,)}, got {img.dtype} {img.shape}")
        if self.landcover is not None and (self.landcover.dtype != np.uint8
                                           or self.landcover.shape != shape):
            raise ValueError(f"landcover: expected uint8 {shape}, got "
                             f"{self.landcover.dtype} {self.landcover.shape}")
        if self.junctions is not None:
            self.junctions = tuple(self.junctions)

    @property
    def width_px(self) -> int:
        return self.manifest.width_px

    @property
    def height_px(self) -> int:
        return self.manifest.height_px

    @property
    def m_per_px(self) -> float:
        return self.manifest.m_per_px

    def world_to_pixel(self, x_m, y_m):
        """World ENU metres -> continuous pixel (u, v); see worlds/frames.py."""
        return frames.world_to_pixel(x_m, y_m, self.width_px, self.height_px, self.m_per_px)

    def pixel_to_world(self, u, v):
        """Continuous pixel (u, v) -> world ENU metres (x, y); see worlds/frames.py."""
        return frames.pixel_to_world(u, v, self.width_px, self.height_px, self.m_per_px)

    def save(self, directory) -> None:
        """Write the world folder (created if needed; existing world files are overwritten)."""
        d = Path(directory)
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"{d}: cannot create the world folder ({exc.strerror})") from None
        _write_rgb(d / ORTHOPHOTO_FILE, self.orthophoto)
        _write_rgb(d / REFERENCE_FILE, self.reference)
        if self.landcover is not None:
            _write_png(d / LANDCOVER_FILE, self.landcover)
        else:
            _remove_stale(d / LANDCOVER_FILE)
        if self.junctions is not None:
            text = json.dumps([j.to_dict() for j in self.junctions], indent=1) + "\n"
            _write_text(d / JUNCTIONS_FILE, text)
        else:
            _remove_stale(d / JUNCTIONS_FILE)
        # The manifest goes last: a folder with a manifest is complete.
        _write_text(d / MANIFEST_FILE, self.manifest.to_json())
        log.info("saved world %r (%dx%d px) to %s", self.manifest.name, self.width_px,
                 self.height_px, d)

    @classmethod
    def load(cls, directory) -> "World":
        """Read a world folder; raises UserError (one line) for anything missing or malformed."""
        d = Path(directory)
        if not d.is_dir():
            raise UserError(f"{d}: no such world folder (expected a folder with {MANIFEST_FILE})")
        mpath = d / MANIFEST_FILE
        if not mpath.is_file():
            raise UserError(f"{mpath}: missing (expected the world manifest written by "
                            f"'scenenav world generate' or 'scenenav world import')")
        try:
            text = mpath.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise UserError(f"{mpath}: cannot read ({exc})") from None
        manifest = WorldManifest.from_json(text, str(mpath))
        shape = (manifest.height_px, manifest.width_px)
        ortho = _read_rgb(d / ORTHOPHOTO_FILE, shape)
        ref = _read_rgb(d / REFERENCE_FILE, shape)
        landcover = None
        if manifest.has_landcover:
            landcover = _read_landcover(d / LANDCOVER_FILE, shape)
        junctions = None
        if manifest.has_junctions:
            junctions = _read_junctions(d / JUNCTIONS_FILE)
        return cls(manifest=manifest, orthophoto=ortho, reference=ref, landcover=landcover,
                   junctions=junctions)


def load_world(directory) -> World:
    """Read a world folder (see :meth:`World.load`)."""
    return World.load(directory)


def _remove_stale(path: Path) -> None:
    """Delete ground truth left over from an earlier world in the same folder."""
    try:
        path.unlink(missing_ok=True)
    except OSError as exc:
        raise UserError(f"{path}: cannot remove the stale file ({exc.strerror})") from None


def _write_text(path: Path, text: str) -> None:
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise UserError(f"{path}: cannot write ({exc.strerror})") from None


def _write_png(path: Path, img: np.ndarray) -> None:
    ok = False
    try:
        ok = cv2.imwrite(str(path), img, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION_LEVEL])
    except cv2.error as exc:
        raise UserError(f"{path}: cannot write PNG ({exc.msg})") from None
    if not ok:
        raise UserError(f"{path}: cannot write PNG (check the folder exists and is writable)")


def _write_rgb(path: Path, rgb: np.ndarray) -> None:
    _write_png(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def _imread(path: Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise UserError(f"{path}: missing (expected a PNG image)")
    try:
        img = cv2.imread(str(path), flags)
    except cv2.error as exc:
        raise UserError(f"{path}: cannot decode image ({exc.msg})") from None
    if img is None:
        raise UserError(f"{path}: unreadable or truncated image (expected a valid PNG)")
    return img


def _read_rgb(path: Path, shape: tuple[int, int]) -> np.ndarray:
    img = _imread(path, cv2.IMREAD_COLOR)
    if img.shape[:2] != shape:
        raise UserError(f"{path}: size {img.shape[1]}x{img.shape[0]} px does not match the "
                        f"manifest ({shape[1]}x{shape[0]} px)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _read_landcover(path: Path, shape: tuple[int, int]) -> np.ndarray:
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise UserError(f"{path}: expected a single-channel 8-bit PNG of LandCover values")
    if img.shape != shape:
        raise UserError(f"{path}: size {img.shape[1]}x{img.shape[0]} px does not match the "
                        f"manifest ({shape[1]}x{shape[0]} px)")
    top = max(int(c) for c in LandCover)
    if int(img.max()) > top:
        raise UserError(f"{path}: value {int(img.max())} is not a LandCover class (expected 0..{top})")
    return img


def _read_junctions(path: Path) -> tuple[Junction, ...]:
    if not path.is_file():
        raise UserError(f"{path}: missing (the manifest says has_junctions = true)")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, list):
        raise UserError(f"{path}: expected a JSON list of junctions")
    out = []
    for i, item in enumerate(data):
        if not isinstance(item, dict):
            raise UserError(f"{path}: item {i}: expected an object with u_px, v_px, arms, kind")
        try:
            out.append(Junction.from_dict(item))
        except (KeyError, ValueError, TypeError) as exc:
            raise UserError(f"{path}: item {i}: {exc} (expected u_px, v_px numbers, arms >= 2, "
                            f"kind one of cross/tee/wye/corner/bend)") from None
    return tuple(out)
