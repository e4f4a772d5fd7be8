"""Simulator node: pybullet physics, sensors and the lockstep clock.

Inputs
  ``actuators/motors``            MotorCommand   (autopilot flights; zero thrust until one arrives;
                                                  also the tick answer of its sender ``node_id``)
  ``lockstep/ack/*``              LockstepAck    (answers of the other lockstep members)
  ``lockstep/member/**``          liveliness     (who must answer)
  ``autopilot/status``            AutopilotStatus (ends the run when the mission is done and landed)
Outputs
  ``clock``                       ClockTick      (every control tick, after that tick's sensors)
  ``sensors/imu``                 ImuSample      (every tick)
  ``sensors/baro``, ``sensors/compass``, ``sensors/gps``   at their configured rates (GPS only if enabled)
  ``sensors/power``               PowerSample    (battery voltage and current, ``sim.battery.rate_hz``)
  ``sensors/flow``                FlowSample     (optical flow and range, ``sim.flow.rate_hz``, if enabled)
  ``sensors/camera``              CameraFrame    (camera rate)
  ``truth/pose``                  TruthPose      (every tick; evaluation and logs only)
  ``events/<id>``, ``info/<id>``  Event, NodeInfo

A thin shell: the physics, sensors, battery and camera scheduling are ``sitl.core.SimulatorCore``;
this node adds the bus, the lockstep/realtime clock, the camera render pipeline and the end of the run.
Its configuration (``sitl.config.SimNodeConfig``) is resolved by the app layer (``scenenav node sim``).

Lockstep (default): per tick the simulator publishes sensors and the clock, then (while the members
compute) the truth and a due camera frame, waits for every live ``tick`` member (the autopilot) and,
``clock.camera_answer_ticks`` ticks after a camera frame (default 0: at once), every ``camera``
member (perception), then applies the newest motor command for the tick's physics sub-steps. Realtime: the same, paced so that
simulated time runs at ``speed_factor`` times the wall clock; ``tick`` members are still waited for
(physics never runs on a stale motor command, as in ArduPilot's SITL), ``camera`` members at most one
tick period.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from scenenav.core.bus import Bus, BusConfig
from scenenav.core.contracts import (
    AutopilotStatus,
    ClockMode,
    ClockTick,
    Event,
    LockstepAck,
    LockstepRole,
    MotorCommand,
    NodeInfo,
    RunState,
    Severity,
)
from scenenav.core.frames import heading_to_enu_yaw
from scenenav.core.keys import Keys
from scenenav.core.lockstep import LockstepBarrier
from scenenav.core.presence import announce_node
from sitl.config import SimNodeConfig
from sitl.core import SimulatorCore, TickOutput
from sitl.surroundings import BUILDING_MIN_HEIGHT_M, Surface
from worlds.landcover import LandCover

log = logging.getLogger(__name__)

NODE_ID = "sim"
#: Realtime mode: wall seconds the loop may fall behind the paced clock and catch up (a short stall);
#: further behind, it paces on from where it is instead of running flat out to catch up.
MAX_PACE_LAG_S = 0.25
#: Lockstep: camera frames a suspended camera member may hold unanswered (about 0.5 MB at 200 x 200);
#: while every camera member is suspended that far behind (frozen), further frames are withheld.
SUSPENDED_BACKLOG_FRAMES = 4
#: Lockstep: the run ends this many ticks after the simulated time of the AutopilotStatus that
#: reports the mission done (or a landing before it): by then that status has arrived in every run.
END_AFTER_STATUS_TICKS = 2


@dataclass
class SimStats:
    """What a run of the node did (written to ``<run>/sim_stats.json``); times are wall seconds."""

    ticks: int = 0
    camera_frames: int = 0
    #: frames not published because every camera member was suspended (frozen) at the time
    camera_frames_withheld: int = 0
    camera_rejoin_waits: int = 0      # lockstep: times the clock waited for a camera member to join again
    ack_timeouts: int = 0
    time_physics_s: float = 0.0
    time_render_s: float = 0.0
    time_bus_wait_s: float = 0.0
    time_publish_s: float = 0.0
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    real_time_factor: float = 0.0
    end_reason: str = ""
    dropped: dict[str, int] = field(default_factory=dict)
    #: per lockstep member: answers timed and their mean answer time (publish -> ack), wall ms
    member_answers: dict[str, int] = field(default_factory=dict)
    member_answer_ms_mean: dict[str, float] = field(default_factory=dict)
    #: realtime mode: wall seconds the loop fell behind the paced clock (then paced from there on)
    realtime_lag_s: float = 0.0


def sensor_surface(sim, world) -> Surface | None:
    """The world's buildings for the sensor models that need them (magnetic anomalies, GPS
    multipath, baro ground effect over roofs, the flow module's range finder); None when none of them is on or the world is flat."""
    needed = (sim.compass.anomaly_mgauss > 0.0 or sim.gps.multipath_std_m > 0.0
              or sim.baro.ground_effect_m != 0.0 or sim.flow.enabled)
    if not needed or world.dsm_m is None:
        return None
    if world.landcover is not None:
        built = np.isin(world.landcover, [int(LandCover.BUILDING_UNIFORM), int(LandCover.BUILDING_TEXTURED)])
    else:   # an imported world: every raised pixel may be a building
        built = world.dsm_m > BUILDING_MIN_HEIGHT_M
    return Surface(world.dsm_m, built, world.m_per_px)


