"""A route as a MAVLink mission (what the autopilot flies by itself in a scenario's autopilot
flight): NAV_TAKEOFF, one NAV_WAYPOINT per route point, then NAV_LAND or NAV_RETURN_TO_LAUNCH.
"""

from __future__ import annotations

from typing import Sequence

from autopilot_bridge.config import MissionEndMode
from autopilot_bridge.geo_frame import GeoFrame
from autopilot_bridge.vehicle_interface import (
    MavFrame,
    MissionCommand,
    MissionItem,
)


def build_route_mission(geo: GeoFrame, route_enu_m: Sequence[Sequence[float]], altitude_m: float,
                        end: MissionEndMode) -> tuple[MissionItem, ...]:
    """A mission for a route: NAV_TAKEOFF to ``altitude_m`` above home, one NAV_WAYPOINT per route
    point at that height, then NAV_LAND at the last point or NAV_RETURN_TO_LAUNCH (seq 1..n)."""
    rel = int(MavFrame.GLOBAL_RELATIVE_ALT_INT)
    items = [MissionItem(seq=1, command=int(MissionCommand.NAV_TAKEOFF), frame=rel,
                         alt_m=float(altitude_m))]
    last = (0, 0)
    for x, y in route_enu_m:
        lat, lon = geo.to_geodetic(float(x), float(y))
        last = (int(round(lat * 1e7)), int(round(lon * 1e7)))
        items.append(MissionItem(seq=len(items) + 1, command=int(MissionCommand.NAV_WAYPOINT),
                                 frame=rel, lat_e7=last[0], lon_e7=last[1],
                                 alt_m=float(altitude_m)))
    if end == MissionEndMode.RTL:
        items.append(MissionItem(seq=len(items) + 1,
                                 command=int(MissionCommand.NAV_RETURN_TO_LAUNCH), frame=rel))
    else:
        items.append(MissionItem(seq=len(items) + 1, command=int(MissionCommand.NAV_LAND),
                                 frame=rel, lat_e7=last[0], lon_e7=last[1]))
    return tuple(items)
