"""The world-folder manifest (``manifest.json``): the file format every package reads.

A world folder (docs/worlds.md) holds ``manifest.json`` (this), ``orthophoto.png`` (the ground the
camera sees, seen from straight above: a true orthophoto, roofs where their footprints are),
``reference.png`` (the reference map "of another day" as a true orthophoto, see
:class:`ReferenceInfo`), and optionally ``reference_perspective.png`` (the same day seen in perspective
from ``ReferenceInfo.camera_height_m`` above the map centre), ``landcover.png``, ``junctions.json``, ``dsm.png`` (the surface model: heights above the ground) and
``facade.png`` (the base colour of the walls of each building pixel). Parsing raises :class:`scenenav.core.errors.UserError` with one line naming
the file and the key.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np

from scenenav.core.errors import UserError

#: Version 2 added the surface model (``has_dsm``, ``dsm.png``, ``facade.png``) and ``reference``.
#: Version 1 folders still load: they are flat worlds with a true-orthophoto reference.
FORMAT_VERSION = 2
READABLE_FORMAT_VERSIONS = (1, 2)
MANIFEST_FILE = "manifest.json"
ORTHOPHOTO_FILE = "orthophoto.png"
REFERENCE_FILE = "reference.png"
LANDCOVER_FILE = "landcover.png"
JUNCTIONS_FILE = "junctions.json"
DSM_FILE = "dsm.png"
PERSPECTIVE_REFERENCE_FILE = "reference_perspective.png"
FACADE_FILE = "facade.png"

#: ``dsm.png`` is a 16-bit grey PNG of heights above the ground in units of this many metres
#: (1 cm: 0 .. 655.35 m). The height of a map pixel is the surface height at its centre.
DSM_UNIT_M = 0.01

#: PNG zlib level: 1 keeps 8000x8000 saves fast; files are still lossless.
PNG_COMPRESSION_LEVEL = 1

CONVENTIONS = (
    "pixels: continuous (u, v) = (column, row), pixel (c, r) covers [c, c+1) x [r, r+1), row 0 north; "
    "world: ENU metres, origin at map centre (u, v) = (W/2, H/2), x = (u - W/2) * m_per_px, "
    "y = (H/2 - v) * m_per_px; geodetic origin (origin_lat_deg, origin_lon_deg) at the map centre, "
    "WGS-84 local tangent plane; images RGB uint8; landcover uint8 LandCover values; "
    "dsm uint16 heights above ground in units of DSM_UNIT_M at pixel centres; "
    "reference misregistration: a ground point at world (x, y) appears in the reference map at "
    "(x, y) + ReferenceInfo.offset_m(x, y)"
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
    DSM = "dsm"


class ReferenceKind(str, Enum):
    """How the reference map was taken.

    ``orthophoto``: a true orthophoto (every map pixel seen from straight above; roofs exactly over
    their footprints). ``perspective``: one perspective image taken from ``camera_height_m`` above
    the map centre and resampled to the map grid, so roofs lean away from the map centre by
    ``height * distance / camera_height`` (as the paper's reference, section 6.1, taken from 500 m).
    """

    ORTHOPHOTO = "orthophoto"
    PERSPECTIVE = "perspective"


@dataclass(frozen=True)
class WarpTerm:
    """One smooth term of the reference misregistration: a plane wave of displacement.

    Adds ``(amp_east_m, amp_north_m) * sin(2 pi (x k_east + y k_north) + phase_rad)`` metres, with
    the wave vector ``(k_east, k_north)`` in cycles per metre.
    """

    amp_east_m: float
    amp_north_m: float
    k_east_per_m: float
    k_north_per_m: float
    phase_rad: float


@dataclass(frozen=True)
class ReferenceInfo:
    """How the reference maps relate to the world (the ``reference`` object of the manifest).

    ``reference.png`` is always the other day as a true orthophoto; ``reference_perspective.png``
    exists when ``camera_height_m`` is set (the same day, same misregistration, taken in perspective
    from that height above the map centre). ``kind`` is the one perception uses unless its
    configuration names the other.

    The misregistration is the reference's georeferencing error: a ground point at world ``(x, y)``
    is drawn in the reference map at ``(x, y) + offset_m(x, y)``, where the offset is a global
    shift plus a sum of smooth plane-wave terms. A perfect match of a capture over ``(x, y)``
    therefore reports ``(x, y) + offset_m(x, y)``; evaluation subtracts the offset.
    """

    kind: ReferenceKind = ReferenceKind.ORTHOPHOTO
    camera_height_m: float | None = None       # of reference_perspective.png; None: no such file
    shift_east_m: float = 0.0
    shift_north_m: float = 0.0
    warp: tuple[WarpTerm, ...] = ()
    season: str = "summer"
    changed_buildings: int = 0                 # buildings re-roofed, added or removed between the days

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", ReferenceKind(self.kind))
        object.__setattr__(self, "warp", tuple(t if isinstance(t, WarpTerm) else WarpTerm(**t)
                                               for t in self.warp))

    def offset_m(self, x_m, y_m):
        """(dx, dy) metres: where the reference draws the ground point (x, y), minus (x, y).

        Works on floats and on numpy arrays alike.
        """
        dx = np.zeros_like(np.asarray(x_m, dtype=float)) + self.shift_east_m
        dy = np.zeros_like(np.asarray(y_m, dtype=float)) + self.shift_north_m
        for t in self.warp:
            s = np.sin(2.0 * math.pi * (np.asarray(x_m) * t.k_east_per_m + np.asarray(y_m) * t.k_north_per_m)
                       + t.phase_rad)
            dx = dx + t.amp_east_m * s
            dy = dy + t.amp_north_m * s
        if np.ndim(dx) == 0:
            return float(dx), float(dy)
        return dx, dy

    def to_dict(self) -> dict:
        data = asdict(self)
        data["kind"] = self.kind.value
        data["warp"] = [asdict(t) for t in self.warp]
        return data

    @classmethod
    def from_dict(cls, data: object, where: str) -> "ReferenceInfo":
        if not isinstance(data, dict):
            raise UserError(f"{where}: reference: expected an object (kind, shift_east_m, ...)")
        try:
            kind = ReferenceKind(data.get("kind", "orthophoto"))
        except ValueError:
            raise UserError(f"{where}: reference.kind = {data.get('kind')!r}: expected 'orthophoto' or "
                            f"'perspective'") from None
        numbers = {}
        for key in ("shift_east_m", "shift_north_m"):
            v = data.get(key, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise UserError(f"{where}: reference.{key} = {v!r}: expected a finite number of metres")
            numbers[key] = float(v)
        h = data.get("camera_height_m")
        if h is not None and (isinstance(h, bool) or not isinstance(h, (int, float)) or not h > 0):
            raise UserError(f"{where}: reference.camera_height_m = {h!r}: expected a height > 0 m or null")
        if kind is ReferenceKind.PERSPECTIVE and h is None:
            raise UserError(f"{where}: reference.camera_height_m: missing (reference.kind = 'perspective' "
                            f"needs {PERSPECTIVE_REFERENCE_FILE} and the height it was taken from)")
        terms = data.get("warp", [])
        if not isinstance(terms, list):
            raise UserError(f"{where}: reference.warp: expected a list of terms")
        warp = []
        names = ("amp_east_m", "amp_north_m", "k_east_per_m", "k_north_per_m", "phase_rad")
        for i, t in enumerate(terms):
            if not isinstance(t, dict) or set(t) != set(names) or not all(
                    isinstance(t[n], (int, float)) and not isinstance(t[n], bool) and math.isfinite(t[n])
                    for n in names):
                raise UserError(f"{where}: reference.warp[{i}]: expected an object with finite numbers "
                                f"{', '.join(names)}")
            warp.append(WarpTerm(**{n: float(t[n]) for n in names}))
        season = data.get("season", "summer")
        if season not in ("summer", "winter"):
            raise UserError(f"{where}: reference.season = {season!r}: expected 'summer' or 'winter'")
        changed = data.get("changed_buildings", 0)
        if isinstance(changed, bool) or not isinstance(changed, int) or changed < 0:
            raise UserError(f"{where}: reference.changed_buildings = {changed!r}: expected a count >= 0")
        return cls(kind=kind, camera_height_m=None if h is None else float(h), warp=tuple(warp),
                   season=season, changed_buildings=changed, **numbers)


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
    #: A surface model is in ``dsm.png`` (and wall colours in ``facade.png``); without one the
    #: world is flat (every height 0) and ``missing_ground_truth`` lists "dsm".
    has_dsm: bool = False
    reference: ReferenceInfo = field(default_factory=ReferenceInfo)
    #: Imported GeoTIFFs: the coordinate reference system of the source image ("EPSG:<code>" when
    #: it has one, else its WKT) and the local projection (a PROJ string, metres, centred on the
    #: map centre, grid north = true north there) it was reprojected to. None: not georeferenced.
    source_crs: str | None = None
    local_projection: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "missing_ground_truth", tuple(self.missing_ground_truth))

    def to_dict(self) -> dict:
        data = asdict(self)
        data["missing_ground_truth"] = list(self.missing_ground_truth)
        data["reference"] = self.reference.to_dict()
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
        if version not in READABLE_FORMAT_VERSIONS:
            raise UserError(f"{where}: format_version = {version}: expected one of "
                            f"{', '.join(str(v) for v in READABLE_FORMAT_VERSIONS)}")
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
        has_dsm = data.get("has_dsm", False)
        if not isinstance(has_dsm, bool):
            raise UserError(f"{where}: has_dsm = {has_dsm!r}: expected true or false")
        reference = ReferenceInfo.from_dict(data.get("reference", {}), where)
        geo = {}
        for key in ("source_crs", "local_projection"):
            v = data.get(key)
            if v is not None and (not isinstance(v, str) or not v.strip()):
                raise UserError(f"{where}: {key} = {v!r}: expected a non-empty string (a CRS) or null")
            geo[key] = v
        return cls(format_version=version, name=name, width_px=width, height_px=height,
                   m_per_px=m_per_px, origin_lat_deg=lat, origin_lon_deg=lon, source=source,
                   seed=seed, has_landcover=has_lc, has_junctions=has_jn,
                   missing_ground_truth=tuple(missing), conventions=conventions,
                   generator=generator, has_dsm=has_dsm, reference=reference, **geo)


def read_manifest(world_dir: str | Path) -> WorldManifest:
    """The manifest of the world folder ``world_dir`` (one-line UserError if missing or malformed)."""
    path = Path(world_dir) / MANIFEST_FILE
    try:
        text = path.read_text()
    except OSError as exc:
        raise UserError(f"{path}: cannot read the world manifest ({exc.strerror}); expected a world "
                        "folder made by `scenenav world generate` or `scenenav world import`") from None
    return WorldManifest.from_json(text, str(path))


def reference_file(manifest: WorldManifest, kind: ReferenceKind | str | None = None) -> str:
    """The file of the world's reference map of ``kind`` (None: the manifest's ``reference.kind``).

    ``perspective`` is ``reference_perspective.png`` when the world has one. A flat world
    (``has_dsm`` false) without one uses ``reference.png``: seen from any height straight above,
    a flat ground drawn back onto the map grid is its orthophoto, so the two are the same map. A
    world with relief and no perspective reference is a one-line UserError saying how to get one.
    """
    k = manifest.reference.kind if kind is None else ReferenceKind(kind)
    if k is not ReferenceKind.PERSPECTIVE:
        return REFERENCE_FILE
    if manifest.reference.camera_height_m is not None:
        return PERSPECTIVE_REFERENCE_FILE
    if not manifest.has_dsm:
        return REFERENCE_FILE
    raise UserError(f"world {manifest.name!r} has relief but no perspective reference "
                    f"({PERSPECTIVE_REFERENCE_FILE}), which perception.reference = perspective asks for "
                    f"(the paper and realistic profiles do): import it again with this scenenav (`scenenav "
                    f"world import ... --dsm RASTER` renders one from --reference-height-m), or set "
                    f"perception.reference=orthophoto")
