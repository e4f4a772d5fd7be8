"""Import a real orthophoto as a world: a plain PNG/JPEG/TIFF at a given resolution, or a GeoTIFF
with its georeferencing, optionally with a DSM/nDSM giving the heights.

A georeferenced image (a CRS and a geotransform, read through rasterio) is reprojected onto the
world's local grid (:mod:`worlds.georaster`: azimuthal equidistant on WGS-84 centred on the image
centre, north up, at ``m_per_px`` or the source's ground resolution at its centre); the geodetic
origin is the image centre, and the manifest records the source CRS and the local projection. A
``--reference`` and a ``--dsm``/``--dtm`` raster are reprojected onto the same grid (or, without a
CRS of their own and at the image's pixel size, taken as pixel-aligned with the image). Pixels
outside the source or nodata in it are :data:`NODATA_FILL_RGB` in the images and height 0 in the
surface model. Plain images (PNG/JPEG, or a TIFF without a CRS) are used pixel for pixel at the
given ``m_per_px``, north up, as they are.

An imported world has no land-cover map and no junction ground truth (the generator's graph does
not exist); both are listed in ``manifest.missing_ground_truth``, as are the geodetic origin when
the image is not georeferenced and no origin is given, and the DSM when none is given (the world is
then flat). Without a separate reference image, the reference map is the image itself (matching
is then optimistic: same day, same sensor).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import CONVENTIONS, FORMAT_VERSION, GroundTruth, WorldManifest, WorldSource
from worlds import georaster
from worlds.city_config import CityConfig
from worlds.ground import DEFAULT_GROUND_WINDOW_M, DsmKind, heights_above_ground
from worlds.perspective import perspective_reference

#: The eye of the perspective reference an import renders with a DSM: the generator's (the paper's 500 m).
DEFAULT_REFERENCE_HEIGHT_M = CityConfig.reference_height_m
from worlds.world import World

log = logging.getLogger(__name__)

#: Smallest accepted image side: a camera footprint at 100 m is ~217 px at 0.53 m/px.
MIN_IMPORT_SIDE_PX = 256
#: Largest accepted world side (pixels), as for generated worlds (worlds/city_config.py).
MAX_IMPORT_SIDE_PX = 16384

#: Suffixes read as plain images by OpenCV, pixel for pixel (no georeferencing is looked for).
PLAIN_IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg"})

#: Colour of image pixels with no source data (outside the source footprint, nodata, alpha 0).
NODATA_FILL_RGB = (0, 0, 0)

#: An nDSM whose 5th percentile lies above this (metres) holds elevations, not heights above the
#: ground: even a dense city centre has streets and yards at ~0 m on far more than 5 % of its area.
NDSM_MAX_P5_M = 50.0


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


def _check_m_per_px(m_per_px: float | None) -> None:
    if m_per_px is None:
        return
    if isinstance(m_per_px, bool) or not isinstance(m_per_px, (int, float)) \
            or not math.isfinite(m_per_px) or m_per_px <= 0:
        raise UserError(f"--m-per-px = {m_per_px!r}: expected a positive number of metres per pixel")


def _check_origin(origin_lat_lon: tuple[float, float] | None) -> tuple[float, float] | None:
    if origin_lat_lon is None:
        return None
    lat, lon = (float(x) for x in origin_lat_lon)
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise UserError(f"--origin = {lat},{lon}: expected latitude in [-90, 90] and longitude "
                        f"in [-180, 180] degrees")
    return lat, lon


def _check_size(path: Path, w: int, h: int, what: str) -> None:
    if min(h, w) < MIN_IMPORT_SIDE_PX:
        raise UserError(f"{path}: {w}x{h} px {what}is too small (expected at least "
                        f"{MIN_IMPORT_SIDE_PX} px on each side)")
    if max(h, w) > MAX_IMPORT_SIDE_PX:
        raise UserError(f"{path}: {w}x{h} px {what}is too large (expected at most {MAX_IMPORT_SIDE_PX} px "
                        f"a side; pass a coarser --m-per-px or crop the image)")


def _is_plain(path: Path) -> bool:
    return path.suffix.lower() in PLAIN_IMAGE_SUFFIXES


def import_world(image: Path, m_per_px: float | None, out_dir: Path, reference: Path | None = None,
                 origin_lat_lon: tuple[float, float] | None = None,
                 name: str | None = None, dsm: Path | None = None,
                 dsm_kind: DsmKind | str = DsmKind.NDSM, dtm: Path | None = None,
                 ground_window_m: float = DEFAULT_GROUND_WINDOW_M, progress: bool = False,
                 reference_height_m: float = DEFAULT_REFERENCE_HEIGHT_M) -> World:
    """Build a world folder in ``out_dir`` from an orthophoto and return the world.

    ``m_per_px`` is the ground resolution of the world (metres per pixel, > 0); for a georeferenced
    image None means the source's ground resolution at its centre, for a plain image it is
    required. ``reference`` is an optional second image of the same area (the reference map);
    ``origin_lat_lon`` the geodetic position of a plain image's centre in degrees (a georeferenced
    image knows its own). ``dsm`` is an optional surface model of ``dsm_kind`` (``dtm`` the ground
    under a DSM; without one the ground is estimated with a ``ground_window_m`` opening, see
    worlds/ground.py). With a DSM, the reference is also rendered in perspective from
    ``reference_height_m`` above the map centre (``reference_perspective.png``, what the ``paper`` and
    ``realistic`` profiles match against; 0: not rendered). Every input is checked before anything is
    written. ``progress``: a progress bar of the reprojection steps on stderr (when it is a terminal).
    """
    image = Path(image)
    if not image.is_file():
        raise UserError(f"{image}: no such image file (expected a GeoTIFF, PNG, JPEG or TIFF image)")
    _check_m_per_px(m_per_px)
    kind = DsmKind(dsm_kind)
    if dtm is not None and dsm is None:
        raise UserError("--dtm: given without --dsm (the DTM is the ground under a DSM of elevations)")
    if dtm is not None and kind is not DsmKind.DSM:
        raise UserError("--dtm: given with --dsm-kind ndsm (an nDSM already holds heights above the "
                        "ground); expected --dsm-kind dsm")
    if isinstance(ground_window_m, bool) or not math.isfinite(ground_window_m) or ground_window_m <= 0:
        raise UserError(f"--ground-window-m = {ground_window_m!r}: expected a positive number of metres")
    if (isinstance(reference_height_m, bool) or not math.isfinite(reference_height_m)
            or not (reference_height_m == 0 or 50.0 <= reference_height_m <= 20000.0)):
        raise UserError(f"--reference-height-m = {reference_height_m!r}: expected 50 .. 20000 m (or 0: no "
                        f"perspective reference)")
    info = None if _is_plain(image) else georaster.inspect_raster(image, "image")
    if info is not None and info.georeferenced:
        if origin_lat_lon is not None:
            raise UserError(f"--origin: not used with the georeferenced {image} (its geodetic origin is "
                            f"its centre, from its CRS); drop --origin")
        world = _import_georeferenced(image, info, m_per_px, out_dir, reference, name, dsm, kind, dtm,
                                      ground_window_m, progress)
        return _save(world, out_dir, reference_height_m)
    if m_per_px is None:
        where = "has no CRS" if info is not None else "is a plain image"
        raise UserError(f"{image}: {where}, so its scale is unknown; pass --m-per-px M (it is then "
                        f"imported as a plain image, north up)")
    if info is not None:
        log.warning("%s: no CRS; importing it as a plain image at %g m/px, north up", image, m_per_px)
    world = _import_plain(image, float(m_per_px), out_dir, reference, _check_origin(origin_lat_lon), name,
                          dsm, kind, dtm, ground_window_m)
    return _save(world, out_dir, reference_height_m)


def _save(world: World, out_dir: Path, reference_height_m: float) -> World:
    """Add the perspective reference to a world with relief (``import_world``) and write the folder."""
    if world.dsm_m is not None and reference_height_m > 0:
        persp = perspective_reference(world.reference, world.dsm_m, None, world.m_per_px,
                                      float(reference_height_m))
        ref = dataclasses.replace(world.manifest.reference, camera_height_m=float(reference_height_m))
        world = dataclasses.replace(world, manifest=dataclasses.replace(world.manifest, reference=ref),
                                    reference_perspective=persp)
    world.save(out_dir)
    return world


def _import_plain(image: Path, m_per_px: float, out_dir: Path, reference: Path | None,
                  origin: tuple[float, float] | None, name: str | None, dsm: Path | None,
                  kind: DsmKind, dtm: Path | None, ground_window_m: float) -> World:
    ortho = read_image_rgb(image, "image")
    h, w = ortho.shape[:2]
    _check_size(image, w, h, "")
    if reference is not None:
        reference = Path(reference)
        ref = read_image_rgb(reference, "reference image")
        if ref.shape != ortho.shape:
            raise UserError(f"{reference}: {ref.shape[1]}x{ref.shape[0]} px does not match {image} "
                            f"({w}x{h} px); expected the same area at the same size")
    else:
        ref = ortho.copy()
    heights = None
    if dsm is not None:
        values = _aligned_heights(Path(dsm), "DSM", image, w, h)
        ground = _aligned_heights(Path(dtm), "DTM", image, w, h) if dtm is not None else None
        heights = _heights(values, kind, m_per_px, ground, ground_window_m, Path(dsm))
    missing = [GroundTruth.LANDCOVER.value, GroundTruth.JUNCTIONS.value]
    if origin is None:
        lat, lon = 0.0, 0.0
        missing.append(GroundTruth.GEODETIC_ORIGIN.value)
        log.warning("%s: no geodetic origin given; using 0, 0 (pass --origin LAT,LON)", image)
    else:
        lat, lon = origin
    if heights is None:
        missing.append(GroundTruth.DSM.value)
    generator = {"image": str(image), "reference": str(reference) if reference else None,
                 "georeferencing": "none: a plain image, north up, at the given m_per_px"}
    generator.update(_dsm_provenance(dsm, kind, dtm, ground_window_m))
    manifest = WorldManifest(
        format_version=FORMAT_VERSION, name=name or image.stem, width_px=w, height_px=h,
        m_per_px=float(m_per_px), origin_lat_deg=lat, origin_lon_deg=lon,
        source=WorldSource.IMPORTED.value, seed=None, has_landcover=False, has_junctions=False,
        missing_ground_truth=tuple(missing), conventions=CONVENTIONS, generator=generator,
        has_dsm=heights is not None)
    return World(manifest=manifest, orthophoto=ortho, reference=ref, dsm_m=heights)


def _aligned_heights(path: Path, label: str, image: Path, w: int, h: int) -> np.ndarray:
    """Heights of a raster pixel-aligned with a plain image (same size, no CRS of its own)."""
    info = georaster.inspect_raster(path, label)
    if info.georeferenced:
        raise UserError(f"{path}: the {label} is georeferenced but {image} is not, so it cannot be placed "
                        f"on the image; expected a {label} without CRS at {w}x{h} px, or a GeoTIFF image")
    if (info.width_px, info.height_px) != (w, h):
        raise UserError(f"{path}: {info.width_px}x{info.height_px} px does not match {image} ({w}x{h} px); "
                        f"expected a {label} pixel-aligned with the image")
    return georaster.read_heights(path, label)


def _heights(values: np.ndarray, kind: DsmKind, m_per_px: float, ground: np.ndarray | None,
             ground_window_m: float, dsm_path: Path) -> np.ndarray:
    """World.dsm_m from DSM/nDSM values on the world grid, with the plausibility check of an nDSM."""
    if not np.any(np.isfinite(values)):
        raise UserError(f"{dsm_path}: the DSM has no valid height over the image (all nodata)")
    if kind is DsmKind.NDSM:
        p5 = float(np.percentile(values[np.isfinite(values)], 5))
        if p5 > NDSM_MAX_P5_M:
            raise UserError(f"{dsm_path}: 95 % of its heights are above {p5:.0f} m, so it holds elevations, "
                            f"not heights above the ground; pass --dsm-kind dsm (and --dtm FILE if you "
                            f"have the ground model)")
    heights = heights_above_ground(values, kind, m_per_px, ground, ground_window_m)
    top = float(heights.max())
    if top > 655.0:
        log.warning("%s: heights up to %.0f m are clipped to 655.35 m (dsm.png holds centimetres in 16 bits)",
                    dsm_path, top)
    return heights


def _dsm_provenance(dsm: Path | None, kind: DsmKind, dtm: Path | None, window_m: float) -> dict:
    if dsm is None:
        return {"dsm": None}
    if kind is DsmKind.NDSM:
        ground = "none: an nDSM holds heights above the ground"
    elif dtm is not None:
        ground = f"the DTM {dtm}"
    else:
        ground = (f"estimated: 10th percentile per 5 m cell, morphological opening and box filter of "
                  f"{window_m:g} m (worlds/ground.py)")
    return {"dsm": str(dsm), "dsm_kind": kind.value, "dtm": str(dtm) if dtm else None,
            "ground": ground, "dsm_nodata": "height 0", "dsm_negative": "clipped to 0"}


def _companion(path: Path, label: str, image_info: "georaster.RasterInfo",
               grid: "georaster.LocalGrid") -> "georaster.RasterInfo":
    """The georeferencing a reference/DSM/DTM raster is reprojected with: its own CRS, or (none, at
    the image's pixel size) the image's; UserError if neither, or if it misses the image."""
    info = georaster.inspect_raster(path, label)
    if not info.georeferenced:
        if (info.width_px, info.height_px) != (image_info.width_px, image_info.height_px):
            raise UserError(f"{path}: the {label} has no CRS and {info.width_px}x{info.height_px} px, not the "
                            f"image's {image_info.width_px}x{image_info.height_px} px; expected a "
                            f"georeferenced {label} or one pixel-aligned with the image")
        log.info("%s: no CRS; taken as pixel-aligned with %s", path, image_info.path)
        return georaster.RasterInfo(path=path, width_px=info.width_px, height_px=info.height_px,
                                    count=info.count, dtype=info.dtype, crs=image_info.crs,
                                    transform=image_info.transform)
    if not georaster.overlaps_grid(info, grid):
        raise UserError(f"{path}: the {label} does not overlap the image {image_info.path} (no common "
                        f"ground); expected a {label} of the same area")
    return info


def _import_georeferenced(image: Path, info: "georaster.RasterInfo", m_per_px: float | None,
                          out_dir: Path, reference: Path | None, name: str | None, dsm: Path | None,
                          kind: DsmKind, dtm: Path | None, ground_window_m: float,
                          progress: bool = False) -> World:
    assert info.crs is not None
    grid, source_res = georaster.grid_for(info, m_per_px)
    _check_size(image, grid.width_px, grid.height_px,
                f"on the local grid at {grid.m_per_px:.4g} m/px ")
    ref_info = _companion(Path(reference), "reference image", info, grid) if reference is not None else None
    dsm_info = _companion(Path(dsm), "DSM", info, grid) if dsm is not None else None
    dtm_info = _companion(Path(dtm), "DTM", info, grid) if dtm is not None else None
    steps = 2 + sum(x is not None for x in (ref_info, dsm_info, dtm_info))
    with tqdm(total=steps, desc=f"import {image.name}", unit="step", leave=False,
              disable=None if progress else True) as bar:
        world = _reproject_all(image, info, grid, source_res, out_dir, reference, name, dsm, kind, dtm,
                               ground_window_m, ref_info, dsm_info, dtm_info, bar)
    return world


def _reproject_all(image: Path, info: "georaster.RasterInfo", grid: "georaster.LocalGrid", source_res: float,
                   out_dir: Path, reference: Path | None, name: str | None, dsm: Path | None,
                   kind: DsmKind, dtm: Path | None, ground_window_m: float,
                   ref_info: "georaster.RasterInfo | None", dsm_info: "georaster.RasterInfo | None",
                   dtm_info: "georaster.RasterInfo | None", bar) -> World:
    assert info.crs is not None

    resampling = georaster.image_resampling(source_res, grid.m_per_px)
    ortho_f = georaster.reproject_onto(georaster.read_rgb(image, "image"), info, grid, resampling)
    ortho, nodata_share = _to_rgb8(ortho_f)
    bar.update()
    if nodata_share >= 1.0:
        raise UserError(f"{image}: no valid pixel (everything is nodata or masked)")
    if ref_info is not None:
        ref_f = georaster.reproject_onto(georaster.read_rgb(ref_info.path, "reference image"), ref_info,
                                         grid, resampling)
        ref, ref_nodata = _to_rgb8(ref_f)
        bar.update()
        if ref_nodata >= 1.0:
            raise UserError(f"{reference}: the reference image has no valid pixel over {image}")
    else:
        ref = ortho.copy()
    heights = None
    dsm_coverage = None
    if dsm_info is not None:
        bilinear = georaster.Resampling.bilinear
        values = georaster.reproject_onto(georaster.read_heights(dsm_info.path, "DSM"), dsm_info, grid,
                                          bilinear)
        dsm_coverage = float(np.mean(np.isfinite(values)))
        bar.update()
        if dsm_coverage == 0.0:
            raise UserError(f"{dsm}: the DSM has no valid height over {image} (does not overlap it, or "
                            f"nodata there)")
        ground = None
        if dtm_info is not None:
            ground = georaster.reproject_onto(georaster.read_heights(dtm_info.path, "DTM"), dtm_info, grid,
                                              bilinear)
            if not np.any(np.isfinite(ground)):
                raise UserError(f"{dtm}: the DTM has no valid height over {image}")
            bar.update()
        heights = _heights(values, kind, grid.m_per_px, ground, ground_window_m, Path(dsm_info.path))
        if dsm_coverage < 0.5:
            log.warning("%s: the DSM covers only %.0f %% of the world; the rest is flat", dsm,
                        100.0 * dsm_coverage)
    missing = [GroundTruth.LANDCOVER.value, GroundTruth.JUNCTIONS.value]
    if heights is None:
        missing.append(GroundTruth.DSM.value)
    local = grid.crs
    generator = {
        "image": str(image), "reference": str(reference) if reference else None,
        "georeferencing": "reprojected onto the local grid (local_projection) with rasterio.warp.reproject",
        "image_resampling": resampling.name, "dsm_resampling": "bilinear",
        "source_m_per_px_at_centre": source_res,
        "source_up_azimuth_deg": georaster.source_up_azimuth_deg(info, local),
        "nodata_fill_rgb": list(NODATA_FILL_RGB), "nodata_share": nodata_share,
        "dsm_coverage_share": dsm_coverage,
    }
    generator.update(_dsm_provenance(dsm, kind, dtm, ground_window_m))
    manifest = WorldManifest(
        format_version=FORMAT_VERSION, name=name or image.stem, width_px=grid.width_px,
        height_px=grid.height_px, m_per_px=float(grid.m_per_px), origin_lat_deg=grid.origin_lat_deg,
        origin_lon_deg=grid.origin_lon_deg, source=WorldSource.IMPORTED.value, seed=None,
        has_landcover=False, has_junctions=False, missing_ground_truth=tuple(missing),
        conventions=CONVENTIONS, generator=generator, has_dsm=heights is not None,
        source_crs=georaster.crs_label(info.crs), local_projection=grid.proj)
    bar.update()
    return World(manifest=manifest, orthophoto=ortho, reference=ref, dsm_m=heights)


def _to_rgb8(rgb_f: np.ndarray) -> tuple[np.ndarray, float]:
    """(3, H, W) float RGB with NaN -> (H, W, 3) uint8 with NODATA_FILL_RGB there, and the NaN share."""
    invalid = ~np.all(np.isfinite(rgb_f), axis=0)
    out = np.empty(rgb_f.shape[1:] + (3,), dtype=np.uint8)
    for k in range(3):
        band = np.nan_to_num(rgb_f[k], nan=0.0)
        out[..., k] = np.clip(np.rint(band), 0, 255).astype(np.uint8)
        out[..., k][invalid] = NODATA_FILL_RGB[k]
    return out, float(np.mean(invalid))
