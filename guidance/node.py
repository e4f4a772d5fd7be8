"""Guidance node: plans a potential-field route over the assistant map, uploads it to the autopilot
as a MAVLink mission, starts it, and replans when the map changes under the route or the vehicle
drifts off it.

Inputs
  ``clock``                ClockTick     simulated time; in lockstep the node is a TICK member from
                                          start to landing; the main loop gets only the ticks a
                                          start try or a drift check is due at (the simulator waits
                                          while it plans, uploads or replans), and each ack answers
                                          ahead through the tick before the next one due (an ack of
                                          seq M answers every tick up to M: no message per tick)
  ``autopilot/estimate``   NavEstimate   where the autopilot thinks it is (drift checks, replans): the
                                          estimate at or before the check's tick, waited for (at
                                          most ESTIMATE_WAIT_S) until it has surely arrived
  ``autopilot/status``     AutopilotStatus  armed / mission progress / landed
  the assistant-map file   .npz; re-read when it changes on disk (e.g. replaced by a later flight)
  MAVLink from the autopilot (HEARTBEAT, COMMAND_ACK, MISSION_REQUEST_INT, MISSION_ACK; the
  geofence: MISSION_COUNT / MISSION_ITEM_INT of mission_type FENCE and the FENCE_* PARAM_VALUEs)
Outputs
  MAVLink to the autopilot, as any companion computer would send: the mission (take-off, route
  waypoints, land or RTL), GUIDED, arm, AUTO, MISSION_START; on a replan a new mission continuing
  from the vehicle's position, then AUTO from its first waypoint
  ``events/guidance`` (Event: plans, replans and why), ``info/guidance``,
  liveliness ``nodes/guidance/guidance`` and, in lockstep until the node is done (landed, no route,
  stopped), ``lockstep/member/tick/guidance`` + ``lockstep/ack/guidance`` (LockstepAck)
  ``<run>/route.json`` and ``route.png`` (``route-<n>.json`` after the n-th replan)

The planning itself is ``guidance.planner.plan_through`` (pure), on the assistant map with the
autopilot's geofence drawn in as bad areas (``guidance.fence``, pure): before the first plan and
before every replan the node downloads the fence and reads FENCE_ENABLE / _TYPE / _RADIUS / _MARGIN
/ _ALT_MAX, so routes stay FENCE_MARGIN inside it and the cruise altitude below FENCE_ALT_MAX; a
start or goal outside the fence is "no route". Determinism: in lockstep every plan, upload and
replan happens at a fixed tick while the simulator waits for this node, and a drift check reads the
autopilot's estimate of its own tick (``scenenav.core.timed_history``), so a lockstep run that replans
is as reproducible as one that does not (until session 23 the node left lockstep once the mission ran,
and a replanning flight diverged from its twin after the first replan). In real time (no lockstep) a
replan happens while the simulation runs on, as on a real companion computer.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
from collections import deque
from enum import Enum
from pathlib import Path

import numpy as np

from guidance.config import GuidanceRunConfig, PlannerConfig
from guidance.fence import (
    FENCE_PARAM_NAMES,
    Fence,
    apply_fence,
    check_points_inside,
    cruise_altitude_m,
    fence_from_items,
)
from guidance.mavlink_client import AutopilotLink, MavlinkClientError, MissionWaypoint
from guidance.planner import PlannedRoute, plan_keeping_on_map, snap_to_good_area
from guidance.smoothing import polyline_length
from scenenav.core.bus import Bus, BusConfig
from scenenav.core.contracts import (
    AutopilotStatus,
    ClockMode,
    ClockTick,
    Event,
    LockstepAck,
    LockstepRole,
    NavEstimate,
    NodeInfo,
    RunState,
    Severity,
)
from scenenav.core.errors import UserError
from scenenav.core.formats.assistant_map_file import read_probability_map
from scenenav.core.formats.route_file import ROUTE_FORMAT_VERSION, round_or_none, write_route_json
from scenenav.core.formats.world_manifest import WorldManifest
from scenenav.core.frames import enu_to_geodetic
from scenenav.core.geometry import distance_to_polyline_m
from scenenav.core.keys import Keys
from scenenav.core.presence import announce_node
from scenenav.core.timed_history import sample_at, sample_settled

log = logging.getLogger(__name__)

NODE_ID = "guidance"
#: Within this distance of the final goal nothing is replanned (the vehicle is arriving).
ARRIVING_M = 30.0
#: Wall seconds a drift check waits for the autopilot's estimate of its tick; after that it uses the
#: newest one it has (``stats["estimate_late"]``; only a stalled or dead autopilot gets there).
ESTIMATE_WAIT_S = 0.5
#: Estimates kept for the drift checks (5 s at the autopilot's 20 Hz; a check reads one of its tick).
ESTIMATE_HISTORY = 100


class Phase(str, Enum):
    WAITING = "waiting"      # before the mission is started
    FLYING = "flying"        # mission running; drift and map checks
    DONE = "done"            # landed, or gave up


def cross_track_m(route_xy: np.ndarray, p_xy: np.ndarray) -> float:
    """Distance (m) from a point to a polyline."""
    return float(distance_to_polyline_m(p_xy, route_xy)[0])


def replan_reason(route_xy: np.ndarray, here_xy, goal_xy, drift_limit_m: float,
                  map_changed: bool) -> str | None:
    """Why the route must be replanned from ``here_xy`` (None: keep flying it). Pure."""
    here = np.asarray(here_xy, dtype=float).reshape(2)
    if math.hypot(*(here - np.asarray(goal_xy, dtype=float))) < ARRIVING_M:
        return None
    drift = cross_track_m(route_xy, here)
    if drift > drift_limit_m:
        return f"drifted {drift:.0f} m off the route"
    if map_changed:
        return "assistant map changed"
    return None


def remaining_goals(goals: tuple[tuple[float, float], ...], reached: int) -> tuple[tuple[float, float], ...]:
    """Goals not yet reached (the final goal is always kept)."""
    return tuple(goals[min(reached, len(goals) - 1):])


class GuidanceNode:
    """See the module docstring. ``run()`` blocks until stopped or the vehicle has landed."""

    def __init__(self, world: WorldManifest, bus_cfg: BusConfig, cfg: GuidanceRunConfig,
                 planner_cfg: PlannerConfig | None = None, out_dir: Path | None = None):
        self.world = world
        self.cfg = cfg
        self.planner_cfg = planner_cfg or PlannerConfig(altitude_m=cfg.altitude_m)
        self.out_dir = out_dir
        self.keys = Keys(bus_cfg.namespace)
        self.bus = Bus(bus_cfg)
        self.phase = Phase.WAITING
        #: why the mission can never start (no route), or None
        self.failure: str | None = None
        self.route_xy: np.ndarray | None = None
        self.legs: list[PlannedRoute] = []
        self.replans = 0
        self.stats = {"ticks": 0, "start_tries": 0, "replans": 0, "replan_failures": 0, "estimate_late": 0}
        self._estimates: deque[tuple[int, NavEstimate]] = deque(maxlen=ESTIMATE_HISTORY)
        self._estimate_arrived = threading.Condition()
        self._status: AutopilotStatus | None = None
        self._ticks: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._map_mtime = 0.0
        self._next_try_us = int(round(cfg.start_after_s * 1e6))
        self._next_check_us = 0
        self._last_t_us = 0
        self._link: AutopilotLink | None = None
        self.fence = Fence()
        self._member_token = None
        self._acked_through = -1        # the newest tick answered (ahead) in lockstep
        self._ack_lock = threading.Lock()
        self.bus.subscribe(self.keys.nav_estimate, NavEstimate, self._on_estimate)
        self.bus.subscribe(self.keys.autopilot_status, AutopilotStatus, self._on_status)
        self.bus.subscribe(self.keys.clock, ClockTick, self._on_tick)
        self.presence = announce_node(self.bus, self.keys, "guidance", NODE_ID)
        if cfg.lockstep:
            self._member_token = self.bus.declare_token(
                self.keys.lockstep_member(LockstepRole.TICK, NODE_ID))
        goals = " -> ".join(f"({x:.0f}, {y:.0f})" for x, y in cfg.goals_enu_m)
        self.bus.publish(self.keys.node_info(NODE_ID), NodeInfo(0, NODE_ID, "guidance", f"goals {goals}"))

    # ------------------------------------------------------------------ callbacks (Zenoh threads)
    def _on_estimate(self, msg: NavEstimate, _k: str) -> None:
        with self._estimate_arrived:
            self._estimates.append((msg.timestamp_us, msg))
            self._estimate_arrived.notify_all()

    def _on_status(self, msg: AutopilotStatus, _k: str) -> None:
        self._status = msg

    def _on_tick(self, msg: ClockTick, _k: str) -> None:
        """Hand the main loop only the ticks it acts on: those at which a start try or a drift check
        is due, and the last one; the others are counted here (no thread wake-up per tick) and, in
        lockstep, answered unless an earlier ack already answered them ahead (only the ticks before
        the node's first action are)."""
        if self._acts_on(msg):
            self._ticks.put(msg)
            return
        self.stats["ticks"] += 1
        self._last_t_us = msg.timestamp_us
        self._ack(msg)

    def _due_us(self) -> int | None:
        """Simulated time of the next tick the main loop acts on (None: none, the node is done)."""
        if self.phase is Phase.WAITING:
            return self._next_try_us
        if self.phase is Phase.FLYING:
            return self._next_check_us
        return None

    def _ack(self, tick: ClockTick) -> None:
        """In lockstep, answer ``tick`` and every later tick before the next one due (an ack of seq
        M answers all up to M, docs/interfaces.md section 5): the simulator then does not wait for
        this node, nor send it anything to answer, until a start try or a check is due. The due time
        is set before the ack, so a tick the receive thread passes by is always answered already."""
        if self._member_token is None or tick.mode != ClockMode.LOCKSTEP.value:
            return
        with self._ack_lock:
            if tick.tick <= self._acked_through:
                return
            through = tick.tick
            due_us = self._due_us()
            if due_us is not None and tick.tick_period_us > 0:
                through += max(0, -(-(due_us - tick.timestamp_us) // tick.tick_period_us) - 1)
            self._acked_through = through
            self.bus.publish(self.keys.lockstep_ack(NODE_ID), LockstepAck(
                tick.timestamp_us + (through - tick.tick) * tick.tick_period_us, NODE_ID,
                LockstepRole.TICK.value, through))

    def _acts_on(self, msg: ClockTick) -> bool:
        # Read from a Zenoh thread while the main loop may change them: a stale phase or due time
        # only hands over a tick more, which the main loop handles as before.
        if msg.state == RunState.FINISHED.value:
            return True
        if self.phase is Phase.WAITING:
            return msg.timestamp_us >= self._next_try_us
        if self.phase is Phase.FLYING:
            return msg.timestamp_us >= self._next_check_us
        return False

    # ------------------------------------------------------------------ helpers
    def event(self, text: str, severity: Severity = Severity.INFO) -> None:
        self.bus.publish(self.keys.events(NODE_ID), Event(self._last_t_us, NODE_ID, int(severity), text))
        log.log(logging.WARNING if severity <= Severity.WARNING else logging.INFO, "%s", text)

    def _probability(self) -> np.ndarray:
        path = Path(self.cfg.assistant_map)
        self._map_mtime = path.stat().st_mtime
        return read_probability_map(path).probability

    def _map_changed(self) -> bool:
        try:
            return Path(self.cfg.assistant_map).stat().st_mtime != self._map_mtime
        except OSError:
            return False

    def load_fence(self) -> Fence:
        """The autopilot's geofence over MAVLink (``self.fence``); on failure the last one is kept."""
        if self._link is None:
            return self.fence
        try:
            params = self._link.read_params(FENCE_PARAM_NAMES)
            items = self._link.download_fence() if int(params.get("FENCE_ENABLE", 0)) == 1 else []
            fence = fence_from_items(items, params, self.cfg.start_enu_m, self.world.origin_lat_deg,
                                     self.world.origin_lon_deg)
        except (MavlinkClientError, UserError) as exc:
            self.event(f"geofence not read ({exc}); planning with the last one", Severity.WARNING)
            return self.fence
        if fence.horizontal or fence.alt_max_m is not None:
            self.event(f"geofence: {fence.describe()}")
        self.fence = fence
        return fence

    def altitude_m(self) -> float:
        """The route altitude: the configured one, kept FENCE_MARGIN below FENCE_ALT_MAX."""
        return cruise_altitude_m(self.cfg.altitude_m, self.fence)

    def plan(self, start_xy: tuple[float, float], goals: tuple[tuple[float, float], ...]) -> np.ndarray:
        """Plan through ``goals`` from ``start_xy`` inside ``self.fence``; sets ``self.route_xy`` and
        writes the route file."""
        points = (start_xy, *goals)
        check_points_inside(self.fence, points, ["start"] + [f"goal {i + 1}" for i in range(len(goals))])
        probability = apply_fence(self._probability(), self.world.m_per_px, self.fence)
        legs, self.route_xy, escaped, kept = plan_keeping_on_map(probability, self.world.m_per_px, points,
                                                                 self.planner_cfg, self.cfg.snap_goals_m)
        if self.planner_cfg.keep_footprint_on_map and not kept:
            self.event("no route keeps the camera footprint on the map: planned one that may leave it "
                       "(guidance.keep_footprint_on_map)")
        if escaped is not None:
            self.event(f"start ({start_xy[0]:.0f}, {start_xy[1]:.0f}) m lies on a bad matching area: the route "
                       f"leaves it straight to ({escaped[0]:.0f}, {escaped[1]:.0f}) m, "
                       f"{math.dist(start_xy, escaped):.0f} m (guidance.snap_goals_m)")
        self.legs = legs
        length = polyline_length(self.route_xy)
        clearance = min(leg.min_clearance_m for leg in legs)
        methods = ", ".join(sorted({leg.method.value for leg in legs}))
        self.event(f"planned {length:.0f} m route ({len(self.route_xy)} waypoints, {len(legs)} legs, "
                   f"min clearance {clearance:.1f} m, {methods})")
        self._write_route(length, clearance)
        return self.route_xy

    def _snap_goals(self) -> None:
        """With ``snap_goals_m`` > 0, move each goal that lies on a bad matching area to the nearest
        point with the route's clearance, once, before the first plan; every later plan and replan
        uses the moved goals. A goal with no such point within
        ``snap_goals_m`` stays (the plan then says why there is no route)."""
        limit = self.cfg.snap_goals_m
        if limit <= 0.0:
            return
        probability = apply_fence(self._probability(), self.world.m_per_px, self.fence)
        goals = []
        for i, goal in enumerate(self.cfg.goals_enu_m):
            moved = snap_to_good_area(probability, self.world.m_per_px, goal, self.planner_cfg, limit)
            if moved is not None and moved != tuple(goal):
                self.event(f"goal {i + 1} ({goal[0]:.0f}, {goal[1]:.0f}) m lies on a bad matching "
                           f"area: moved {math.dist(goal, moved):.0f} m to "
                           f"({moved[0]:.0f}, {moved[1]:.0f}) m (guidance.snap_goals_m)")
            goals.append(tuple(goal) if moved is None else moved)
        self.cfg = dataclasses.replace(self.cfg, goals_enu_m=tuple(goals))

    def _write_route(self, length_m: float, clearance_m: float) -> None:
        if self.out_dir is None:
            return
        name = "route.json" if self.replans == 0 else f"route-{self.replans}.json"
        lat, lon = enu_to_geodetic(self.route_xy[:, 0], self.route_xy[:, 1],
                                   self.world.origin_lat_deg, self.world.origin_lon_deg)
        doc = {
            "format_version": ROUTE_FORMAT_VERSION, "replan": self.replans,
            "sim_time_s": self._last_t_us * 1e-6,
            "length_m": round(float(length_m), 2), "min_clearance_m": round_or_none(clearance_m, 3),
            "straight_line_bad_fraction": [round(leg.straight_line_bad_fraction, 4) for leg in self.legs],
            "route_bad_fraction": [round(leg.route_bad_fraction, 4) for leg in self.legs],
            "waypoints": [{"x_m": round(float(x), 3), "y_m": round(float(y), 3),
                           "lat": float(a), "lon": float(o)}
                          for (x, y), a, o in zip(self.route_xy, lat, lon, strict=False)],
            "assistant_map": str(self.cfg.assistant_map),
            "planner": self.legs[0].planner_params(),
        }
        write_route_json(self.out_dir / name, doc)

    def _mission(self) -> list[MissionWaypoint]:
        # The first point is the take-off (or replan) position: not a waypoint to fly to.
        pts = self.route_xy[1:]
        lat, lon = enu_to_geodetic(pts[:, 0], pts[:, 1], self.world.origin_lat_deg,
                                   self.world.origin_lon_deg)
        alt = self.altitude_m()
        return [MissionWaypoint(float(a), float(o), alt) for a, o in zip(lat, lon, strict=False)]

    # ------------------------------------------------------------------ main loop
    def run(self) -> None:
        self._link = AutopilotLink(self.cfg.mavlink_url)
        try:
            self._link.wait_heartbeat()
            while not self._stop.is_set() and self.phase is not Phase.DONE:
                try:
                    tick = self._ticks.get(timeout=0.05)
                except queue.Empty:
                    self._link.heartbeat()
                    self._drain_mavlink()
                    continue
                self._on_clock(tick)
        finally:
            self._leave_lockstep()
            self._link.close()

    def _drain_mavlink(self) -> None:
        while self._link.poll() is not None:
            pass

    def _on_clock(self, tick: ClockTick) -> None:
        self._last_t_us = tick.timestamp_us
        if tick.state == RunState.FINISHED.value:
            self.phase = Phase.DONE
            return
        self.stats["ticks"] += 1
        try:
            if self.phase is Phase.WAITING and tick.timestamp_us >= self._next_try_us:
                self._try_start(tick)
            elif self.phase is Phase.FLYING and tick.timestamp_us >= self._next_check_us:
                self._next_check_us = tick.timestamp_us + int(round(self.cfg.check_period_s * 1e6))
                self._check(tick)
        finally:
            self._ack(tick)

    def _leave_lockstep(self) -> None:
        if self._member_token is not None:
            self._member_token.undeclare()
            self._member_token = None

    def _try_start(self, tick: ClockTick) -> None:
        """Plan (once), upload, GUIDED, arm, AUTO, MISSION_START; while lockstep holds the clock."""
        self.stats["start_tries"] += 1
        self._next_try_us = tick.timestamp_us + int(round(self.cfg.retry_period_s * 1e6))
        link = self._link
        if self.route_xy is None:
            self.load_fence()
            try:
                self._snap_goals()
                self.plan(self.cfg.start_enu_m, self.cfg.goals_enu_m)
            except UserError as exc:
                self.event(f"no route: {exc}", Severity.ERROR)
                self.failure = f"no route: {exc}"
                self.phase = Phase.DONE
                return
            link.upload_mission(self._mission(), takeoff_alt_m=self.altitude_m(),
                                end=self.cfg.end)
            self.event(f"mission uploaded: {len(self.route_xy) - 1} waypoints at "
                       f"{self.altitude_m():.0f} m, then {self.cfg.end.value}")
        try:
            link.set_mode("GUIDED")
            link.arm(retry_s=0.0)
            link.set_mode("AUTO")
            link.start_mission()
        except MavlinkClientError as exc:
            log.info("start not possible yet (%s); retrying in %.1f s", exc, self.cfg.retry_period_s)
            return
        self.phase = Phase.FLYING
        self._next_check_us = tick.timestamp_us + int(round(self.cfg.check_period_s * 1e6))
        self.event("mission started")

    def _check(self, tick: ClockTick) -> None:
        st = self._status
        if st is not None and st.landed and not st.armed:
            self.event("landed: guidance done")
            self.phase = Phase.DONE
            return
        est = self._estimate_at(tick.timestamp_us)
        if est is None or self.route_xy is None or est.position_enu_m[2] < 0.5 * self.cfg.altitude_m:
            return
        here = (float(est.position_enu_m[0]), float(est.position_enu_m[1]))
        why = replan_reason(self.route_xy, here, self.cfg.goals_enu_m[-1], self.cfg.replan_drift_m,
                            self._map_changed())
        if why is None:
            return
        goals = remaining_goals(self.cfg.goals_enu_m, self._goals_reached(here))
        try:
            self.replans += 1
            self.load_fence()
            self.plan(here, goals)
            self._link.upload_mission(self._mission(), takeoff_alt_m=None, end=self.cfg.end)
            self._link.set_current(1)
            self._link.set_mode("AUTO")
        except (UserError, MavlinkClientError) as exc:   # keep flying the old mission; say why
            self.stats["replan_failures"] += 1
            self.event(f"replan failed ({why}): {exc}", Severity.WARNING)
            return
        self.stats["replans"] += 1
        self.event(f"replanned ({why})", Severity.NOTICE)

    def _estimate_at(self, t_us: int) -> NavEstimate | None:
        """The autopilot's estimate at or before ``t_us``, once it has surely arrived (at most
        ``ESTIMATE_WAIT_S``): the newest one to arrive would depend on which Zenoh link was faster."""
        with self._estimate_arrived:
            if not self._estimate_arrived.wait_for(
                    lambda: sample_settled(self._estimates, t_us) or self._stop.is_set(), ESTIMATE_WAIT_S):
                self.stats["estimate_late"] += 1
            return sample_at(self._estimates, t_us)

    def _goals_reached(self, here: tuple[float, float]) -> int:
        """How many via-points lie behind the vehicle: the index of the leg it is closest to."""
        if not self.legs:
            return 0
        dists = [cross_track_m(leg.waypoints_xy_m, np.array(here)) for leg in self.legs]
        # legs are planned from the current start; leg i ends at goal i of the remaining goals
        done_before = len(self.cfg.goals_enu_m) - len(self.legs)
        return done_before + int(np.argmin(dists))

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> dict:
        self.stop()
        self.presence.close()
        self.bus.close()
        return dict(self.stats, phase=self.phase.value, replans=self.replans)
