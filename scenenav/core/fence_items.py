"""The MAVLink ids of geofence and rally items and ArduCopter's FENCE_TYPE bits: shared by the
autopilot (which stores and enforces the fence) and guidance (which plans inside it), which meet only
over MAVLink. Values from MAVLink's common.xml (MAV_CMD_NAV_FENCE_*, MAV_CMD_NAV_RALLY_POINT) and
ArduPilot's AC_Fence (AC_FENCE_TYPE_*)."""

from __future__ import annotations

from enum import IntEnum, IntFlag


class FenceCommand(IntEnum):
    """MAV_CMD ids of fence and rally items."""

    RETURN_POINT = 5000
    POLYGON_VERTEX_INCLUSION = 5001
    POLYGON_VERTEX_EXCLUSION = 5002
    CIRCLE_INCLUSION = 5003
    CIRCLE_EXCLUSION = 5004
    RALLY_POINT = 5100


class FenceType(IntFlag):
    """FENCE_TYPE bits (AC_FENCE_TYPE_*)."""

    NONE = 0
    ALT_MAX = 1
    CIRCLE = 2
    POLYGON = 4
    ALT_MIN = 8

    @classmethod
    def all_fences(cls) -> FenceType:
        return cls.ALT_MAX | cls.CIRCLE | cls.POLYGON | cls.ALT_MIN


class FenceEnable(IntEnum):
    """MAV_CMD_DO_FENCE_ENABLE param1 (common.xml FENCE_ENABLE_*; AC_Fence ``enable`` /
    ``disable_floor``)."""

    DISABLE = 0
    ENABLE = 1
    DISABLE_FLOOR = 2
