"""ArduCopter flight modes as seen on MAVLink (HEARTBEAT.custom_mode, DO_SET_MODE param2).

Pure module (no pymavlink). Mode numbers are ArduCopter's ``Mode::Number`` enumeration
(ArduPilot ``ArduCopter/mode.h``); number 8, 10 and 12 are unused there. Only a subset is
implemented by the scenenav flight core: ``SUPPORTED_MODES``.
"""

from __future__ import annotations

from enum import IntEnum


class CopterMode(IntEnum):
    """ArduCopter custom_mode numbers (ArduPilot ``ArduCopter/mode.h``, ``Mode::Number``)."""

    STABILIZE = 0
    ACRO = 1
    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    CIRCLE = 7
    LAND = 9
    DRIFT = 11
    SPORT = 13
    FLIP = 14
    AUTOTUNE = 15
    POSHOLD = 16
    BRAKE = 17
    THROW = 18
    AVOID_ADSB = 19
    GUIDED_NOGPS = 20
    SMART_RTL = 21
    FLOWHOLD = 22
    FOLLOW = 23
    ZIGZAG = 24
    SYSTEMID = 25
    AUTOROTATE = 26
    AUTO_RTL = 27
    TURTLE = 28


# Modes the scenenav flight core implements; any other known number is refused with a reason.
SUPPORTED_MODES: frozenset[CopterMode] = frozenset({
    CopterMode.STABILIZE,
    CopterMode.ALT_HOLD,
    CopterMode.AUTO,
    CopterMode.GUIDED,
    CopterMode.LOITER,
    CopterMode.RTL,
    CopterMode.LAND,
    CopterMode.POSHOLD,
    CopterMode.BRAKE,
    CopterMode.CIRCLE,
    CopterMode.SMART_RTL,
    CopterMode.AUTO_RTL,      # AUTO flying the mission's landing sequence (not a mode of its own)
})

# Modes in which ArduCopter's horizontal position controller runs; HEARTBEAT.base_mode then
# carries MAV_MODE_FLAG_GUIDED_ENABLED (ArduCopter sets it when the NE position controller is
# active, ``GCS_MAVLINK_Copter::base_mode``; this is the mode-level approximation of that).
POSITION_CONTROLLED_MODES: frozenset[CopterMode] = frozenset({
    CopterMode.AUTO,
    CopterMode.GUIDED,
    CopterMode.LOITER,
    CopterMode.RTL,
    CopterMode.CIRCLE,
    CopterMode.LAND,
    CopterMode.POSHOLD,
    CopterMode.BRAKE,
    CopterMode.SMART_RTL,
    CopterMode.FOLLOW,
    CopterMode.AUTO_RTL,
})


# Modes with a position controller in the flight core (failsafes treat them as position modes).
POSITION_MODES: frozenset[CopterMode] = frozenset({CopterMode.GUIDED, CopterMode.AUTO,
                                                   CopterMode.LOITER, CopterMode.RTL, CopterMode.LAND,
                                                   CopterMode.POSHOLD, CopterMode.BRAKE,
                                                   CopterMode.CIRCLE, CopterMode.SMART_RTL,
                                                   CopterMode.AUTO_RTL})
# Modes that need a horizontal position estimate to be entered (ArduCopter requires_GPS()).
NEEDS_POSITION: frozenset[CopterMode] = frozenset({CopterMode.GUIDED, CopterMode.AUTO,
                                                   CopterMode.LOITER, CopterMode.RTL,
                                                   CopterMode.POSHOLD, CopterMode.BRAKE,
                                                   CopterMode.CIRCLE, CopterMode.SMART_RTL,
                                                   CopterMode.AUTO_RTL})
# Modes a ground station may arm in (ArduCopter Mode::allows_arming for GCS arming; BRAKE's is
# false, POSHOLD's true).
ARMABLE_MODES: frozenset[CopterMode] = frozenset({CopterMode.STABILIZE, CopterMode.ALT_HOLD,
                                                  CopterMode.GUIDED, CopterMode.LOITER,
                                                  CopterMode.POSHOLD})


def mode_from_number(number: int) -> CopterMode | None:
    """The CopterMode for a custom_mode number, or None when ArduCopter has no such mode."""
    try:
        return CopterMode(int(number))
    except (ValueError, OverflowError):
        return None


def mode_from_name(name: str) -> CopterMode | None:
    """The CopterMode for a name such as ``"guided"`` or ``"ALT_HOLD"``, or None."""
    key = name.strip().upper().replace("-", "_")
    return CopterMode.__members__.get(key)
