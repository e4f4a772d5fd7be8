"""World files: a folder with a manifest, the orthophoto, the reference map and ground truth.

Layout of a world folder (see docs/worlds.md)::

    manifest.json    WorldManifest (format version, size, resolution, geodetic origin, provenance)
    orthophoto.png   (H, W, 3) 8-bit RGB: the ground the drone camera sees
    reference.png    (H, W, 3) 8-bit RGB: the reference map, same area "on another day", as a
                     true orthophoto
    reference_perspective.png  the same day seen in perspective from manifest.reference.camera_height_m
                     above the map centre, resampled to the map grid (only when that height is set)
    landcover.png    (H, W) 8-bit grey, LandCover values (only when has_landcover)
    junctions.json   list of {u_px, v_px, arms, kind} (only when has_junctions)
    dsm.png          (H, W) 16-bit grey: surface height above the ground at each pixel centre, in
                     units of DSM_UNIT_M (1 cm) (only when has_dsm; otherwise the world is flat)
    facade.png       (H, W, 3) 8-bit RGB: base colour of the walls of the building (or tree) at
                     each pixel, black where there is none (only when has_dsm)

Loading raises :class:`scenenav.core.errors.UserError` with a one-line message for anything missing or
malformed.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from scenenav.core import frames
from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import (
    DSM_FILE,
    DSM_UNIT_M,
    FACADE_FILE,
    JUNCTIONS_FILE,
    LANDCOVER_FILE,
    MANIFEST_FILE,
    ORTHOPHOTO_FILE,
    PERSPECTIVE_REFERENCE_FILE,
    PNG_COMPRESSION_LEVEL,
    REFERENCE_FILE,
    ReferenceKind,
    WorldManifest,
    reference_file,
)
from worlds.landcover import Junction, LandCover

log = logging.getLogger(__name__)


@dataclass(eq=False)
class World:
    """An orthophoto, its reference map, its surface model and (for generated worlds) ground truth.

    ``dsm_m`` is float32 (H, W) metres above the ground (None: a flat world, every height 0);
    ``facade_rgb`` (H, W, 3) uint8 the wall colour of each raised pixel (None: derived from the
    orthophoto by whoever renders walls). Both are present exactly when ``manifest.has_dsm``.
    """

    manifest: WorldManifest
    orthophoto: np.ndarray
    reference: np.ndarray
    landcover: np.ndarray | None = None
    junctions: tuple[Junction, ...] | None = None
    dsm_m: np.ndarray | None = None
    facade_rgb: np.ndarray | None = None
    reference_perspective: np.ndarray | None = None

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
        if (self.dsm_m is not None) != self.manifest.has_dsm:
            raise ValueError(f"dsm_m is {'given' if self.dsm_m is not None else 'None'} but the manifest "
                             f"says has_dsm = {self.manifest.has_dsm}")
        if self.dsm_m is not None:
            if self.dsm_m.dtype != np.float32 or self.dsm_m.shape != shape:
                raise ValueError(f"dsm_m: expected float32 {shape}, got {self.dsm_m.dtype} {self.dsm_m.shape}")
            if not np.all(np.isfinite(self.dsm_m)) or float(self.dsm_m.min()) < 0.0:
                raise ValueError("dsm_m: expected finite heights >= 0 m above the ground")
        has_persp = self.manifest.reference.camera_height_m is not None
        if (self.reference_perspective is not None) != has_persp:
            raise ValueError(f"reference_perspective is {'given' if self.reference_perspective is not None else 'None'}"
                             f" but the manifest's reference.camera_height_m is "
                             f"{self.manifest.reference.camera_height_m}")
        if self.reference_perspective is not None and (self.reference_perspective.dtype != np.uint8
                                                       or self.reference_perspective.shape != shape + (3,)):
            raise ValueError(f"reference_perspective: expected uint8 {shape + (3,)}")
        if self.facade_rgb is not None and (self.facade_rgb.dtype != np.uint8
                                            or self.facade_rgb.shape != shape + (3,)):
            raise ValueError(f"facade_rgb: expected uint8 {shape + (3,)}, got "
                             f"{self.facade_rgb.dtype} {self.facade_rgb.shape}")

    def reference_map(self, kind: ReferenceKind | str | None = None) -> np.ndarray:
        """The reference map of ``kind`` (default: the manifest's ``reference.kind``)."""
        if reference_file(self.manifest, kind) == PERSPECTIVE_REFERENCE_FILE:
            assert self.reference_perspective is not None      # __post_init__: with camera_height_m
            return self.reference_perspective
        return self.reference

    @property
    def heights_m(self) -> np.ndarray:
        """The surface heights above the ground (float32 (H, W)); zeros for a flat world."""
        if self.dsm_m is not None:
            return self.dsm_m
        return np.zeros((self.height_px, self.width_px), dtype=np.float32)

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
        """World ENU metres -> continuous pixel (u, v); see scenenav/core/frames.py."""
        return frames.world_to_pixel(x_m, y_m, self.width_px, self.height_px, self.m_per_px)

    def pixel_to_world(self, u, v):
        """Continuous pixel (u, v) -> world ENU metres (x, y); see scenenav/core/frames.py."""
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
        if self.reference_perspective is not None:
            _write_rgb(d / PERSPECTIVE_REFERENCE_FILE, self.reference_perspective)
        else:
            _remove_stale(d / PERSPECTIVE_REFERENCE_FILE)
        if self.landcover is not None:
            _write_png(d / LANDCOVER_FILE, self.landcover)
        else:
            _remove_stale(d / LANDCOVER_FILE)
        if self.junctions is not None:
            text = json.dumps([j.to_dict() for j in self.junctions], indent=1) + "\n"
            _write_text(d / JUNCTIONS_FILE, text)
        else:
            _remove_stale(d / JUNCTIONS_FILE)
        if self.dsm_m is not None:
            _write_png(d / DSM_FILE, encode_dsm(self.dsm_m))
        else:
            _remove_stale(d / DSM_FILE)
        if self.facade_rgb is not None:
            _write_rgb(d / FACADE_FILE, self.facade_rgb)
        else:
            _remove_stale(d / FACADE_FILE)
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
        dsm = facade = persp = None
        if manifest.reference.camera_height_m is not None:
            persp = _read_rgb(d / PERSPECTIVE_REFERENCE_FILE, shape)
        if manifest.has_dsm:
            dsm = _read_dsm(d / DSM_FILE, shape)
            if (d / FACADE_FILE).is_file():
                facade = _read_rgb(d / FACADE_FILE, shape)
        return cls(manifest=manifest, orthophoto=ortho, reference=ref, landcover=landcover,
                   junctions=junctions, dsm_m=dsm, facade_rgb=facade, reference_perspective=persp)


def encode_dsm(dsm_m: np.ndarray) -> np.ndarray:
    """Heights in metres -> the uint16 array of ``dsm.png`` (units of DSM_UNIT_M, clipped to 655.35 m)."""
    return np.clip(np.rint(np.asarray(dsm_m, dtype=np.float64) / DSM_UNIT_M), 0, 65535).astype(np.uint16)


def decode_dsm(raw: np.ndarray) -> np.ndarray:
    """The uint16 array of ``dsm.png`` -> float32 heights in metres."""
    return (raw.astype(np.float32) * np.float32(DSM_UNIT_M)).astype(np.float32)


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


def _read_dsm(path: Path, shape: tuple[int, int]) -> np.ndarray:
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim != 2 or img.dtype != np.uint16:
        raise UserError(f"{path}: expected a single-channel 16-bit PNG of heights in centimetres "
                        f"(the manifest says has_dsm = true)")
    if img.shape != shape:
        raise UserError(f"{path}: size {img.shape[1]}x{img.shape[0]} px does not match the "
                        f"manifest ({shape[1]}x{shape[0]} px)")
    return decode_dsm(img)


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
