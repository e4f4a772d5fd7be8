"""CIRCLE mode and the mission's NAV_LOITER_TURNS: fly a circle around a centre (pure).

As ArduCopter's ``AC_Circle`` (``libraries/AC_WPNav/AC_Circle.cpp``, read for behaviour):

* CIRCLE mode puts the centre CIRCLE_RADIUS ahead of the vehicle's stopping point along its
  heading, so the vehicle starts on the circle's edge, and faces the centre while it circles;
* the angular rate is CIRCLE_RATE (deg/s, positive clockwise seen from above), limited so that the
  speed stays within WPNAV_SPEED and the centripetal acceleration within half of WPNAV_ACCEL
  (``v_max = min(WPNAV_SPEED, sqrt(0.5 * WPNAV_ACCEL * r))``), and ramped up at
  ``max(WPNAV_ACCEL / r, 2 deg/s/s)``;
* a radius of 0 is the panorama: the vehicle stays on the centre and turns at CIRCLE_RATE;
* NAV_LOITER_TURNS flies to the circle's nearest edge point first (ArduCopter's "move to edge"),
  then circles ``turns`` times (radius param3, negative = counter-clockwise) and completes.

Bearings here are compass bearings (clockwise from north) of the target seen from the centre;
positions are world ENU metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot_bridge.config import GuidanceConfig
from autopilot_bridge.control import PositionTarget
from autopilot_bridge.ekf import NavState
from autopilot_bridge.flight_laws import LawKind
from autopilot_bridge.guidance_law import GuidanceEvent, GuidanceEventKind, GuidanceLaw, Waypoint, WaypointTracker

# ArduCopter AC_Circle.cpp: AC_CIRCLE_ANGULAR_ACCEL_MIN, 2 deg/s/s
ANGULAR_ACCEL_MIN_RAD_S2 = math.radians(2.0)
# An edge point closer than this needs no approach leg (ArduCopter's move-to-edge is skipped
# when the vehicle is already at the edge).
ON_EDGE_M = 1.0


@dataclass(frozen=True)
class CircleSettings:
    """CIRCLE_RADIUS (m, >= 0) and CIRCLE_RATE (deg/s, signed: positive clockwise)."""

    radius_m: float
    rate_deg_s: float


def centre_ahead(stop_enu_m, heading_rad: float, radius_m: float) -> tuple[float, float]:
    """CIRCLE mode's centre: ``radius_m`` ahead of the stopping point along the heading."""
    return (float(stop_enu_m[0]) + radius_m * math.sin(heading_rad),
            float(stop_enu_m[1]) + radius_m * math.cos(heading_rad))


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class Circle(GuidanceLaw):
    """Circle ``centre_xy`` at height ``z_m``; ``turns`` None circles until the mode changes."""

    kind = LawKind.CIRCLE

    def __init__(self, cfg: GuidanceConfig, centre_xy, z_m: float, settings: CircleSettings,
                 start_enu_m, *, turns: float | None = None, heading_rad: float = 0.0) -> None:
        self._cfg = cfg
        self.centre = np.array([float(centre_xy[0]), float(centre_xy[1])])
        self._z = float(z_m)
        self.radius_m = max(0.0, float(settings.radius_m))
        rate = math.radians(float(settings.rate_deg_s))
        r = self.radius_m
        if r > 0.0:
            v_max = min(cfg.wp_speed_m_s, math.sqrt(0.5 * cfg.wp_accel_m_s2 * r))
            w_max = v_max / r
            self._w_max = min(max(rate, -w_max), w_max)
            self._w_accel = max(cfg.wp_accel_m_s2 / r, ANGULAR_ACCEL_MIN_RAD_S2)
        else:
            self._w_max = rate
            self._w_accel = max(abs(rate), ANGULAR_ACCEL_MIN_RAD_S2)
        self._w = 0.0
        self._turns = turns
        self.angle_total_rad = 0.0
        start = np.asarray(start_enu_m, dtype=float)
        off = start[:2] - self.centre
        self._bearing = (math.atan2(float(off[0]), float(off[1])) if r > 0.0 and np.hypot(*off) > 1e-3
                         else float(heading_rad))
        self._events: list[GuidanceEvent] = []
        self._complete = False
        self._approach: WaypointTracker | None = None
        edge = self._point(self._bearing)
        if r > 0.0 and float(np.hypot(*(start[:2] - edge))) > ON_EDGE_M:
            self._approach = WaypointTracker(cfg, [Waypoint((float(edge[0]), float(edge[1]), self._z))],
                                             start)
        self._heading: float | None = None

    @property
    def complete(self) -> bool:
        return self._complete

    @property
    def circling(self) -> bool:
        return self._approach is None

    def _point(self, bearing: float) -> np.ndarray:
        r = self.radius_m
        return self.centre + r * np.array([math.sin(bearing), math.cos(bearing)])

    def handle_position_reset(self, delta_xy_m) -> None:
        self.centre = self.centre + np.asarray(delta_xy_m, dtype=float)[:2]
        if self._approach is not None:
            self._approach.handle_position_reset(delta_xy_m)

    def update(self, nav: NavState, dt_s: float) -> PositionTarget:
        if self._approach is not None:
            target = self._approach.update(nav, dt_s)
            self._approach.pop_events()
            if not self._approach.complete:
                return target
            self._approach = None
        # ramp the angular rate towards its limit
        step = self._w_accel * dt_s
        self._w += min(max(self._w_max - self._w, -step), step)
        d = self._w * dt_s
        if not self._complete:
            self._bearing = _wrap_pi(self._bearing + d)
            self.angle_total_rad += d
        if self._turns is not None and not self._complete \
                and abs(self.angle_total_rad) >= 2.0 * math.pi * self._turns:
            self._complete = True
            self._w = 0.0
            self._w_max = 0.0
            self._events.append(GuidanceEvent(GuidanceEventKind.MISSION_COMPLETE, 0))
        r = self.radius_m
        p = self._point(self._bearing)
        if r > 0.0:
            # tangential velocity feed-forward; the nose points at the centre
            v = self._w * r
            vel = (v * math.cos(self._bearing), -v * math.sin(self._bearing), 0.0)
            heading = (self._bearing + math.pi) % (2.0 * math.pi)
        else:
            vel = (0.0, 0.0, 0.0)
            heading = self._bearing % (2.0 * math.pi)
        if self._complete:
            vel = (0.0, 0.0, 0.0)
        return PositionTarget((float(p[0]), float(p[1]), self._z), vel, heading_rad=heading)
