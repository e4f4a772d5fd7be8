"""Vibration levels as ArduPilot's ``AP_InertialSensor::calc_vibration_and_clipping`` computes them
for the VIBRATION message (pure: no zenoh, no pymavlink).

Per axis: a 5 Hz low-pass of the accelerometer is the "floor" (AP_INERTIAL_SENSOR_ACCEL_VIBE_FLOOR_FILT_HZ);
the squared difference from it goes through a 2 Hz low-pass (AP_INERTIAL_SENSOR_ACCEL_VIBE_FILT_HZ);
the vibration level is its square root (m/s/s). Clipping counts samples whose magnitude on an axis
reaches the sensor's range (ArduPilot: 16 g here-ish per sensor; the simulator's IMU has no
range, so the counts stay 0 unless a sample exceeds ``CLIP_LIMIT_M_S2``).
"""

from __future__ import annotations

import math

import numpy as np

VIBE_FLOOR_FILT_HZ = 5.0
VIBE_FILT_HZ = 2.0
GRAVITY_M_S2 = 9.80665
CLIP_LIMIT_M_S2 = 16.0 * GRAVITY_M_S2 - 0.1 * GRAVITY_M_S2   # AP_InertialSensor: 15.9 g


def _alpha(cutoff_hz: float, dt_s: float) -> float:
    """First-order low-pass coefficient (ArduPilot's LowPassFilter calc_lowpass_alpha_dt)."""
    rc = 1.0 / (2.0 * math.pi * cutoff_hz)
    return dt_s / (dt_s + rc)


class VibrationMonitor:
    """Feed every accelerometer sample; ``levels`` and ``clip_counts`` as in VIBRATION."""

    def __init__(self) -> None:
        self._floor: np.ndarray | None = None
        self._vibe_sq = np.zeros(3)
        self.clip_counts = [0, 0, 0]

    def add(self, accel_m_s2, dt_s: float) -> None:
        a = np.asarray(accel_m_s2, dtype=float)
        if a.shape != (3,) or not (np.all(np.isfinite(a)) and dt_s > 0.0):
            return
        if self._floor is None:
            self._floor = a.copy()
        self._floor += _alpha(VIBE_FLOOR_FILT_HZ, dt_s) * (a - self._floor)
        diff_sq = (a - self._floor) ** 2
        self._vibe_sq += _alpha(VIBE_FILT_HZ, dt_s) * (diff_sq - self._vibe_sq)
        for i in range(3):
            if abs(a[i]) >= CLIP_LIMIT_M_S2:
                self.clip_counts[i] += 1

    @property
    def levels(self) -> tuple[float, float, float]:
        v = np.sqrt(self._vibe_sq)
        return float(v[0]), float(v[1]), float(v[2])
