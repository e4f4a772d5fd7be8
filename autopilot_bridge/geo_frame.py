"""ENU metres <-> WGS-84 around the world origin, and ENU <-> NED vectors (the MAVLink side).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenenav.core.frames import enu_to_geodetic, geodetic_to_enu


@dataclass(frozen=True)
class GeoFrame:
    """ENU metres <-> WGS-84 around the world origin (scenenav.core.frames), AMSL = origin + z."""

    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_amsl_m: float = 0.0

    def to_geodetic(self, x_m: float, y_m: float) -> tuple[float, float]:
        return enu_to_geodetic(x_m, y_m, self.origin_lat_deg, self.origin_lon_deg)

    def to_enu(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        return geodetic_to_enu(lat_deg, lon_deg, self.origin_lat_deg, self.origin_lon_deg)


def ned_to_enu(v) -> np.ndarray:
    return np.array([float(v[1]), float(v[0]), -float(v[2])])


def enu_to_ned(v) -> tuple[float, float, float]:
    return (float(v[1]), float(v[0]), -float(v[2]))
