"""Georeferenced rasters (GeoTIFF and whatever else GDAL reads) through rasterio, and their
reprojection onto the local grid of an imported world.

The local grid (:class:`LocalGrid`) is the world's pixel grid: ``W x H`` pixels of ``m_per_px``,
north up, its centre ``(W/2, H/2)`` at the geodetic origin (the centre of the source image). Its
coordinates are those of an azimuthal equidistant projection on WGS-84 centred on the origin
(``+proj=aeqd +lat_0 +lon_0 +datum=WGS84``): x east and y north in metres, exact distances and
azimuths from the origin, so grid north is true north at the origin and a ground distance is the
same number of metres in every direction. A UTM image (whose grid north differs from true north by
the meridian convergence) or a Web Mercator image (whose metres are ``1/cos(lat)`` ground metres)
is resampled onto this grid, so neither becomes a hidden compass bias or scale error. Over the few
kilometres a world spans, the grid agrees with the local tangent plane of
``scenenav/core/frames.py`` to millimetres (the two differ by ``r^3 / (6 R^2)``: 0.5 mm at 5 km).

Invalid pixels (the source's nodata value, alpha or mask band, undeclared nodata markers) and
pixels outside the source are NaN after reprojection; :mod:`worlds.importer` fills them.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.enums import ColorInterp, Resampling
from rasterio.errors import CRSError, NotGeoreferencedWarning, RasterioError
from rasterio.transform import Affine
from rasterio.warp import reproject
from rasterio.warp import transform as transform_points

from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

WGS84 = CRS.from_epsg(4326)

#: Points per edge of the source footprint when it is mapped onto the local grid (the footprint of a
#: reprojected raster has curved edges; 64 points bound it to far below a pixel for world sizes).
FOOTPRINT_POINTS_PER_EDGE = 64

#: Height values outside this range (metres) are undeclared nodata markers (-9999, -3.4e38, 32767
#: ...), not the surface: the Dead Sea shore is at -430 m, Everest at 8849 m.
PLAUSIBLE_ELEVATION_M = (-500.0, 9000.0)

#: Band units accepted for heights (GDAL's per-band unit type); empty means unstated (metres).
METRE_UNITS = frozenset({"", "m", "metre", "meter", "metres", "meters"})

#: Percentiles (of valid pixels, all bands together) mapped to 0 and 255 when an image that is not
#: 8-bit (12/16-bit or float orthophotos) is converted to 8-bit RGB.
STRETCH_PERCENTILES = (0.1, 99.9)

#: Side (pixels) of the decimated read the stretch percentiles are taken from.
STRETCH_SAMPLE_SIDE_PX = 1024


@dataclass(frozen=True)
class LocalGrid:
    """The pixel grid of an imported world (see the module docstring)."""

    width_px: int
    height_px: int
    m_per_px: float
    origin_lat_deg: float
    origin_lon_deg: float

    @property
    def proj(self) -> str:
        return local_projection(self.origin_lat_deg, self.origin_lon_deg)

    @property
    def crs(self) -> CRS:
        return CRS.from_string(self.proj)

    @property
    def transform(self) -> Affine:
        """Pixel (column, row) -> local metres: x = (u - W/2) m, y = (H/2 - v) m (frames.py)."""
        m = self.m_per_px
        return Affine(m, 0.0, -self.width_px / 2.0 * m, 0.0, -m, self.height_px / 2.0 * m)


@dataclass(frozen=True)
class RasterInfo:
    """What a raster file says about itself: size, bands and georeferencing (``crs`` None: none)."""

    path: Path
    width_px: int
    height_px: int
    count: int
    dtype: str
    crs: CRS | None
    transform: Affine

    @property
    def georeferenced(self) -> bool:
        return self.crs is not None


def local_projection(lat_deg: float, lon_deg: float) -> str:
    """The PROJ string of the local grid's projection centred on (lat, lon)."""
    return (f"+proj=aeqd +lat_0={lat_deg:.10f} +lon_0={lon_deg:.10f} +x_0=0 +y_0=0 "
            f"+datum=WGS84 +units=m +no_defs")


def crs_label(crs: CRS) -> str:
    """``EPSG:<code>`` when the CRS has one, else its WKT (what the manifest records)."""
    try:
        code = crs.to_epsg()
    except CRSError:
        code = None
    return f"EPSG:{code}" if code else crs.to_wkt()


