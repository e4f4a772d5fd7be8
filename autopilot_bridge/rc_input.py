"""Pilot input from a ground station: RC_CHANNELS_OVERRIDE and MANUAL_CONTROL as ArduCopter reads
them (pure; the MAVLink server decodes the messages, the flight core flies the result).

As ArduPilot (``GCS_MAVLINK::handle_rc_channels_override``, ``handle_manual_control``,
``RC_Channel.cpp``, ``ArduCopter/mode.cpp`` ``get_pilot_desired_*``, ``Attitude.cpp``):

* only the ground station SYSID_MYGCS may override; channels 1..8: UINT16_MAX leaves a channel
  as it is, 0 releases it; channels 9..18: 0 and UINT16_MAX leave it, UINT16_MAX - 1 releases it;
* an override lasts RC_OVERRIDE_TIME seconds after the last message (-1: for ever, 0: overrides
  are ignored);
* MANUAL_CONTROL x (pitch), y (roll), z (throttle 0..1000), r (yaw) in -1000..1000 become the
  PWM of the RCMAP channels (ArduPilot's ``manual_override``: pitch and roll as 1500 -/+ 500 x/1000
  with pitch reversed, i.e. stick forward = nose down; throttle 1000 + z);
* the channel of each axis comes from RCMAP_ROLL / _PITCH / _THROTTLE / _YAW; a PWM is scaled
  with RCn_MIN / _TRIM / _MAX / _REVERSED and the dead zone RCn_DZ: roll, pitch, yaw to
  -1..1 around the trim, throttle to 0..1 above MIN + DZ;
* lean angles: stick x ANGLE_MAX, the roll/pitch vector limited to ANGLE_MAX (circular limit);
  yaw rate: stick x PILOT_Y_RATE (deg/s, clockwise positive); climb rate in ALT_HOLD / LOITER /
  POSHOLD: the throttle outside mid-stick +/- THR_DZ (of 1000) scaled to PILOT_SPEED_UP above and
  PILOT_SPEED_DN (0: PILOT_SPEED_UP) below; STABILIZE throttle: ArduCopter's expo curve through
  the hover throttle at mid stick (``get_pilot_desired_throttle``).

Radio failsafe (FS_THR_ENABLE): with no RC receiver here, the overrides are the radio. Once
overrides have been received while armed, their loss (RC_OVERRIDE_TIME) is a radio failsafe, as
ArduCopter's after its radio timeout: see ``RadioFailsafeAction``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum

RC_CHANNEL_COUNT = 18
UINT16_MAX = 0xFFFF
# ArduPilot: ROLL_PITCH_YAW_INPUT_MAX (4500) and the throttle range 0..1000 are normalised here.
THROTTLE_MID = 0.5
MANUAL_CONTROL_RANGE = 1000.0
PWM_MID = 1500
PWM_HALF_RANGE = 500
PWM_THROTTLE_MIN = 1000
# ArduCopter get_pilot_desired_throttle: the hover throttle is clamped to 0.1 .. 0.9, the expo
# to -0.5 .. 1 (expo = -(hover - 0.5) / 0.375).
HOVER_THROTTLE_LIMITS = (0.1, 0.9)
THROTTLE_EXPO_LIMITS = (-0.5, 1.0)
THROTTLE_EXPO_SCALE = 0.375


class RadioFailsafeAction(IntEnum):
    """FS_THR_ENABLE (ArduCopter ``Parameters.cpp``)."""

    DISABLED = 0
    RTL = 1
    CONTINUE_MISSION = 2      # in AUTO; RTL otherwise
    LAND = 3
    SMARTRTL_OR_RTL = 4
    SMARTRTL_OR_LAND = 5
    AUTO_DO_LAND_START = 6    # the mission's landing sequence (AUTO_RTL), else RTL
    BRAKE_OR_LAND = 7


@dataclass(frozen=True)
class ChannelCalibration:
    """RCn_MIN / _TRIM / _MAX / _REVERSED / _DZ."""

    min_pwm: float
    trim_pwm: float
    max_pwm: float
    reversed: bool
    dead_zone: float

    def angle(self, pwm: float) -> float:
        """A centred channel (roll, pitch, yaw) as -1..1 outside the dead zone (``pwm_to_angle_dz``)."""
        lo, hi = self.trim_pwm - self.dead_zone, self.trim_pwm + self.dead_zone
        if pwm > hi and self.max_pwm > hi:
            out = (pwm - hi) / (self.max_pwm - hi)
        elif pwm < lo and lo > self.min_pwm:
            out = (pwm - lo) / (lo - self.min_pwm)
        else:
            out = 0.0
        out = min(max(out, -1.0), 1.0)
        return -out if self.reversed else out

    def range(self, pwm: float) -> float:
        """A range channel (throttle) as 0..1 above MIN + DZ (``pwm_to_range_dz``)."""
        r = min(max(pwm, self.min_pwm), self.max_pwm)
        if self.reversed:
            r = self.max_pwm - (r - self.min_pwm)
        low = self.min_pwm + self.dead_zone
        if r <= low or self.max_pwm <= low:
            return 0.0
        return (r - low) / (self.max_pwm - low)


@dataclass(frozen=True)
class PilotSticks:
    """Normalised sticks: roll, pitch, yaw -1..1 (right, nose-up / back, clockwise), throttle 0..1."""

    roll: float
    pitch: float
    yaw: float
    throttle: float

    @property
    def centred(self) -> bool:
        return self.roll == 0.0 and self.pitch == 0.0 and self.yaw == 0.0


class RcOverrides:
    """The overridden channels and when they last arrived (the caller's clock)."""

    def __init__(self) -> None:
        self._pwm = [0] * RC_CHANNEL_COUNT
        self._last_s: float | None = None

    @property
    def last_s(self) -> float | None:
        return self._last_s

    def pwm(self, channel: int) -> int:
        """PWM of channel 1..18 (0: not overridden)."""
        return self._pwm[channel - 1] if 1 <= channel <= RC_CHANNEL_COUNT else 0

    @property
    def channels(self) -> tuple[int, ...]:
        return tuple(self._pwm)

    def rc_channels_override(self, values: Sequence[int], now_s: float) -> None:
        """RC_CHANNELS_OVERRIDE chan1_raw .. chan18_raw."""
        for i, raw in enumerate(list(values)[:RC_CHANNEL_COUNT]):
            v = int(raw)
            if i < 8:
                if v != UINT16_MAX:
                    self._pwm[i] = v
            elif v not in (0, UINT16_MAX):
                self._pwm[i] = 0 if v == UINT16_MAX - 1 else v
        self._last_s = now_s

    def manual_control(self, x: float, y: float, z: float, r: float, rcmap: Sequence[int],
                       now_s: float) -> None:
        """MANUAL_CONTROL on the RCMAP channels (roll, pitch, throttle, yaw); INT16_MAX = unused."""
        roll_ch, pitch_ch, thr_ch, yaw_ch = rcmap
        axes = ((pitch_ch, x, True), (roll_ch, y, False), (yaw_ch, r, False))
        for ch, value, reverse in axes:
            if _used(value):
                v = max(-MANUAL_CONTROL_RANGE, min(MANUAL_CONTROL_RANGE, float(value)))
                v = -v if reverse else v
                self._set(ch, PWM_MID + round(v * PWM_HALF_RANGE / MANUAL_CONTROL_RANGE))
        if _used(z):
            v = max(0.0, min(MANUAL_CONTROL_RANGE, float(z)))
            self._set(thr_ch, PWM_THROTTLE_MIN + round(v * 2 * PWM_HALF_RANGE / MANUAL_CONTROL_RANGE))
        self._last_s = now_s

    def _set(self, channel: int, pwm: int) -> None:
        if 1 <= channel <= RC_CHANNEL_COUNT:
            self._pwm[channel - 1] = pwm

    def active(self, now_s: float, timeout_s: float) -> bool:
        """Whether the overrides count (RC_OVERRIDE_TIME: -1 never expires, 0 disables them)."""
        if self._last_s is None or timeout_s == 0.0:
            return False
        return timeout_s < 0.0 or now_s - self._last_s < timeout_s

    def clear(self) -> None:
        self._pwm = [0] * RC_CHANNEL_COUNT
        self._last_s = None


def _used(value: float) -> bool:
    # MANUAL_CONTROL: INT16_MAX marks an axis as unused
    return math.isfinite(value) and int(value) != 2 ** 15 - 1


def read_sticks(overrides: RcOverrides, rcmap: Sequence[int],
                calibration: Callable[[int], ChannelCalibration]) -> PilotSticks | None:
    """The sticks from the overridden RCMAP channels; None when none of them is overridden.

    An axis without an override reads as a stick at rest: roll, pitch, yaw at trim, throttle at
    mid stick (differs: there is no receiver here; ArduPilot would read the receiver's channel,
    e.g. MAVProxy's ``rc 3 1500`` overrides only the throttle)."""
    roll_ch, pitch_ch, thr_ch, yaw_ch = rcmap
    pwm = [overrides.pwm(ch) for ch in (roll_ch, pitch_ch, thr_ch, yaw_ch)]
    if all(p <= 0 for p in pwm):
        return None

    def angle(ch: int, p: int) -> float:
        return calibration(ch).angle(p) if p > 0 else 0.0

    return PilotSticks(roll=angle(roll_ch, pwm[0]), pitch=angle(pitch_ch, pwm[1]),
                       yaw=angle(yaw_ch, pwm[3]),
                       throttle=calibration(thr_ch).range(pwm[2]) if pwm[2] > 0 else THROTTLE_MID)


def lean_angles_rad(sticks: PilotSticks, angle_max_rad: float) -> tuple[float, float]:
    """(roll, pitch): sticks x ANGLE_MAX, the vector limited to ANGLE_MAX."""
    roll, pitch = sticks.roll * angle_max_rad, sticks.pitch * angle_max_rad
    total = math.hypot(roll, pitch)
    if total > angle_max_rad > 0.0:
        roll, pitch = roll * angle_max_rad / total, pitch * angle_max_rad / total
    return roll, pitch


def yaw_rate_rad_s(sticks: PilotSticks, pilot_y_rate_deg_s: float) -> float:
    return sticks.yaw * math.radians(pilot_y_rate_deg_s)


def climb_rate_m_s(sticks: PilotSticks, dead_zone: float, speed_up_m_s: float,
                   speed_dn_m_s: float) -> float:
    """ArduCopter get_pilot_desired_climb_rate; ``dead_zone`` is THR_DZ / 1000."""
    thr = min(max(sticks.throttle, 0.0), 1.0)
    top, bottom = THROTTLE_MID + dead_zone, THROTTLE_MID - dead_zone
    if thr < bottom and bottom > 0.0:
        return speed_dn_m_s * (thr - bottom) / bottom
    if thr > top and top < 1.0:
        return speed_up_m_s * (thr - top) / (1.0 - top)
    return 0.0


def stabilize_throttle(sticks: PilotSticks, hover_throttle: float) -> float:
    """ArduCopter get_pilot_desired_throttle: 0..1, mid stick = the hover throttle."""
    thr = min(max(sticks.throttle, 0.0), 1.0)
    thr_in = thr * 0.5 / THROTTLE_MID if thr < THROTTLE_MID \
        else 0.5 + (thr - THROTTLE_MID) * 0.5 / (1.0 - THROTTLE_MID)
    mid = min(max(hover_throttle, HOVER_THROTTLE_LIMITS[0]), HOVER_THROTTLE_LIMITS[1])
    expo = min(max(-(mid - 0.5) / THROTTLE_EXPO_SCALE, THROTTLE_EXPO_LIMITS[0]), THROTTLE_EXPO_LIMITS[1])
    return thr_in * (1.0 - expo) + expo * thr_in ** 3
