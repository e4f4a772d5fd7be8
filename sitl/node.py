"""Simulator node: pybullet physics, sensors and the lockstep clock.

Inputs
  ``actuators/motors``            MotorCommand   (autopilot flights; zero thrust until one arrives)
  ``lockstep/ack/*``              LockstepAck    (answers of lockstep members)
  ``lockstep/member/**``          liveliness     (who must answer)
  ``autopilot/status``            AutopilotStatus (ends the run when the mission is done and landed)
Outputs
  ``clock``                       ClockTick      (every control tick, after that tick's sensors)
  ``sensors/imu``                 ImuSample      (every tick)
  ``sensors/baro``, ``sensors/compass``, ``sensors/gps``   at their configured rates (GPS only if enabled)
  ``sensors/camera``              CameraFrame    (camera rate)
  ``truth/pose``                  TruthPose      (every tick; evaluation and logs only)
  ``events/<id>``, ``info/<id>``  Event, NodeInfo

Lockstep (default): per tick the simulator publishes sensors and the clock, waits for every live
``tick`` member (the autopilot) and, on camera ticks, every ``camera`` member (perception), then
applies the newest motor command for the tick's physics sub-steps. Realtime: the same, paced so that
simulated time runs at ``speed_factor`` times the wall clock, waiting at most one tick period for
answers.
"""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
from dataclasses import dataclass

import numpy as np

from scenenav.core.bus import Bus, BusConfig
from scenenav.core.contracts import (AutopilotStatus, BaroSample, CameraFrame, ClockMode, ClockTick,
                                CompassSample, Event, GpsSample, ImageEncoding, ImuSample,
                                LockstepAck, LockstepRole, MotorCommand, NodeInfo, RunState,
                                Severity, TruthPose)
from scenenav.core.keys import Keys
from scenenav.core.lockstep import LockstepBarrier
from scenenav.app.scenario import FlightMode, ScenarioConfig, route_for
from sitl.scripted import ScriptedTrajectory
from scenenav.core.frames import enu_yaw_to_heading, heading_to_enu_yaw

log = logging.getLogger(__name__)

NODE_ID = "sim"


def yaw_quaternion(yaw_enu_rad: float) -> np.ndarray:
    return np.array([math.cos(yaw_enu_rad / 2), 0.0, 0.0, math.sin(yaw_enu_rad / 2)])


def quaternion_heading(q_wxyz) -> float:
    """Compass heading of the body x axis projected on the ground."""
    w, x, y, z = q_wxyz
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return enu_yaw_to_heading(yaw)


def _rot_t(q_wxyz, v: np.ndarray) -> np.ndarray:
    """World vector -> body frame (inverse rotation of q)."""
    w, x, y, z = q_wxyz
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
    return r.T @ v


@dataclass
class _Rates:
    """Sub-sampling of a tick stream to a sensor rate (deterministic, integer tick periods)."""

    every_ticks: int

    @classmethod
    def of(cls, rate_hz: float, tick_rate_hz: float) -> "_Rates":
        return cls(max(1, int(round(tick_rate_hz / rate_hz))))

    def due(self, tick: int) -> bool:
        return tick % self.every_ticks == 0


