"""The world-folder manifest (``manifest.json``): the file format every package reads.

A world folder (docs/worlds.md) holds ``manifest.json`` (this), ``orthophoto.png`` (the ground the
camera sees), ``reference.png`` (the reference map "of another day"), and optionally ``landcover.png``
and ``junctions.json``. Parsing raises :class:`scenenav.core.errors.UserError` with one line naming
the file and the key.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path

from scenenav.core.errors import UserError

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


def read_manifest(world_dir: str | Path) -> WorldManifest:
    """The manifest of the world folder ``world_dir`` (one-line UserError if missing or malformed)."""
    path = Path(world_dir) / MANIFEST_FILE
    try:
        text = path.read_text()
    except OSError as exc:
        raise UserError(f"{path}: cannot read the world manifest ({exc.strerror}); expected a world "
                        "folder made by `scenenav world generate` or `scenenav world import`") from None
    return WorldManifest.from_json(text, str(path))