class SimulatorNode:
    """The simulator on the bus. ``world`` gives the orthophoto, the surface model (``dsm_m``,
    ``facade_rgb``, None on a flat world), ``m_per_px`` and the geodetic origin
    (``world.manifest.origin_lat_deg`` / ``origin_lon_deg``)."""

    def __init__(self, cfg: SimNodeConfig, world, bus_cfg: BusConfig):
        from sitl.render_worker import CameraPipeline

        self.cfg = cfg
        self.world = world
        self.keys = Keys(bus_cfg.namespace)
        m = world.manifest
        self.core = SimulatorCore(cfg.sim, cfg.clock.tick_rate_hz, cfg.seed, m.origin_lat_deg,
                                  m.origin_lon_deg, surface=sensor_surface(cfg.sim, world))
        self.camera = CameraPipeline(world.orthophoto, world.m_per_px, cfg.sim.camera,
                                     heights_m=world.dsm_m, facade_rgb=world.facade_rgb,
                                     optics_seed=self.core.optics_seed)
        if cfg.scripted is not None:
            self.core.start_scripted(cfg.scripted)
        else:
            sx, sy = cfg.start_enu_m
            self.core.start_at(np.array([sx, sy, 0.0]),
                               heading_to_enu_yaw(math.radians(cfg.start_heading_deg)))
        self.tick_rate_hz = cfg.clock.tick_rate_hz
        self.tick_us = self.core.tick_us

        self.bus = Bus(bus_cfg)
        self.barrier = LockstepBarrier()
        self._motor_lock = threading.Lock()
        self._motor: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
        self._stop = threading.Event()
        self._rejoin_given_up = False     # clock.rejoin_timeout_s ran out for this shortage
        self._mission_done = threading.Event()
        self._landed_early = threading.Event()
        # simulated time (us) of the AutopilotStatus that ended the mission; the run ends
        # END_AFTER_STATUS_TICKS ticks later, so the last tick does not depend on when it arrived
        self._end_status_us: int | None = None
        self._has_flown = False
        self.stats = SimStats()

        self.bus.subscribe(self.keys.motors, MotorCommand, self._on_motor)
        self.bus.subscribe(self.keys.lockstep_ack_all, LockstepAck, self._on_ack)
        self.bus.subscribe(self.keys.autopilot_status, AutopilotStatus, self._on_status)
        self.bus.watch_liveliness(self.keys.lockstep_member_all, self._on_member)
        self.presence = announce_node(self.bus, self.keys, "sim", NODE_ID)

    # --------------------------------------------------------------------------- callbacks
    def _on_motor(self, msg: MotorCommand, _key: str) -> None:
        # plain floats: this runs on the lockstep's critical path, between the answer and the step
        cmd = msg.command
        if all(math.isfinite(c) for c in cmd):
            motor = tuple(min(1.0, max(0.0, c)) for c in cmd) if msg.armed else (0.0,) * len(cmd)
            with self._motor_lock:
                self._motor = motor
        else:
            self.bus.dropped["motors: non-finite command"] += 1
        # the command is its sender's answer to the tick (after it is applied, so the loop woken
        # by the answer steps on it)
        self.barrier.ack(msg.node_id, LockstepRole.TICK, msg.tick)

    def _on_ack(self, msg: LockstepAck, _key: str) -> None:
        try:
            role = LockstepRole(msg.role)
        except ValueError:
            self.bus.dropped["lockstep/ack: unknown role"] += 1
            return
        self.barrier.ack(msg.node_id, role, msg.seq)

    def _on_member(self, key: str, alive: bool) -> None:
        parts = key.split("/")
        try:
            role = LockstepRole(parts[-2])
        except (ValueError, IndexError):
            log.warning("ignoring malformed lockstep member key %s", key)
            return
        self.barrier.member_changed(role, parts[-1], alive)
        self.event(Severity.INFO, f"lockstep member {'joined' if alive else 'left'}: {parts[-1]}")

    def _on_status(self, msg: AutopilotStatus, _key: str) -> None:
        if not self.cfg.end_with_mission:
            return   # ground-station sessions (idle) end only when the user stops them
        if msg.armed:
            self._has_flown = True
        if msg.landed and not msg.armed and (msg.mission_complete or self._has_flown):
            if self._end_status_us is None:
                self._end_status_us = msg.timestamp_us
            if msg.mission_complete:
                self._mission_done.set()
            else:                      # e.g. a failsafe landing: nothing more will happen
                self._landed_early.set()

    def stop(self) -> None:
        self._stop.set()

    def event(self, severity: Severity, text: str, t_us: int | None = None) -> None:
        ts = t_us if t_us is not None else self.stats.ticks * self.tick_us
        self.bus.publish(self.keys.events(NODE_ID), Event(ts, NODE_ID, int(severity), text))
        log.info("%s", text)

    # ------------------------------------------------------------------------------- loop
    def _await_camera_rejoin(self, t_s: float, t_us: int) -> None:
        """Lockstep, before a frame: with fewer camera members than the run expected (one died or
        left), wait up to ``clock.rejoin_timeout_s`` wall seconds for one to join, once per
        shortage: a restarted perception node takes seconds to load, and without the wait the clock
        would fly those seconds (tens of simulated ones) without it."""
        expected = self.cfg.expected_camera_members
        timeout_s = self.cfg.clock.rejoin_timeout_s
        present = self.barrier.members(LockstepRole.CAMERA)
        if len(present) >= expected:
            self._rejoin_given_up = False
            return
        if self._rejoin_given_up or timeout_s <= 0.0 or self._stop.is_set():
            return
        self.event(Severity.INFO, f"t={t_s:.2f}s: {len(present)} of the {expected} expected camera "
                                  f"members present; the clock waits up to {timeout_s:.0f} s (clock.rejoin_timeout_s) "
                                  f"for one to join", t_us)
        t0 = time.perf_counter()
        if self.barrier.wait_members({LockstepRole.CAMERA: expected}, timeout_s,
                                     cancelled=self._stop.is_set):
            self.stats.camera_rejoin_waits += 1
            self.event(Severity.INFO, f"t={t_s:.2f}s: camera member back after "
                                      f"{time.perf_counter() - t0:.1f} s "
                                      f"({', '.join(self.barrier.members(LockstepRole.CAMERA))}); "
                                      f"the clock goes on", t_us)
        elif not self._stop.is_set():
            self._rejoin_given_up = True
            self.event(Severity.WARNING, f"t={t_s:.2f}s: no camera member joined within "
                                         f"{timeout_s:.0f} s (clock.rejoin_timeout_s); going on "
                                         f"without", t_us)

    def _expected_members(self) -> dict[LockstepRole, int]:
        expected = {LockstepRole.TICK: self.cfg.expected_tick_members,
                    LockstepRole.CAMERA: self.cfg.expected_camera_members}
        return {role: n for role, n in expected.items() if n > 0}

    def run(self, before_clock: Callable[[], object] | None = None) -> SimStats:
        """Fly the run: wait for the lockstep members and the renderer, call ``before_clock`` (the
        launcher's last check before simulated time starts), then tick until the end."""
        clock = self.cfg.clock
        core = self.core
        lockstep = clock.mode == ClockMode.LOCKSTEP
        self.bus.publish(self.keys.node_info(NODE_ID), NodeInfo(0, NODE_ID, "sim", clock.mode.value))
        expected = self._expected_members()
        if expected and not self.barrier.wait_members(expected, clock.startup_timeout_s,
                                                       cancelled=self._stop.is_set) \
                and not self._stop.is_set():
            self.event(Severity.WARNING, f"not every expected node joined within "
                                         f"{clock.startup_timeout_s:.0f} s: {self.barrier.members()}")
        # the renderer's start-up (kernels, camera) overlaps the members' joining, not the first frame
        if not self.camera.wait_ready(clock.startup_timeout_s) and not self._stop.is_set():
            self.event(Severity.WARNING, f"the camera renderer was not ready within "
                                         f"{clock.startup_timeout_s:.0f} s; the first frame waits for it")
        if before_clock is not None and not self._stop.is_set():
            before_clock()
        # The control tick's members (the autopilot) are waited for in both modes, as ArduPilot's
        # SITL waits for its servo outputs: physics never runs on a stale motor command, so a busy
        # machine slows simulated time down instead of letting the vehicle fly open loop (a paced
        # takeoff under load flipped the vehicle when the autopilot's answers came ticks late).
        # Camera members (perception) are waited for in lockstep only; paced, a frame answered
        # late is a fix that arrives late, as on a real drone.
        tick_timeout = clock.member_timeout_s
        camera_timeout = clock.member_timeout_s if lockstep else 1.0 / clock.tick_rate_hz
        duration_ticks = round(self.cfg.duration_s * self.tick_rate_hz)
        camera_acked = -1
        # frames published and not yet waited for: (tick at which to wait, seq), oldest first
        camera_due: deque[tuple[int, int]] = deque()
        answer_ticks = clock.camera_answer_ticks
        wall0 = pace0 = time.perf_counter()
        reason = "duration reached"
        tick = 0
        for tick in range(duration_ticks + 1):
            if self._stop.is_set():
                reason = "stopped by signal"
                break
            t_us = core.time_us
            end_us = self._end_status_us     # set before either event below
            if end_us is not None and (self._mission_done.is_set() or self._landed_early.is_set()):
                # The status of tick k went out before the autopilot's answer to tick k + 1 on the
                # same link, so by tick k + 2 it is here in every run: end there, not at whichever
                # tick it happened to arrive (in lockstep two runs ended a tick apart, 2026-12-05).
                if not lockstep or t_us >= end_us + END_AFTER_STATUS_TICKS * self.tick_us:
                    reason = ("mission complete" if self._mission_done.is_set()
                              else "landed before completing the mission")
                    break
            if core.route_complete:
                reason = "scripted route complete"
                break
            t_s = t_us * 1e-6
            tp = time.perf_counter()
            out = core.sense()
            # First what the tick members (the autopilot) step on: the tick's sensors, then the
            # clock. Everything else goes out while they compute (their answer is what the loop
            # waits for next), so it costs the tick no wall time when a core is free.
            self._publish_tick_inputs(out)
            self.barrier.published(LockstepRole.TICK, tick)
            self.bus.publish(self.keys.clock, ClockTick(
                t_us, tick, self.tick_us, camera_acked, clock.mode.value, RunState.RUNNING.value))
            self.bus.publish(self.keys.truth_pose, out.truth)
            if out.camera_request is not None:
                req = out.camera_request
                self.camera.request(req.seq, req.position_enu_m, req.q_wxyz, capture_s=req.capture_us * 1e-6,
                                    velocity_enu_m_s=req.velocity_enu_m_s,
                                    body_rates_flu_rad_s=req.body_rates_flu_rad_s)
            render_s = 0.0
            if out.camera_release is not None:
                camera_seq = out.camera_release.seq
                if lockstep:
                    self._await_camera_rejoin(t_s, t_us)
                tr = time.perf_counter()
                frame = core.camera_frame(out.camera_release, self.camera.result(camera_seq))
                render_s = time.perf_counter() - tr
                self.stats.time_render_s += render_s
                if lockstep and self.barrier.all_suspended_and_behind(LockstepRole.CAMERA,
                                                                       SUSPENDED_BACKLOG_FRAMES):
                    # Every camera member is suspended and has not answered the last frames either
                    # (frozen: SIGSTOP, a debugger): more frames would only fill its link's queue,
                    # and once that is full the simulator's next put blocks until Zenoh closes the
                    # link (seconds: the clock would stand still). The frames it holds are later
                    # than the one it timed out on: answering them when it wakes brings it back.
                    self.stats.camera_frames_withheld += 1
                else:
                    self.barrier.published(LockstepRole.CAMERA, camera_seq)
                    self.bus.publish(self.keys.camera, frame)
                    self.stats.camera_frames += 1
                    camera_due.append((tick + answer_ticks, camera_seq))
            self.stats.time_publish_s += time.perf_counter() - tp - render_s

            tw = time.perf_counter()
            late = self.barrier.wait(LockstepRole.TICK, tick, tick_timeout)
            if late:
                self._report_late(late, tick_timeout, t_s, t_us)
            while camera_due and camera_due[0][0] <= tick:
                camera_seq = camera_due.popleft()[1]
                late = self.barrier.wait(LockstepRole.CAMERA, camera_seq, camera_timeout)
                camera_acked = camera_seq
                if late and lockstep:
                    self._report_late(late, camera_timeout, t_s, t_us)
            rejoined = self.barrier.take_rejoined()
            if rejoined and not lockstep:     # paced, a camera member answering late is no news
                ticking = self.barrier.members(LockstepRole.TICK)
                rejoined = [n for n in rejoined if n in ticking]
            for node_id in rejoined:
                self.event(Severity.INFO, f"t={t_s:.2f}s: {node_id} answers again; waiting for it "
                                          f"again", t_us)
            self.stats.time_bus_wait_s += time.perf_counter() - tw

            tphys = time.perf_counter()
            with self._motor_lock:
                motor = self._motor
            core.advance(motor)
            self.stats.time_physics_s += time.perf_counter() - tphys
            self.stats.ticks = tick + 1
            if not lockstep:
                ahead = (t_s + 1.0 / self.tick_rate_hz) / clock.speed_factor - (time.perf_counter() - pace0)
                if ahead > 0:
                    time.sleep(ahead)
                elif ahead < -MAX_PACE_LAG_S:     # behind: pace on from here, no catch-up burst
                    if self.stats.realtime_lag_s == 0.0:
                        self.event(Severity.WARNING, f"t={t_s:.2f}s: the simulation fell behind "
                                   f"{clock.speed_factor:g}x real time (the machine is busy); it "
                                   f"runs slower rather than on stale motor commands", t_us)
                    self.stats.realtime_lag_s += -ahead
                    pace0 -= ahead
        t_end_us = self.stats.ticks * self.tick_us
        self.bus.publish(self.keys.clock, ClockTick(
            t_end_us, tick, self.tick_us, camera_acked, clock.mode.value, RunState.FINISHED.value))
        wall = time.perf_counter() - wall0
        stats = self.stats
        stats.sim_time_s = t_end_us * 1e-6
        stats.wall_time_s = wall
        stats.real_time_factor = (t_end_us * 1e-6) / wall if wall > 0 else math.inf
        stats.end_reason = reason
        stats.dropped = dict(self.bus.dropped)
        answers = self.barrier.answer_times()
        stats.member_answers = {n: count for n, (count, _) in answers.items()}
        stats.member_answer_ms_mean = {n: 1e3 * total / count for n, (count, total) in answers.items()}
        self.event(Severity.INFO, f"simulation finished: {reason} at t={t_end_us * 1e-6:.1f}s "
                                  f"({stats.real_time_factor:.1f}x real time)", t_end_us)
        return self.stats

    def _report_late(self, late: list[str], timeout_s: float, t_s: float, t_us: int) -> None:
        self.stats.ack_timeouts += 1
        self.event(Severity.WARNING, f"t={t_s:.2f}s: no lockstep answer from {', '.join(late)} "
                                     f"within {timeout_s:.1f} s; going on without it until it "
                                     f"answers again", t_us)

    def _publish_tick_inputs(self, out: TickOutput) -> None:
        """The sensor samples of the tick (not the truth, not the camera), in their documented order."""
        keys = self.keys
        publish = self.bus.publish
        publish(keys.imu, out.imu)
        if out.baro is not None:
            publish(keys.baro, out.baro)
        if out.compass is not None:
            publish(keys.compass, out.compass)
        if out.gps is not None:
            publish(keys.gps, out.gps)
        if out.power is not None:
            publish(keys.power, out.power)
        if out.flow is not None:
            publish(keys.flow, out.flow)

    def close(self) -> None:
        self.presence.close()
        self.bus.close()
        self.camera.close()
        self.core.close()
