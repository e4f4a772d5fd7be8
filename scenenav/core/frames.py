"""Frame conventions shared by every scenenav module.

World frame: ENU metres, origin at the centre of the map, x east, y north, z up.
Image frame: continuous pixel coordinates (u, v) = (column, row); pixel (c, r) covers
[c, c+1) x [r, r+1), so its centre is at (c + 0.5, r + 0.5). Row 0 is the north edge.
The map centre (u, v) = (W/2, H/2) is the world origin.

    x_m = (u - W/2) * m_per_px
    y_m = (H/2 - v) * m_per_px

Geodetic: the map centre sits at (origin_lat_deg, origin_lon_deg). ENU <-> lat/lon uses a
local tangent-plane approximation on the WGS-84 ellipsoid (meridian and prime-vertical radii of
curvature at the origin latitude), accurate to centimetres over the few kilometres a world spans.

Body frame on the bus: FLU (x forward, y left, z up); quaternions are w, x, y, z and rotate body
vectors into the world (ENU) frame. Heading: clockwise from north, radians, [0, 2*pi) — the
compass convention. For a body yaw psi measured counter-clockwise from east (ENU yaw),
heading = pi/2 - psi (wrapped).
"""

from __future__ import annotations

import math

import numpy as np

# WGS-84 ellipsoid (NIMA TR8350.2).
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


def world_to_pixel(x_m, y_m, width_px: int, height_px: int, m_per_px: float):
    """World ENU metres -> continuous pixel coordinates (u, v). Works on scalars and arrays."""
    u = np.asarray(x_m, dtype=float) / m_per_px + width_px / 2.0
    v = height_px / 2.0 - np.asarray(y_m, dtype=float) / m_per_px
    if np.ndim(u) == 0:
        return float(u), float(v)
    return u, v


def pixel_to_world(u, v, width_px: int, height_px: int, m_per_px: float):
    """Continuous pixel coordinates (u, v) -> world ENU metres (x, y)."""
    x = (np.asarray(u, dtype=float) - width_px / 2.0) * m_per_px
    y = (height_px / 2.0 - np.asarray(v, dtype=float)) * m_per_px
    if np.ndim(x) == 0:
        return float(x), float(y)
    return x, y


def metres_to_whole_px(length_m: float, m_per_px: float) -> int:
    """A ground length in whole map pixels: the nearest whole number (Python ``round``), at least 1
    (a cell or a grid step of a world at ``m_per_px``)."""
    return max(1, int(round(length_m / m_per_px)))


def _radii_m(lat_deg: float) -> tuple[float, float]:
    """Meridian (north) and prime-vertical (east) radii of curvature at a latitude."""
    s = math.sin(math.radians(lat_deg))
    w = math.sqrt(1.0 - WGS84_E2 * s * s)
    r_north = WGS84_A_M * (1.0 - WGS84_E2) / (w ** 3)
    r_east = WGS84_A_M / w
    return r_north, r_east


def enu_to_geodetic(x_m, y_m, origin_lat_deg: float, origin_lon_deg: float):
    """Local ENU metres -> (lat_deg, lon_deg) around the origin (tangent-plane approximation)."""
    r_n, r_e = _radii_m(origin_lat_deg)
    lat = origin_lat_deg + np.degrees(np.asarray(y_m, dtype=float) / r_n)
    lon = origin_lon_deg + np.degrees(
        np.asarray(x_m, dtype=float) / (r_e * math.cos(math.radians(origin_lat_deg))))
    if np.ndim(lat) == 0:
        return float(lat), float(lon)
    return lat, lon


def geodetic_to_enu(lat_deg, lon_deg, origin_lat_deg: float, origin_lon_deg: float):
    """(lat_deg, lon_deg) -> local ENU metres (x east, y north) around the origin."""
    r_n, r_e = _radii_m(origin_lat_deg)
    y = np.radians(np.asarray(lat_deg, dtype=float) - origin_lat_deg) * r_n
    x = np.radians(np.asarray(lon_deg, dtype=float) - origin_lon_deg) * r_e * math.cos(
        math.radians(origin_lat_deg))
    if np.ndim(x) == 0:
        return float(x), float(y)
    return x, y


def wrap_2pi(angle_rad: float) -> float:
    """Wrap an angle to [0, 2*pi)."""
    return angle_rad % (2.0 * math.pi)


def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def enu_yaw_to_heading(yaw_enu_rad: float) -> float:
    """ENU yaw (counter-clockwise from east) -> compass heading (clockwise from north), [0, 2pi)."""
    return wrap_2pi(math.pi / 2.0 - yaw_enu_rad)


def heading_to_enu_yaw(heading_rad: float) -> float:
    """Compass heading (clockwise from north) -> ENU yaw (counter-clockwise from east), [-pi, pi)."""
    return wrap_pi(math.pi / 2.0 - heading_rad)