class SimulatorNode:
    def __init__(self, scenario: ScenarioConfig, world, bus_cfg: BusConfig):
        from sitl.physics import PhysicsWorld
        from sitl.render_worker import CameraPipeline
        from sitl.sensors import BaroModel, CameraEffects, CompassModel, GpsModel, ImuModel
        from sitl.vehicle import VehicleParams

        self.cfg = scenario
        self.world = world
        self.keys = Keys(bus_cfg.namespace)
        sim = scenario.sim
        root = np.random.SeedSequence(scenario.seed)
        streams = [np.random.default_rng(s) for s in root.spawn(7)]
        self.params = VehicleParams()
        self.physics = PhysicsWorld(self.params, sim, streams[0])
        self.camera = CameraPipeline(world.orthophoto, world.m_per_px, sim.camera)
        self.camera_latency_ticks = int(round(sim.camera.latency_s * clock_rate_hz(scenario)))
        self.imu = ImuModel(sim.imu, streams[1])
        self.baro = BaroModel(sim.baro, streams[2])
        self.compass = CompassModel(sim.compass, streams[3])
        self.gps = GpsModel(sim.gps, streams[4])
        self.effects = CameraEffects(sim.camera, streams[5])

        clock = scenario.clock
        self.tick_rate_hz = clock.tick_rate_hz
        self.tick_us = int(round(1e6 / clock.tick_rate_hz))
        self.substeps = max(1, int(round(sim.physics_rate_hz / clock.tick_rate_hz)))
        self.rate_baro = _Rates.of(sim.baro.rate_hz, clock.tick_rate_hz)
        self.rate_compass = _Rates.of(sim.compass.rate_hz, clock.tick_rate_hz)
        self.rate_gps = _Rates.of(sim.gps.rate_hz, clock.tick_rate_hz)
        self.rate_camera = _Rates.of(sim.camera.rate_hz, clock.tick_rate_hz)

        flight = scenario.flight
        self.trajectory = None
        if flight.mode == FlightMode.SCRIPTED:
            self.trajectory = ScriptedTrajectory(route_for(scenario, world), flight.altitude_m,
                                                 flight.speed_m_s, flight.turn_radius_m)
            st = self.trajectory.state(0.0)
            self.physics.reset(st.position_enu_m, heading_to_enu_yaw(st.heading_rad))
        else:
            sx, sy = flight.start_enu_m
            self.physics.reset(np.array([sx, sy, 0.0]),
                               heading_to_enu_yaw(math.radians(flight.start_heading_deg)))

        self.bus = Bus(bus_cfg)
        self.barrier = LockstepBarrier()
        self._motor_lock = threading.Lock()
        self._motor = np.zeros(4)
        self._stop = threading.Event()
        self._mission_done = threading.Event()
        self._landed_early = threading.Event()
        self._has_flown = False
        self.stats = {"ticks": 0, "camera_frames": 0, "ack_timeouts": 0,
                      "time_physics_s": 0.0, "time_render_s": 0.0, "time_bus_wait_s": 0.0,
                      "time_publish_s": 0.0}

        self.bus.subscribe(self.keys.motors, MotorCommand, self._on_motor)
        self.bus.subscribe(self.keys.lockstep_ack_all, LockstepAck, self._on_ack)
        self.bus.subscribe(self.keys.autopilot_status, AutopilotStatus, self._on_status)
        self.bus.watch_liveliness(self.keys.lockstep_member_all, self._on_member)
        self.bus.declare_token(self.keys.node_alive("sim", NODE_ID))

    # --------------------------------------------------------------------------- callbacks
    def _on_motor(self, msg: MotorCommand, _key: str) -> None:
        cmd = np.asarray(msg.command, dtype=float)
        if not np.all(np.isfinite(cmd)):
            self.bus.dropped["motors: non-finite command"] += 1
            return
        with self._motor_lock:
            self._motor = np.clip(cmd, 0.0, 1.0) if msg.armed else np.zeros(4)

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
        if self.cfg.flight.mode != FlightMode.AUTOPILOT:
            return   # ground-station sessions (idle) end only when the user stops them
        if msg.armed:
            self._has_flown = True
        if msg.landed and not msg.armed:
            if msg.mission_complete:
                self._mission_done.set()
            elif self._has_flown:      # e.g. a failsafe landing: nothing more will happen
                self._landed_early.set()

    def stop(self) -> None:
        self._stop.set()

    def event(self, severity: Severity, text: str, t_us: int | None = None) -> None:
        ts = t_us if t_us is not None else self.stats["ticks"] * self.tick_us
        self.bus.publish(self.keys.events(NODE_ID), Event(ts, NODE_ID, int(severity), text))
        log.info("%s", text)

    # ------------------------------------------------------------------------------- loop
    def run(self, expected: dict[LockstepRole, int] | None = None) -> dict:
        clock = self.cfg.clock
        lockstep = clock.mode == ClockMode.LOCKSTEP
        self.bus.publish(self.keys.node_info(NODE_ID), NodeInfo(0, NODE_ID, "sim", clock.mode.value))
        if expected:
            if not self.barrier.wait_members(expected, clock.startup_timeout_s):
                self.event(Severity.WARNING, f"not every expected node joined within "
                                             f"{clock.startup_timeout_s:.0f} s: {self.barrier.members()}")
        answer_timeout = clock.member_timeout_s if lockstep else 1.0 / clock.tick_rate_hz
        duration_ticks = int(round(self.cfg.duration_s * self.tick_rate_hz))
        dt_phys = 1.0 / self.cfg.sim.physics_rate_hz
        state = self.physics.state()
        accel_sum = np.zeros(3)
        gyro_sum = np.zeros(3)
        accel_sum[:] = state.specific_force_flu_m_s2
        gyro_sum[:] = state.angular_velocity_flu_rad_s
        n_sum = 1
        camera_seq = -1
        capture_seq = -1
        pending: list[tuple[int, int, int]] = []   # (publish tick, frame seq, capture time us)
        camera_acked = -1
        wall0 = time.perf_counter()
        reason = "duration reached"
        tick = 0
        for tick in range(duration_ticks + 1):
            if self._stop.is_set():
                reason = "stopped by signal"
                break
            if self._mission_done.is_set():
                reason = "mission complete"
                break
            if self._landed_early.is_set():
                reason = "landed before completing the mission"
                break
            t_us = tick * self.tick_us
            t_s = t_us * 1e-6
            if self.trajectory is not None:
                if t_s > self.trajectory.duration_s:
                    reason = "scripted route complete"
                    break
                state, sf = self._scripted_state(t_s)
                accel_sum[:] = sf
                gyro_sum[:] = np.array([0.0, 0.0, -self.trajectory.state(t_s).yaw_rate_rad_s])
                n_sum = 1
            tp = time.perf_counter()
            self._publish_sensors(tick, t_us, state, accel_sum / n_sum, gyro_sum / n_sum)
            if self.rate_camera.due(tick):
                capture_seq += 1
                self.camera.request(capture_seq, state.position_enu_m, state.q_wxyz)
                pending.append((tick + self.camera_latency_ticks, capture_seq, t_us))
            frame_out = bool(pending) and pending[0][0] == tick
            render_s = 0.0
            if frame_out:
                _, camera_seq, t_capture_us = pending.pop(0)
                tr = time.perf_counter()
                image = self.effects.apply(self.camera.result(camera_seq))
                render_s = time.perf_counter() - tr
                self.stats["time_render_s"] += render_s
                self.barrier.published(LockstepRole.CAMERA, camera_seq)
                cam = self.cfg.sim.camera
                self.bus.publish(self.keys.camera, CameraFrame(
                    t_capture_us, camera_seq, image.shape[1], image.shape[0],
                    ImageEncoding.RGB8.value, cam.fov_deg, cam.mount.value, image))
                self.stats["camera_frames"] += 1
            self.barrier.published(LockstepRole.TICK, tick)
            self.bus.publish(self.keys.clock, ClockTick(
                t_us, tick, self.tick_us, camera_acked, clock.mode.value, RunState.RUNNING.value))
            self.stats["time_publish_s"] += time.perf_counter() - tp - render_s

            tw = time.perf_counter()
            late = self.barrier.wait(LockstepRole.TICK, tick, answer_timeout)
            if frame_out:
                late += self.barrier.wait(LockstepRole.CAMERA, camera_seq, answer_timeout)
                camera_acked = camera_seq
            if late and lockstep:
                self.stats["ack_timeouts"] += 1
                self.event(Severity.WARNING, f"t={t_s:.2f}s: no lockstep answer from {late} "
                                             f"within {answer_timeout:.1f} s", t_us)
            self.stats["time_bus_wait_s"] += time.perf_counter() - tw

            tphys = time.perf_counter()
            if self.trajectory is None:
                with self._motor_lock:
                    motor = self._motor.copy()
                accel_sum[:] = 0.0
                gyro_sum[:] = 0.0
                for _ in range(self.substeps):
                    state = self.physics.step(motor)
                    accel_sum += state.specific_force_flu_m_s2
                    gyro_sum += state.angular_velocity_flu_rad_s
                n_sum = self.substeps
            self.stats["time_physics_s"] += time.perf_counter() - tphys
            self.stats["ticks"] = tick + 1
            if not lockstep:
                ahead = (t_s + 1.0 / self.tick_rate_hz) / clock.speed_factor - (time.perf_counter() - wall0)
                if ahead > 0:
                    time.sleep(ahead)
        del dt_phys
        t_end_us = self.stats["ticks"] * self.tick_us
        self.bus.publish(self.keys.clock, ClockTick(
            t_end_us, tick, self.tick_us, camera_acked, clock.mode.value, RunState.FINISHED.value))
        wall = time.perf_counter() - wall0
        self.stats.update(sim_time_s=t_end_us * 1e-6, wall_time_s=wall,
                          real_time_factor=(t_end_us * 1e-6) / wall if wall > 0 else math.inf,
                          end_reason=reason, dropped=dict(self.bus.dropped))
        self.event(Severity.INFO, f"simulation finished: {reason} at t={t_end_us * 1e-6:.1f}s "
                                  f"({self.stats['real_time_factor']:.1f}x real time)", t_end_us)
        return self.stats

    def _scripted_state(self, t_s: float):
        ks = self.trajectory.state(t_s)
        q = yaw_quaternion(heading_to_enu_yaw(ks.heading_rad))
        st = self.physics.set_pose(ks.position_enu_m, q, ks.velocity_enu_m_s)
        g = np.array([0.0, 0.0, -self.params.gravity_m_s2])
        sf = _rot_t(q, ks.acceleration_enu_m_s2 - g)
        return st, sf

    def _publish_sensors(self, tick: int, t_us: int, state, accel_mean, gyro_mean) -> None:
        keys = self.keys
        pos = np.asarray(state.position_enu_m, dtype=float)
        heading = quaternion_heading(state.q_wxyz)
        self.bus.publish(keys.truth_pose, TruthPose(
            t_us, tuple(pos), tuple(np.asarray(state.velocity_enu_m_s, dtype=float)),
            tuple(np.asarray(state.q_wxyz, dtype=float)),
            tuple(np.asarray(state.angular_velocity_flu_rad_s, dtype=float)), heading))
        acc, gyr = self.imu.sample(accel_mean, gyro_mean, 1.0 / self.tick_rate_hz)
        self.bus.publish(keys.imu, ImuSample(t_us, tick, 1.0 / self.tick_rate_hz,
                                             tuple(map(float, acc)), tuple(map(float, gyr))))
        if self.rate_baro.due(tick):
            alt, pa = self.baro.sample(float(pos[2]))
            self.bus.publish(keys.baro, BaroSample(t_us, float(alt), float(pa)))
        if self.rate_compass.due(tick):
            self.bus.publish(keys.compass, CompassSample(t_us, float(self.compass.sample(heading))))
        if self.cfg.sim.gps.enabled and self.rate_gps.due(tick):
            m = self.world.manifest
            g = self.gps.sample(pos, np.asarray(state.velocity_enu_m_s, dtype=float),
                                m.origin_lat_deg, m.origin_lon_deg)
            self.bus.publish(keys.gps, GpsSample(
                t_us, g.lat_deg, g.lon_deg, g.alt_m, tuple(map(float, g.velocity_enu_m_s)),
                g.eph_m, g.epv_m, int(g.fix_type), int(g.satellites)))

    def close(self) -> None:
        self.bus.close()
        self.camera.close()
        self.physics.close()


def clock_rate_hz(scenario: ScenarioConfig) -> float:
    return scenario.clock.tick_rate_hz


def install_stop_handlers(stop) -> None:
    """SIGINT/SIGTERM end the loop cleanly (the run folder stays readable)."""
    def handler(signum, _frame):
        log.info("signal %d: stopping", signum)
        stop()
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
