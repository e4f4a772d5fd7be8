"""Alignment of the navigation filter on the ground (part of ``FlightCore``).

IMU, baro and compass samples are averaged at rest for ``FlightCoreConfig.align_time_s`` (and, with
GPS as the position source, up to ``gps_wait_s`` for three GPS fixes); then the EKF is initialised at
the mean, home and the EKF origin are set there, and the controller starts landed. Position: the mean
GPS fix, or the known take-off point (``start_enu_m``) without GPS.

Pure module: no zenoh, no pymavlink.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from autopilot_bridge.config import PositionSource
from autopilot_bridge.vehicle_interface import (
    HomeChangedEvent,
    MavSeverity,
)

logger = logging.getLogger(__name__)

_TWO_PI = 2.0 * math.pi


class AlignmentMixin:
    """Part of ``FlightCore`` (``autopilot_bridge.flight_core``); works on its state."""

    def _init_alignment(self) -> None:
        """Accumulators of the samples taken at rest before the EKF is aligned."""
        self._align_t0: float | None = None
        self._align_accel = np.zeros(3)
        self._align_gyro = np.zeros(3)
        self._align_n = 0
        self._align_baro: list[float] = []
        self._align_hdg = np.zeros(2)
        self._align_hdg_n = 0
        self._align_gps: list[tuple[float, float]] = []

    def _accumulate_alignment(self, accel: np.ndarray, gyro: np.ndarray, dt_s: float) -> None:
        if self._align_t0 is None:
            self._align_t0 = self._now_s
        self._align_accel += accel
        self._align_gyro += gyro
        self._align_n += 1
        elapsed = self._now_s - self._align_t0
        if elapsed < self.cfg.align_time_s or len(self._align_baro) < 3 or self._align_hdg_n < 3:
            return
        gps_source = self.nav.position_source == PositionSource.GPS
        if gps_source and len(self._align_gps) < 3 and elapsed < self.cfg.gps_wait_s:
            return
        accel_mean = self._align_accel / self._align_n
        gyro_mean = self._align_gyro / self._align_n
        heading = math.atan2(self._align_hdg[1], self._align_hdg[0]) % _TWO_PI
        baro = float(np.mean(self._align_baro))
        if gps_source and self._align_gps:
            xy = np.mean(np.array(self._align_gps), axis=0)
            how = "GPS"
        else:
            xy = np.array(self.cfg.start_enu_m, dtype=float)
            how = "the known take-off point"
        pos = (float(xy[0]), float(xy[1]), self.cfg.ground_z_m)
        try:
            self.nav.initialise(accel_mean, heading, baro, gyro_flu_rad_s=gyro_mean,
                                position_enu_m=pos)
        except ValueError as exc:
            logger.warning("EKF alignment failed (%s); retrying", exc)
            self._reset_alignment()
            return
        self._origin = np.array(pos)
        self._home = np.array(pos)
        self._ground_xy = np.array(pos[:2])
        self._ground_next_s = self._now_s
        self.fc.reset(self.nav.state(), landed=True)
        self._events.append(HomeChangedEvent())
        self._announce(MavSeverity.INFO, "EKF3 IMU0 origin set")
        self._announce(MavSeverity.INFO, f"EKF3 IMU0 is using {self._source_name()}")
        self._bus_text(MavSeverity.INFO, f"EKF aligned at ({pos[0]:.1f}, {pos[1]:.1f}) m from {how}")
        self._baro.clear()
        self._compass.clear()

    def _reset_alignment(self) -> None:
        self._align_t0 = None
        self._align_accel[:] = 0.0
        self._align_gyro[:] = 0.0
        self._align_n = 0
        self._align_baro.clear()
        self._align_hdg[:] = 0.0
        self._align_hdg_n = 0
        self._align_gps.clear()
