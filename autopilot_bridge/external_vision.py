"""External vision over MAVLink the ArduPilot way (pure: no zenoh, no pymavlink): what
``AP_VisualOdom_MAV`` and ``GCS_MAVLINK::handle_vision_position_estimate`` / ``handle_odometry`` do
to VISION_POSITION_ESTIMATE and ODOMETRY before the EKF fuses them.

* **Time**: the sender's ``usec`` is mapped to the autopilot's clock by ArduPilot's
  ``JitterCorrection`` (the smallest local - remote offset seen over a window of samples is the
  transport lag floor; a remote clock that jumps resets it), then ``VISO_DELAY_MS`` earlier is the
  time the EKF fuses the fix at (the filter moves the fix forward with its velocity estimate).
* **Lever arm** ``VISO_POS_X/Y/Z`` (body FRD, m): the camera's position, subtracted after rotating
  it by the vehicle attitude, so the fused position is the body origin's.
* **Position error**: cbrt(c_xx^2 + c_yy^2 + c_zz^2) of the pose covariance (the 21-element upper
  triangle: indices 0, 6, 11), as GCS_Common.cpp; NaN (unknown) -> ``VISO_POS_M_NSE``, which is
  also the floor (``AP_VisualOdom``).
* **Height and yaw** (``EK3_SRCn_POSZ`` / ``EK3_SRCn_YAW`` = 6 in the active source set): the fix's
  height and the message's yaw (VISION_POSITION_ESTIMATE's yaw, ODOMETRY's quaternion) are fused
  instead of the barometer / compass, at the same delayed time as the position; the yaw error is cbrt(c_rr^2 + c_pp^2 + c_yy^2) of the pose
  covariance (indices 15, 18, 20, as GCS_Common.cpp) with ``VISO_YAW_M_NSE`` as the floor.
* **reset_counter**: a change (after the first message) resets the EKF horizontal position to the
  fix (ArduPilot records the reset and EK3 resets its position to external nav).
* **quality** (ODOMETRY): below ``VISO_QUAL_MIN`` the message is ignored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenenav.core.rotations import quat_from_euler_zyx, quat_to_rotation_matrix

JITTER_WINDOW = 100          # samples per minimum-lag window (ArduPilot JitterCorrection: 100 loops)
JITTER_MAX_LAG_S = 0.5       # a larger local - remote jump resets the estimate (max_lag_ms 500)


@dataclass(frozen=True)
class VisoSettings:
    """The VISO_* parameters."""

    delay_s: float = 0.010                 # VISO_DELAY_MS
    lever_arm_frd_m: tuple[float, float, float] = (0.0, 0.0, 0.0)   # VISO_POS_X/Y/Z
    pos_noise_m: float = 0.2               # VISO_POS_M_NSE
    quality_min: int = 0                   # VISO_QUAL_MIN
    yaw_noise_rad: float = 0.2             # VISO_YAW_M_NSE


class JitterCorrection:
    """Remote timestamps -> local seconds (see the module docstring)."""

    def __init__(self) -> None:
        self._offset_s: float | None = None
        self._window_min_s = math.inf
        self._count = 0

    def local_time_s(self, remote_s: float, local_now_s: float) -> float:
        diff = local_now_s - remote_s
        if self._offset_s is None or diff < self._offset_s or diff - self._offset_s > JITTER_MAX_LAG_S:
            self._offset_s = diff
            self._window_min_s = math.inf
            self._count = 0
        self._window_min_s = min(self._window_min_s, diff)
        self._count += 1
        if self._count >= JITTER_WINDOW:       # let the floor drift up with the remote clock
            self._offset_s = self._window_min_s
            self._window_min_s = math.inf
            self._count = 0
        return min(remote_s + self._offset_s, local_now_s)


def position_error_m(cov21, floor_m: float) -> float:
    """ArduPilot's posErr from the pose covariance, at least ``floor_m``."""
    c = tuple(cov21)
    if len(c) < 12 or not all(math.isfinite(c[i]) for i in (0, 6, 11)):
        return floor_m
    return max(floor_m, float(np.cbrt(c[0] ** 2 + c[6] ** 2 + c[11] ** 2)))


def angle_error_rad(cov21, floor_rad: float) -> float:
    """ArduPilot's angErr from the pose covariance (roll, pitch, yaw variances), at least ``floor_rad``."""
    c = tuple(cov21)
    if len(c) < 21 or not all(math.isfinite(c[i]) for i in (15, 18, 20)):
        return floor_rad
    return max(floor_rad, float(np.cbrt(c[15] ** 2 + c[18] ** 2 + c[20] ** 2)))


def heading_of(body_to_ned: np.ndarray) -> float:
    """Heading (clockwise from north, rad, 0..2 pi) of the body x axis of an FRD -> NED rotation."""
    r = np.asarray(body_to_ned, dtype=float)
    return float(math.atan2(r[1, 0], r[0, 0]) % (2.0 * math.pi))


def attitude_matrix(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Body FRD -> NED rotation for aerospace Euler angles."""
    return quat_to_rotation_matrix(quat_from_euler_zyx(yaw_rad, pitch_rad, roll_rad))


def body_origin_ned(pos_ned_m, body_to_ned: np.ndarray, lever_arm_frd_m) -> np.ndarray:
    """The body origin's NED position for a sensor at ``lever_arm_frd_m`` (VISO_POS_X/Y/Z)."""
    arm = np.asarray(lever_arm_frd_m, dtype=float)
    pos = np.asarray(pos_ned_m, dtype=float)
    if not np.any(arm):
        return pos
    return pos - np.asarray(body_to_ned, dtype=float) @ arm


class ResetCounter:
    """True when a message's reset_counter differs from the previous message's."""

    def __init__(self) -> None:
        self._last: int | None = None

    def changed(self, counter: int) -> bool:
        changed = self._last is not None and counter != self._last
        self._last = counter
        return changed
