"""Guidance node: plans a potential-field route over the assistant map, uploads it to the
autopilot as a MAVLink mission, starts it, and replans when the map changes under the route or
the vehicle drifts off it.

Inputs
  ``autopilot/estimate``   NavEstimate (bus) — where the autopilot thinks it is
  the assistant-map file   (.npz; reloaded when it changes on disk, e.g. written by a perception node)
  MAVLink from the autopilot (HEARTBEAT, COMMAND_ACK, MISSION_* , MISSION_ITEM_REACHED)
Outputs
  MAVLink to the autopilot: the mission (takeoff, route waypoints, land), DO_SET_MODE AUTO, arming,
  MISSION_START, and on replans a new mission continuing from the vehicle's position
  ``events/guidance`` (Event: plans, replans and why), ``info/guidance``,
  liveliness ``nodes/guidance/guidance``
The planning itself is ``guidance.planner.plan_route`` (pure).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from guidance.config import PlannerConfig
from guidance.mavlink_client import AutopilotLink, MissionWaypoint
from guidance.planner import PlannedRoute, plan_route
from guidance.route import WorldInfo, load_assistant_map
from scenenav.bus import Bus, BusConfig
from scenenav.config import check
from scenenav.contracts import Event, NavEstimate, NodeInfo, Severity
from scenenav.keys import Keys
from worlds.frames import enu_to_geodetic

log = logging.getLogger(__name__)

NODE_ID = "guidance"


@dataclass(frozen=True)
class GuidanceNodeConfig:
    goal_enu_m: tuple[float, float] = (0.0, 0.0)   # where to fly, world metres (east, north)
    assistant_map: str = ""                         # .npz; empty: the run's perception map
    altitude_m: float = 100.0                       # cruise altitude above home
    replan_drift_m: float = 40.0                    # replan when this far off the route
    check_period_s: float = 1.0                     # wall seconds between drift/map checks
    land_at_goal: bool = True
    mavlink_url: str = "tcp:127.0.0.1:5760"

    def __post_init__(self) -> None:
        check(self.altitude_m > 0, "altitude_m", self.altitude_m, "a positive height in m")
        check(self.replan_drift_m > 0, "replan_drift_m", self.replan_drift_m, "> 0 m")
        check(self.check_period_s > 0, "check_period_s", self.check_period_s, "> 0 s")


def cross_track_m(route_xy: np.ndarray, p_xy: np.ndarray) -> float:
    """Distance from a point to a polyline (metres)."""
    a, b = route_xy[:-1], route_xy[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p_xy - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-9), 0, 1)
    closest = a + ab * t[:, None]
    return float(np.min(np.hypot(*(closest - p_xy).T)))


class GuidanceNode:
    def __init__(self, world: WorldInfo, bus_cfg: BusConfig, cfg: GuidanceNodeConfig,
                 planner_cfg: PlannerConfig | None = None):
        self.world = world
        self.cfg = cfg
        self.planner_cfg = planner_cfg or PlannerConfig(altitude_m=cfg.altitude_m)
        self.keys = Keys(bus_cfg.namespace)
        self.bus = Bus(bus_cfg)
        self._estimate: NavEstimate | None = None
        self._stop = threading.Event()
        self.route: PlannedRoute | None = None
        self.replans = 0
        self._map_mtime = 0.0
        self.bus.subscribe(self.keys.nav_estimate, NavEstimate, self._on_estimate)
        self.bus.declare_token(self.keys.node_alive("guidance", NODE_ID))
        self.bus.publish(self.keys.node_info(NODE_ID), NodeInfo(0, NODE_ID, "guidance",
                                                                f"goal {cfg.goal_enu_m}"))

    def _on_estimate(self, msg: NavEstimate, _k: str) -> None:
        self._estimate = msg

    def event(self, text: str, severity: Severity = Severity.INFO) -> None:
        t = self._estimate.timestamp_us if self._estimate else 0
        self.bus.publish(self.keys.events(NODE_ID), Event(t, NODE_ID, int(severity), text))
        log.info("%s", text)

    def _probability(self) -> np.ndarray:
        path = Path(self.cfg.assistant_map)
        self._map_mtime = path.stat().st_mtime
        return load_assistant_map(path).probability

    def _plan_from(self, start_xy: tuple[float, float]) -> PlannedRoute:
        route = plan_route(self._probability(), self.world.m_per_px, start_xy, self.cfg.goal_enu_m,
                           self.planner_cfg)
        self.event(f"planned {route.length_m:.0f} m route ({len(route.waypoints_xy_m)} waypoints, "
                   f"min clearance {route.min_clearance_m:.1f} m, {route.method.value})")
        return route

    def _mission(self, route: PlannedRoute) -> list[MissionWaypoint]:
        lat, lon = enu_to_geodetic(route.waypoints_xy_m[:, 0], route.waypoints_xy_m[:, 1],
                                   self.world.origin_lat_deg, self.world.origin_lon_deg)
        return [MissionWaypoint(float(a), float(o), self.cfg.altitude_m) for a, o in zip(lat, lon)]

    def _wait_estimate(self, timeout_s: float = 120.0) -> NavEstimate:
        t0 = time.monotonic()
        while self._estimate is None and not self._stop.is_set():
            if time.monotonic() - t0 > timeout_s:
                raise TimeoutError("no autopilot estimate on the bus")
            time.sleep(0.05)
        return self._estimate

    def run(self) -> None:
        link = AutopilotLink(self.cfg.mavlink_url)
        try:
            link.wait_heartbeat()
            est = self._wait_estimate()
            start = (est.position_enu_m[0], est.position_enu_m[1])
            self.route = self._plan_from(start)
            link.upload_mission(self._mission(self.route), takeoff_alt_m=self.cfg.altitude_m,
                                land_at_end=self.cfg.land_at_goal)
            link.set_mode("GUIDED")
            link.arm()
            link.set_mode("AUTO")
            link.start_mission()
            self.event("mission started")
            self._watch(link)
        finally:
            link.close()

    def _watch(self, link: AutopilotLink) -> None:
        next_check = time.monotonic()
        while not self._stop.is_set():
            msg = link.poll()
            if msg is None:
                time.sleep(0.02)
            if time.monotonic() < next_check:
                continue
            next_check = time.monotonic() + self.cfg.check_period_s
            est = self._estimate
            if est is None or self.route is None or est.position_enu_m[2] < 0.5 * self.cfg.altitude_m:
                continue
            here = np.array(est.position_enu_m[:2])
            if math.hypot(*(here - self.route.waypoints_xy_m[-1])) < 30.0:
                continue   # arriving: nothing to replan
            why = None
            drift = cross_track_m(self.route.waypoints_xy_m, here)
            if drift > self.cfg.replan_drift_m:
                why = f"drifted {drift:.0f} m off the route"
            elif Path(self.cfg.assistant_map).stat().st_mtime != self._map_mtime:
                why = "assistant map changed"
            if why is None:
                continue
            try:
                route = self._plan_from((float(here[0]), float(here[1])))
            except Exception as exc:   # keep flying the old route; say why
                self.event(f"replan failed ({why}): {exc}", Severity.WARNING)
                continue
            self.replans += 1
            self.route = route
            link.upload_mission(self._mission(route), takeoff_alt_m=None, land_at_end=self.cfg.land_at_goal)
            link.set_current(1)
            link.set_mode("AUTO")
            self.event(f"replanned ({why})", Severity.NOTICE)

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        self.bus.close()
