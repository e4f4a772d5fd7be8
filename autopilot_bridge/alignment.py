"""Alignment of the navigation filter on the ground: the samples taken at rest before the EKF starts.

IMU, baro and compass samples are averaged at rest for ``FlightCoreConfig.align_time_s`` (and, with
GPS as the position source, up to ``gps_wait_s`` for three GPS fixes); ``Alignment.result`` then
gives the means the EKF is initialised with (``FlightCore`` sets home and the EKF origin there and
starts the controller landed). Position: the mean GPS fix, or (``gps_xy_enu_m`` None) the known
take-off point.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_TWO_PI = 2.0 * math.pi
MIN_SAMPLES = 3          # baro, compass (and GPS) samples needed before aligning


@dataclass(frozen=True)
class AlignmentResult:
    """The means at rest the EKF is initialised with."""

    accel_flu_m_s2: np.ndarray                     # (3,) specific force
    gyro_flu_rad_s: np.ndarray                     # (3,) rate at rest (the initial gyro bias)
    heading_rad: float                             # circular mean of the compass, [0, 2 pi)
    baro_alt_m: float
    gps_xy_enu_m: tuple[float, float] | None       # mean GPS position; None without GPS fixes


class Alignment:
    """Accumulates the samples at rest; ``result`` once there are enough (see the module docstring)."""

    def __init__(self) -> None:
        self._t0_s: float | None = None
        self._accel = np.zeros(3)
        self._gyro = np.zeros(3)
        self._n = 0
        self._baro: list[float] = []
        self._hdg = np.zeros(2)
        self._hdg_n = 0
        self._gps: list[tuple[float, float]] = []

    def reset(self) -> None:
        self._t0_s = None
        self._accel[:] = 0.0
        self._gyro[:] = 0.0
        self._n = 0
        self._baro.clear()
        self._hdg[:] = 0.0
        self._hdg_n = 0
        self._gps.clear()

    def add_baro(self, altitude_m: float) -> None:
        self._baro.append(float(altitude_m))

    def add_heading(self, heading_rad: float) -> None:
        """A compass heading in [0, 2 pi)."""
        self._hdg += (math.cos(heading_rad), math.sin(heading_rad))
        self._hdg_n += 1

    def add_gps(self, xy_enu_m: tuple[float, float]) -> None:
        self._gps.append(xy_enu_m)

    def add_imu(self, now_s: float, accel: np.ndarray, gyro: np.ndarray) -> None:
        if self._t0_s is None:
            self._t0_s = now_s
        self._accel += accel
        self._gyro += gyro
        self._n += 1

    def result(self, now_s: float, align_time_s: float, gps_wait_s: float,
               gps_source: bool) -> AlignmentResult | None:
        """The means, or None while the samples are too few or too short (with ``gps_source``: also
        while fewer than three GPS fixes arrived, for at most ``gps_wait_s``)."""
        if self._t0_s is None:
            return None
        elapsed = now_s - self._t0_s
        if elapsed < align_time_s or len(self._baro) < MIN_SAMPLES or self._hdg_n < MIN_SAMPLES:
            return None
        if gps_source and len(self._gps) < MIN_SAMPLES and elapsed < gps_wait_s:
            return None
        gps_xy = None
        if gps_source and self._gps:
            xy = np.mean(np.array(self._gps), axis=0)
            gps_xy = (float(xy[0]), float(xy[1]))
        return AlignmentResult(
            accel_flu_m_s2=self._accel / self._n, gyro_flu_rad_s=self._gyro / self._n,
            heading_rad=math.atan2(self._hdg[1], self._hdg[0]) % _TWO_PI,
            baro_alt_m=float(np.mean(self._baro)), gps_xy_enu_m=gps_xy)