def _open(path: Path, label: str):
    if not path.is_file():
        raise UserError(f"{path}: no such {label} file (expected a GeoTIFF or another raster GDAL reads)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            return rasterio.open(path)
    except RasterioError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UserError(f"{path}: not a raster {label} ({first}); expected a GeoTIFF, PNG or JPEG") from None


def inspect_raster(path: Path, label: str) -> RasterInfo:
    """Size, bands and georeferencing of a raster file; UserError (one line) if it is missing, not a
    raster, georeferenced only by control points, or has a CRS that cannot be placed on the earth."""
    path = Path(path)
    with _open(path, label) as src:
        crs = src.crs
        transform = src.transform
        if crs is None and src.gcps[0]:
            raise UserError(f"{path}: the {label} is georeferenced by ground control points only; expected "
                            f"a geotransform (warp it first, e.g. gdalwarp -t_srs EPSG:<code>)")
        info = RasterInfo(path=path, width_px=src.width, height_px=src.height, count=src.count,
                          dtype=str(src.dtypes[0]), crs=crs, transform=transform)
    if crs is not None:
        _check_crs(info, label)
    return info


def _check_crs(info: RasterInfo, label: str) -> None:
    crs = info.crs
    assert crs is not None
    where = f"{info.path}: the {label}'s CRS ({crs.to_string()[:60]})"
    try:
        unit, factor = crs.units_factor
    except CRSError:
        unit, factor = "unknown", 0.0
    if crs.is_projected:
        if unit in ("", "unknown") or not factor > 0:
            raise UserError(f"{where} has no length unit; expected a projected CRS in metres or feet, "
                            f"or a geographic CRS")
    elif not crs.is_geographic:
        raise UserError(f"{where} is a local/engineering CRS not tied to the earth; expected a projected "
                        f"or geographic CRS (or drop the CRS and pass --m-per-px to import a plain image)")
    if abs(info.transform.determinant) == 0.0:
        raise UserError(f"{info.path}: the {label}'s geotransform is degenerate (zero pixel size)")
    x, y = info.transform @ (info.width_px / 2.0, info.height_px / 2.0)
    try:
        lon, lat = transform_points(crs, WGS84, [x], [y])
    except Exception as exc:   # GDAL/PROJ raise their own CPLE_* classes
        raise UserError(f"{where} cannot be related to WGS-84 ({str(exc).splitlines()[0][:80]}); "
                        f"expected a projected or geographic CRS") from None
    if not (math.isfinite(lat[0]) and math.isfinite(lon[0]) and abs(lat[0]) <= 90.0):
        raise UserError(f"{where}: the image centre maps to no place on the earth; check the georeferencing")


def centre_lat_lon(info: RasterInfo) -> tuple[float, float]:
    """WGS-84 (lat, lon) in degrees of the centre of a georeferenced raster."""
    assert info.crs is not None
    x, y = info.transform @ (info.width_px / 2.0, info.height_px / 2.0)
    lon, lat = transform_points(info.crs, WGS84, [x], [y])
    return float(lat[0]), float(lon[0])


def _to_local(info: RasterInfo, local: CRS, cols, rows) -> tuple[np.ndarray, np.ndarray]:
    assert info.crs is not None
    xs, ys = info.transform @ (np.asarray(cols, dtype=float), np.asarray(rows, dtype=float))
    lx, ly = transform_points(info.crs, local, np.atleast_1d(xs).tolist(), np.atleast_1d(ys).tolist())
    return np.asarray(lx, dtype=float), np.asarray(ly, dtype=float)


def centre_jacobian(info: RasterInfo, local: CRS) -> np.ndarray:
    """2x2 metres per source pixel at the source centre: columns d(x, y)/d column and d(x, y)/d row
    in local (east, north) metres (central differences over +-0.5 px)."""
    c, r = info.width_px / 2.0, info.height_px / 2.0
    lx, ly = _to_local(info, local, [c - 0.5, c + 0.5, c, c], [r, r, r - 0.5, r + 0.5])
    return np.array([[lx[1] - lx[0], lx[3] - lx[2]], [ly[1] - ly[0], ly[3] - ly[2]]])


def ground_resolution_m(info: RasterInfo, local: CRS) -> float:
    """The source's ground resolution at its centre: the side of the square of ground (metres) one
    source pixel covers there (sqrt of the Jacobian determinant)."""
    return math.sqrt(abs(float(np.linalg.det(centre_jacobian(info, local)))))


def source_up_azimuth_deg(info: RasterInfo, local: CRS) -> float:
    """Azimuth (degrees clockwise from true north) of the source's pixel-up direction at its centre:
    the meridian convergence for a north-up UTM image, 0 for Web Mercator or geographic."""
    j = centre_jacobian(info, local)
    up_east, up_north = -j[0, 1], -j[1, 1]
    return math.degrees(math.atan2(up_east, up_north))


def footprint_local(info: RasterInfo, local: CRS) -> tuple[np.ndarray, np.ndarray]:
    """The source raster's outline (densified edges) in local metres; non-finite points dropped."""
    n = FOOTPRINT_POINTS_PER_EDGE
    t = np.linspace(0.0, 1.0, n)
    w, h = float(info.width_px), float(info.height_px)
    cols = np.concatenate([t * w, np.full(n, w), (1 - t) * w, np.zeros(n)])
    rows = np.concatenate([np.zeros(n), t * h, np.full(n, h), (1 - t) * h])
    lx, ly = _to_local(info, local, cols, rows)
    ok = np.isfinite(lx) & np.isfinite(ly)
    return lx[ok], ly[ok]


def grid_for(info: RasterInfo, m_per_px: float | None) -> tuple[LocalGrid, float]:
    """The local grid covering the whole source footprint, and the source's ground resolution at
    its centre (the grid's resolution unless ``m_per_px`` is given). The grid is symmetric about
    the origin, so it may hold a margin outside the source (filled by the importer)."""
    lat, lon = centre_lat_lon(info)
    local = CRS.from_string(local_projection(lat, lon))
    res = ground_resolution_m(info, local)
    m = float(m_per_px) if m_per_px is not None else res
    lx, ly = footprint_local(info, local)
    if lx.size == 0:
        raise UserError(f"{info.path}: the image outline cannot be mapped around its centre; check the "
                        f"georeferencing")
    half_w = float(np.max(np.abs(lx)))
    half_h = float(np.max(np.abs(ly)))
    width = 2 * max(1, math.ceil(half_w / m - 1e-6))
    height = 2 * max(1, math.ceil(half_h / m - 1e-6))
    return LocalGrid(width, height, m, lat, lon), res


def overlaps_grid(info: RasterInfo, grid: LocalGrid) -> bool:
    """Whether the raster's footprint intersects the grid's extent (bounding boxes)."""
    lx, ly = footprint_local(info, grid.crs)
    if lx.size == 0:
        return False
    hw, hh = grid.width_px * grid.m_per_px / 2.0, grid.height_px * grid.m_per_px / 2.0
    return bool(lx.min() < hw and lx.max() > -hw and ly.min() < hh and ly.max() > -hh)


def read_rgb(path: Path, label: str) -> np.ndarray:
    """(3, h, w) float32 RGB in 0..255 with NaN at invalid pixels.

    Bands: red, green and blue by their colour interpretation, else the first three; one band is
    grey (or a palette); a fourth alpha band or a mask marks invalid pixels. Images that are not
    8-bit are stretched linearly from the STRETCH_PERCENTILES of their valid pixels to 0..255.
    """
    with _open(Path(path), label) as src:
        interp = list(src.colorinterp)
        if src.count >= 3:
            wanted = [ColorInterp.red, ColorInterp.green, ColorInterp.blue]
            idx = [interp.index(c) + 1 for c in wanted] if all(c in interp for c in wanted) else [1, 2, 3]
        else:
            idx = [1]
        valid = src.dataset_mask() > 0
        palette = None
        if src.count == 1 and interp[0] == ColorInterp.palette:
            try:
                cmap = src.colormap(1)
                palette = np.zeros((256, 3), dtype=np.float32)
                for k, rgba in cmap.items():
                    if 0 <= k < 256:
                        palette[k] = rgba[:3]
            except ValueError:
                palette = None
        eight_bit = src.dtypes[idx[0] - 1] == "uint8"
        lo, hi = 0.0, 255.0
        if not eight_bit and palette is None:
            step = max(1, math.ceil(max(src.width, src.height) / STRETCH_SAMPLE_SIDE_PX))
            shape = (len(idx), max(1, src.height // step), max(1, src.width // step))
            sample = src.read(idx, out_shape=shape, masked=True).astype(np.float64)
            values = sample.compressed() if np.ma.is_masked(sample) else np.asarray(sample).ravel()
            values = values[np.isfinite(values)]
            if values.size:
                lo, hi = (float(v) for v in np.percentile(values, STRETCH_PERCENTILES))
            if not hi > lo:
                hi = lo + 1.0
        out = np.empty((3, src.height, src.width), dtype=np.float32)
        for k in range(3):
            band = src.read(idx[min(k, len(idx) - 1)]).astype(np.float32)
            if palette is not None:
                band = palette[np.clip(band, 0, 255).astype(np.intp), k]
            elif not eight_bit:
                finite = np.isfinite(band)
                valid &= finite
                band = np.clip((band - lo) * np.float32(255.0 / (hi - lo)), 0.0, 255.0)
            out[k] = band
    out[:, ~valid] = np.nan
    return out


def read_heights(path: Path, label: str) -> np.ndarray:
    """(h, w) float32 heights/elevations in metres (band 1), NaN at invalid pixels (nodata, mask,
    non-finite, outside PLAUSIBLE_ELEVATION_M). UserError if the band's unit is not metres."""
    with _open(Path(path), label) as src:
        colour = [ColorInterp.red, ColorInterp.green, ColorInterp.blue]
        if (src.count >= 3 and (list(src.colorinterp[:3]) == colour or src.dtypes[0] == "uint8")) \
                or src.colorinterp[0] == ColorInterp.palette:
            raise UserError(f"{path}: the {label} is a colour image ({src.count} bands, "
                            f"{src.colorinterp[0].name}); expected one band of heights in metres "
                            "(a DSM or nDSM raster, e.g. a float32 GeoTIFF)")
        unit = (src.units[0] or "").strip().lower()
        if unit not in METRE_UNITS:
            raise UserError(f"{path}: the {label}'s values are in {src.units[0]!r}; expected metres "
                            f"(convert it first, e.g. gdal_calc.py)")
        values = src.read(1).astype(np.float32)
        valid = (src.read_masks(1) > 0) & (src.dataset_mask() > 0)
        scale, offset = float(src.scales[0] or 1.0), float(src.offsets[0] or 0.0)
    if (scale, offset) != (1.0, 0.0):
        values = values * np.float32(scale) + np.float32(offset)
    lo, hi = PLAUSIBLE_ELEVATION_M
    valid &= np.isfinite(values) & (values >= lo) & (values <= hi)
    values[~valid] = np.nan
    return values


def reproject_onto(bands: np.ndarray, info: RasterInfo, grid: LocalGrid, resampling: Resampling) -> np.ndarray:
    """Reproject float32 ``bands`` ((n, h, w) or (h, w), NaN = invalid) georeferenced like ``info``
    onto ``grid``; NaN where no valid source pixel contributes."""
    assert info.crs is not None
    src = np.ascontiguousarray(bands, dtype=np.float32)
    shape = (src.shape[0], grid.height_px, grid.width_px) if src.ndim == 3 else (grid.height_px, grid.width_px)
    dst = np.full(shape, np.nan, dtype=np.float32)
    reproject(source=src, destination=dst, src_transform=info.transform, src_crs=info.crs,
              src_nodata=np.nan, dst_transform=grid.transform, dst_crs=grid.crs, dst_nodata=np.nan,
              resampling=resampling, num_threads=1)
    return dst


def image_resampling(source_res_m: float, m_per_px: float) -> Resampling:
    """Resampling of images: ``average`` (area-weighted, anti-aliased) when the grid is coarser than
    the source by more than 1 %, else ``bilinear`` (no ringing, unlike cubic)."""
    return Resampling.average if m_per_px > 1.01 * source_res_m else Resampling.bilinear


__all__ = ["LocalGrid", "RasterInfo", "inspect_raster", "grid_for", "overlaps_grid", "read_rgb",
           "read_heights", "reproject_onto", "image_resampling", "crs_label", "local_projection",
           "centre_lat_lon", "ground_resolution_m", "source_up_azimuth_deg", "WGS84",
           "FOOTPRINT_POINTS_PER_EDGE", "PLAUSIBLE_ELEVATION_M", "STRETCH_PERCENTILES", "Resampling"]
