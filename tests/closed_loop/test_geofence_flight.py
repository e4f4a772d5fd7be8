"""Geofence and rally points on the in-process flight (``CoreFlight``), one short flight: a
circular fence of 25 m (FENCE_TYPE 2), GUIDED north past it -> "Fence Breached" and FENCE_ACTION 1
(RTL), and that RTL heads for the uploaded rally point (RALLY_INCL_HOME 0) instead of home."""

from __future__ import annotations

import numpy as np
from support.sim_flight import CoreFlight

from autopilot_bridge.geofence import FenceCommand
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    MavFrame,
    MavSeverity,
    MissionItem,
    StatusTextEvent,
)

RALLY_ENU_M = (-20.0, 10.0)   # inside the fence


def test_circle_fence_breach_rtl_to_the_rally_point():
    f = CoreFlight(9, gps=True, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=3, EK3_SRC1_VELXY=3,
                   FENCE_ENABLE=1, FENCE_TYPE=2, FENCE_RADIUS=30, FENCE_ACTION=1, RALLY_INCL_HOME=0,
                   RTL_ALT=500, WPNAV_SPEED=600)
    c = f.core
    try:
        f.run(3.0)
        lat, lon = c.geo.to_geodetic(*RALLY_ENU_M)
        rally = MissionItem(seq=0, command=int(FenceCommand.RALLY_POINT),
                            frame=int(MavFrame.GLOBAL_RELATIVE_ALT), lat_e7=round(lat * 1e7),
                            lon_e7=round(lon * 1e7), alt_m=10.0)
        assert c.rally_changed((rally,)).ok
        assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok and c.takeoff(5.0).ok
        assert f.run(20.0, until=lambda: f.p[2] > 4.5)
        home = c.home_enu_m
        lat, lon = c.geo.to_geodetic(float(home[0]), float(home[1]) + 80.0)
        assert c.reposition(lat, lon, 5.0, AltFrame.RELATIVE_HOME, None, None).ok
        assert f.run(15.0, until=lambda: c.mode == CopterMode.RTL)
        texts = [(e.severity, e.text) for e in c.drain_events() if isinstance(e, StatusTextEvent)]
        assert (MavSeverity.CRITICAL, "Fence Breached") in texts
        est = c.estimate()
        assert float(np.hypot(*(est.position_enu_m[:2] - home[:2]))) > 29.0
        # RTL flies towards the rally point, not home: after a few seconds it is nearer to it
        f.run(10.0)
        p = np.asarray(c.estimate().position_enu_m[:2])
        assert np.linalg.norm(p - np.array(RALLY_ENU_M)) < np.linalg.norm(
            np.asarray(est.position_enu_m[:2]) - np.array(RALLY_ENU_M)) - 5.0
        assert c.fence.breach_count == 1 and c.stats["failsafe_fence_rtl"] == 1
    finally:
        f.close()
