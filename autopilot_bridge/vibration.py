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
        # per axis, Python floats (three-element numpy arithmetic costs more than the arithmetic)
        self._floor: list[float] | None = None
        self._vibe_sq = [0.0, 0.0, 0.0]
        self.clip_counts = [0, 0, 0]
        self._alpha_dt = math.nan               # the dt the two coefficients below are for
        self._alpha_floor = self._alpha_vibe = 0.0

    def add(self, accel_m_s2, dt_s: float) -> None:
        a = np.asarray(accel_m_s2, dtype=float)
        if a.shape != (3,):
            return
        acc = a.tolist()
        if not (all(map(math.isfinite, acc)) and dt_s > 0.0):
            return
        if self._floor is None:
            self._floor = list(acc)
        if dt_s != self._alpha_dt:
            self._alpha_dt = dt_s
            self._alpha_floor = _alpha(VIBE_FLOOR_FILT_HZ, dt_s)
            self._alpha_vibe = _alpha(VIBE_FILT_HZ, dt_s)
        floor, vibe = self._floor, self._vibe_sq
        k_floor, k_vibe = self._alpha_floor, self._alpha_vibe
        for i in range(3):
            x = acc[i]
            floor[i] += k_floor * (x - floor[i])
            d = x - floor[i]
            vibe[i] += k_vibe * (d * d - vibe[i])
            if abs(x) >= CLIP_LIMIT_M_S2:
                self.clip_counts[i] += 1

    @property
    def levels(self) -> tuple[float, float, float]:
        v = self._vibe_sq
        return math.sqrt(v[0]), math.sqrt(v[1]), math.sqrt(v[2])
