"""Small GeoTIFFs the tests write themselves with rasterio: a raster of a known place in a given
CRS, painted by ground position.

Painting is independent of the importer's local projection: every source pixel centre is taken to
WGS-84 through the source CRS (PROJ), then to local ENU metres around a chosen origin with the
tangent-plane formulas of ``scenenav/core/frames.py``; a shape is a predicate on those metres.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.transform import Affine, from_origin
from rasterio.warp import transform as transform_points

from scenenav.core import frames


def centred_transform(crs: str, lat_deg: float, lon_deg: float, res: float, width: int,
                      height: int) -> Affine:
    """A north-up geotransform in ``crs`` units whose raster centre is at (lat, lon)."""
    (cx,), (cy,) = transform_points("EPSG:4326", crs, [lon_deg], [lat_deg])
    return from_origin(cx - width / 2.0 * res, cy + height / 2.0 * res, res, res)


def pixel_enu(crs: str, transform: Affine, width: int, height: int, origin_lat: float,
              origin_lon: float) -> tuple[np.ndarray, np.ndarray]:
    """ENU metres (x, y) of every pixel centre, (height, width) arrays each."""
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    xs, ys = transform @ (cols.ravel(), rows.ravel())
    lon, lat = transform_points(crs, "EPSG:4326", list(xs), list(ys))
    x, y = frames.geodetic_to_enu(np.asarray(lat), np.asarray(lon), origin_lat, origin_lon)
    return np.asarray(x).reshape(height, width), np.asarray(y).reshape(height, width)


def north_of(lat_deg: float, distance_m: float) -> float:
    """The latitude ``distance_m`` due north of ``lat_deg`` (meridian radius of curvature of WGS-84)."""
    s = math.sin(math.radians(lat_deg))
    m = frames.WGS84_A_M * (1.0 - frames.WGS84_E2) / (1.0 - frames.WGS84_E2 * s * s) ** 1.5
    return lat_deg + math.degrees(distance_m / m)


def write_raster(path: Path, bands: np.ndarray, crs: str | CRS | None, transform: Affine | None,
                 nodata: float | None = None, **profile) -> Path:
    """Write (bands, H, W) or (H, W) as a GeoTIFF (crs None: no CRS, a plain TIFF)."""
    data = bands if bands.ndim == 3 else bands[None]
    kw = dict(driver="GTiff", width=data.shape[2], height=data.shape[1], count=data.shape[0],
              dtype=str(data.dtype))
    if crs is not None:
        kw["crs"] = crs
    if transform is not None:
        kw["transform"] = transform
    if nodata is not None:
        kw["nodata"] = nodata
    kw.update(profile)
    with rasterio.open(path, "w", **kw) as dst:
        dst.write(data)
    return path
