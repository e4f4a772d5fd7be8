"""Import a real orthophoto (PNG, JPEG, or a TIFF/GeoTIFF OpenCV can decode) as a world.

An imported world has no land-cover map and no junction ground truth (the generator's graph does
not exist); both are listed in ``manifest.missing_ground_truth``, as is the geodetic origin when
none is given. Without a separate reference image, the reference map is the image itself (matching
is then optimistic: same day, same sensor).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import cv2
import numpy as np

from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import CONVENTIONS, FORMAT_VERSION, GroundTruth, WorldManifest, WorldSource
from worlds.world import World

log = logging.getLogger(__name__)

#: Smallest accepted image side: a camera footprint at 100 m is ~217 px at 0.53 m/px.
MIN_IMPORT_SIDE_PX = 256


def read_image_rgb(path: Path, label: str = "image") -> np.ndarray:
    """Read an image file as (H, W, 3) uint8 RGB; UserError if missing or undecodable."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such {label} file (expected a PNG, JPEG or TIFF image)")
    try:
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    except cv2.error as exc:
        raise UserError(f"{p}: cannot decode {label} ({exc.msg})") from None
    if img is None:
        raise UserError(f"{p}: unreadable or truncated {label} (expected a PNG, JPEG or TIFF image)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def import_world(image: Path, m_per_px: float, out_dir: Path, reference: Path | None = None,
                 origin_lat_lon: tuple[float, float] | None = None,
                 name: str | None = None) -> World:
    """Build a world folder in ``out_dir`` from an orthophoto and return the world.

    ``m_per_px`` is the ground resolution (metres per pixel, > 0). ``reference`` is an optional
    second image of the same area and size (the reference map); ``origin_lat_lon`` the geodetic
    position of the image centre in degrees.
    """
    image = Path(image)
    if isinstance(m_per_px, bool) or not isinstance(m_per_px, (int, float)) \
            or not math.isfinite(m_per_px) or m_per_px <= 0:
        raise UserError(f"--m-per-px = {m_per_px!r}: expected a positive number of metres per pixel")
    ortho = read_image_rgb(image, "image")
    h, w = ortho.shape[:2]
    if min(h, w) < MIN_IMPORT_SIDE_PX:
        raise UserError(f"{image}: {w}x{h} px is too small (expected at least "
                        f"{MIN_IMPORT_SIDE_PX} px on each side)")
    if reference is not None:
        reference = Path(reference)
        ref = read_image_rgb(reference, "reference image")
        if ref.shape != ortho.shape:
            raise UserError(f"{reference}: {ref.shape[1]}x{ref.shape[0]} px does not match {image} "
                            f"({w}x{h} px); expected the same area at the same size")
    else:
        ref = ortho.copy()
    missing = [GroundTruth.LANDCOVER.value, GroundTruth.JUNCTIONS.value]
    if origin_lat_lon is None:
        lat, lon = 0.0, 0.0
        missing.append(GroundTruth.GEODETIC_ORIGIN.value)
        log.warning("%s: no geodetic origin given; using 0, 0 (pass --origin LAT,LON)", image)
    else:
        lat, lon = (float(x) for x in origin_lat_lon)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise UserError(f"--origin = {lat},{lon}: expected latitude in [-90, 90] and longitude "
                            f"in [-180, 180] degrees")
    manifest = WorldManifest(
        format_version=FORMAT_VERSION, name=name or image.stem, width_px=w, height_px=h,
        m_per_px=float(m_per_px), origin_lat_deg=lat, origin_lon_deg=lon,
        source=WorldSource.IMPORTED.value, seed=None, has_landcover=False, has_junctions=False,
        missing_ground_truth=tuple(missing), conventions=CONVENTIONS,
        generator={"image": str(image), "reference": str(reference) if reference else None})
    world = World(manifest=manifest, orthophoto=ortho, reference=ref)
    world.save(out_dir)
    return world
