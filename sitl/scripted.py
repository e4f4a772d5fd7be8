"""Scripted flight: a kinematic trajectory along a polyline at constant altitude and speed.

Used when a scenario flies without the autopilot (``flight.mode: scripted``) — e.g. to log the vision
pipeline over a fixed path as the paper did. Pure module: numpy only.

The vehicle starts over the first waypoint at the cruise altitude and flies the legs at constant
speed; corners are rounded with circular arcs of radius ``turn_radius_m`` (clipped to half the
shorter leg) so velocity is continuous; heading follows the track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenenav.core.frames import wrap_2pi


@dataclass(frozen=True)
class KinematicState:
    position_enu_m: np.ndarray
    velocity_enu_m_s: np.ndarray
    acceleration_enu_m_s2: np.ndarray
    heading_rad: float
    yaw_rate_rad_s: float


class ScriptedTrajectory:
    """Constant-speed path through 2-D waypoints with rounded corners."""

    def __init__(self, waypoints_xy_m, altitude_m: float, speed_m_s: float, turn_radius_m: float):
        pts = np.asarray(waypoints_xy_m, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError("scripted flight needs at least two (x, y) waypoints")
        if speed_m_s <= 0:
            raise ValueError("scripted flight speed must be positive")
        self.altitude_m = float(altitude_m)
        self.speed_m_s = float(speed_m_s)
        # Build a sequence of segments: ("line", p0, p1) and ("arc", centre, r, a0, dtheta).
        self._segments: list[tuple] = []
        starts = [pts[0]]
        for i in range(1, len(pts) - 1):
            a, b, c = pts[i - 1], pts[i], pts[i + 1]
            d1, d2 = b - a, c - b
            l1, l2 = np.linalg.norm(d1), np.linalg.norm(d2)
            if l1 < 1e-6 or l2 < 1e-6:
                continue
            u1, u2 = d1 / l1, d2 / l2
            turn = math.atan2(u1[0] * u2[1] - u1[1] * u2[0], float(np.dot(u1, u2)))
            if abs(turn) < 1e-3:
                continue
            tan_half = math.tan(abs(turn) / 2.0)
            r = min(turn_radius_m, 0.5 * min(l1, l2) / max(tan_half, 1e-9))
            cut = r * tan_half
            p_in, p_out = b - u1 * cut, b + u2 * cut
            self._segments.append(("line", starts[-1], p_in))
            normal = np.array([-u1[1], u1[0]]) * math.copysign(1.0, turn)
            centre = p_in + normal * r
            a0 = math.atan2(p_in[1] - centre[1], p_in[0] - centre[0])
            self._segments.append(("arc", centre, r, a0, turn))
            starts.append(p_out)
        self._segments.append(("line", starts[-1], pts[-1]))
        self._lengths = np.array([self._seg_length(s) for s in self._segments])
        self._cum = np.concatenate([[0.0], np.cumsum(self._lengths)])
        self.length_m = float(self._cum[-1])
        self.duration_s = self.length_m / self.speed_m_s

    @staticmethod
    def _seg_length(seg: tuple) -> float:
        if seg[0] == "line":
            return float(np.linalg.norm(seg[2] - seg[1]))
        return abs(seg[2] * seg[4])

    def state(self, t_s: float) -> KinematicState:
        s = min(max(t_s, 0.0) * self.speed_m_s, self.length_m)
        i = int(np.searchsorted(self._cum, s, side="right") - 1)
        i = min(max(i, 0), len(self._segments) - 1)
        seg = self._segments[i]
        ds = s - self._cum[i]
        v = self.speed_m_s if t_s < self.duration_s else 0.0
        if seg[0] == "line":
            p0, p1 = seg[1], seg[2]
            length = max(self._lengths[i], 1e-9)
            u = (p1 - p0) / length
            xy = p0 + u * ds
            vel = u * v
            acc = np.zeros(2)
            yaw_rate = 0.0
        else:
            centre, r, a0, turn = seg[1], seg[2], seg[3], seg[4]
            sign = math.copysign(1.0, turn)
            ang = a0 + sign * ds / r
            xy = centre + r * np.array([math.cos(ang), math.sin(ang)])
            tangent = sign * np.array([-math.sin(ang), math.cos(ang)])
            vel = tangent * v
            acc = (centre - xy) / r * (v * v / r)
            yaw_rate = sign * v / r
        heading = wrap_2pi(math.atan2(vel[0], vel[1])) if v > 0 else self._final_heading()
        return KinematicState(
            position_enu_m=np.array([xy[0], xy[1], self.altitude_m]),
            velocity_enu_m_s=np.array([vel[0], vel[1], 0.0]),
            acceleration_enu_m_s2=np.array([acc[0], acc[1], 0.0]),
            heading_rad=heading,
            yaw_rate_rad_s=-yaw_rate,  # heading is clockwise: a left (CCW) turn lowers it
        )

    def _final_heading(self) -> float:
        seg = self._segments[-1]
        d = seg[2] - seg[1]
        return wrap_2pi(math.atan2(d[0], d[1]))
