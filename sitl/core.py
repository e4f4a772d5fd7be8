"""The simulator's core: one control tick of physics, wind, sensors, battery and camera requests.

``SimulatorCore`` is what the simulator node (``sitl.node``), the benchmarks (``scenenav bench sim``,
``scenenav bench autopilot``) and the tests drive; it knows nothing of the bus or the clock. One tick
is two calls, in this order:

* ``sense()``: the outputs due at the current tick, as the bus messages the node publishes
  (``TickOutput``: truth pose, the IMU sample averaged over the last tick's physics steps, the baro,
  compass, GPS and power samples when due at their rates, a camera capture request when due and the
  frame whose capture latency has elapsed);
* ``advance(motor_command)``: apply a (4,) normalised motor command for the tick's physics
  sub-steps and move to the next tick (scripted flights ignore it: the pose follows the route).

Physics shell: the rigid body lives in ``sitl.physics.PhysicsWorld`` (pybullet, DIRECT client, one
per core). The core calls ``PhysicsWorld.step_many`` once per tick for its physics sub-steps, ``reset`` to start a flight
and ``set_pose`` for scripted (kinematic) flights; the motor lag, rotor wrench and wind inside a step
are the pure models of ``sitl.dynamics`` and ``sitl.wind``. The core renders nothing: the node hands
each ``CameraRequest`` to the render pipeline (``sitl.render_worker``/``sitl.camera``, the other
pybullet shell) and gives the rendered image back to ``camera_frame`` for the camera effects.

Randomness: ``seed`` is split (``numpy.random.SeedSequence.spawn``) into one stream per model, in
this fixed order: wind, IMU, baro, compass, GPS, camera effects, power module, camera optics (drawn
in the render worker, ``sitl.camera_model``); a model draws only
from its own stream, so two cores with the same configuration and seed give identical outputs, and
adding a draw to one model never changes another's.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from scenenav.core.camera_geometry import intrinsics_px
from scenenav.core.contracts import (
    BaroSample,
    CameraFrame,
    CompassSample,
    FlowSample,
    GpsSample,
    ImageEncoding,
    ImuSample,
    PowerSample,
    TruthPose,
)
from scenenav.core.frames import heading_to_enu_yaw
from scenenav.core.rotations import (
    heading_from_quat,
    quat_from_yaw,
    quat_to_rotation_matrix,
)
from sitl.battery import BatteryModel, PowerModuleModel, PowerReading
from sitl.camera_model import jpeg_roundtrip
from sitl.config import ScriptedFlight, SimConfig
from sitl.physics import PhysicsWorld, VehicleState
from sitl.scripted import ScriptedTrajectory
from sitl.sensors import BaroModel, CameraEffects, CompassModel, FlowModel, GpsModel, ImuModel
from sitl.surroundings import MagneticAnomalyField, Surface
from sitl.vehicle import VehicleParams

logger = logging.getLogger(__name__)

RNG_STREAMS = ("wind", "imu", "baro", "compass", "gps", "camera_effects", "power", "camera_optics",
               "magnetic_anomaly", "flow")   # append only: earlier streams keep their seeds


@dataclass(frozen=True)
class SensorRate:
    """Sub-sampling of the tick stream to a sensor rate (deterministic, whole tick periods)."""

    every_ticks: int

    @classmethod
    def of(cls, rate_hz: float, tick_rate_hz: float) -> SensorRate:
        return cls(max(1, round(tick_rate_hz / rate_hz)))

    def due(self, tick: int) -> bool:
        return tick % self.every_ticks == 0


@dataclass(frozen=True, eq=False)   # numpy fields
class CameraRequest:
    """Render the camera at this pose (the vehicle's truth at the capture tick, with its velocity and
    body rates for the capture jitter and motion blur of ``sitl.camera_model``)."""

    seq: int
    capture_us: int
    position_enu_m: np.ndarray
    q_wxyz: np.ndarray
    velocity_enu_m_s: np.ndarray
    body_rates_flu_rad_s: np.ndarray


@dataclass(frozen=True)
class CameraRelease:
    """Frame ``seq``, captured at ``capture_us``, is due for publication at this tick."""

    seq: int
    capture_us: int


@dataclass(frozen=True, eq=False)
class TickOutput:
    """What the simulator publishes at one tick (``None``: not due at this tick)."""

    tick: int
    timestamp_us: int
    truth: TruthPose
    imu: ImuSample
    baro: BaroSample | None
    compass: CompassSample | None
    gps: GpsSample | None
    power: PowerSample | None
    flow: FlowSample | None
    camera_request: CameraRequest | None
    camera_release: CameraRelease | None
    state: VehicleState                 # the full truth (benchmarks and tests; not published)


class SimulatorCore:
    """Physics + sensors + battery + camera scheduling, one control tick at a time (see the module
    docstring). ``origin_*`` is the world's geodetic origin (map centre) for the GPS fixes."""

    def __init__(self, sim: SimConfig, tick_rate_hz: float, seed: int, origin_lat_deg: float,
                 origin_lon_deg: float, params: VehicleParams | None = None,
                 surface: Surface | None = None) -> None:
        self.sim = sim
        self.params = params if params is not None else VehicleParams()
        self.origin_lat_deg = float(origin_lat_deg)
        self.origin_lon_deg = float(origin_lon_deg)
        seeds = np.random.SeedSequence(seed).spawn(len(RNG_STREAMS))
        #: seed of the camera and mount realism (``sitl.camera_model``), drawn where the image is
        #: rendered (``sitl.render_worker.CameraPipeline(optics_seed=...)``)
        self.optics_seed = seeds[RNG_STREAMS.index("camera_optics")]
        streams = {name: np.random.default_rng(s) for name, s in zip(RNG_STREAMS, seeds, strict=True)}
        self.physics = PhysicsWorld(self.params, sim, streams["wind"])
        self.imu = ImuModel(sim.imu, streams["imu"])
        self.surface = surface   # the world's buildings (None: flat), for the sensors' surroundings
        anomalies = None
        if surface is not None and sim.compass.anomaly_mgauss > 0.0:
            anomalies = MagneticAnomalyField(surface, sim.compass.anomaly_mgauss, sim.compass.anomaly_height_m,
                                             sim.compass.anomaly_cell_m, streams["magnetic_anomaly"])
        self.baro = BaroModel(sim.baro, streams["baro"])
        self.compass = CompassModel(sim.compass, streams["compass"], anomalies)
        self.gps = GpsModel(sim.gps, streams["gps"], surface)
        self.flow = FlowModel(sim.flow, streams["flow"], surface)
        self.effects = CameraEffects(sim.camera, streams["camera_effects"])
        self.battery = BatteryModel(sim.battery, self.params.max_rotor_speed_rad_s)
        self.power_module = PowerModuleModel(sim.battery, streams["power"])

        self.tick_rate_hz = float(tick_rate_hz)
        self.tick_us = round(1e6 / tick_rate_hz)
        self.substeps = max(1, round(sim.physics_rate_hz / tick_rate_hz))
        self.camera_latency_ticks = round(sim.camera.latency_s * tick_rate_hz)
        self.camera_clock_offset_us = round(sim.camera.clock_offset_s * 1e6)
        self.rate_baro = SensorRate.of(sim.baro.rate_hz, tick_rate_hz)
        self.rate_compass = SensorRate.of(sim.compass.rate_hz, tick_rate_hz)
        self.rate_gps = SensorRate.of(sim.gps.rate_hz, tick_rate_hz)
        self.rate_camera = SensorRate.of(sim.camera.rate_hz, tick_rate_hz)
        self.rate_power = SensorRate.of(sim.battery.rate_hz, tick_rate_hz)
        self.rate_flow = SensorRate.of(sim.flow.rate_hz, tick_rate_hz)

        self.trajectory: ScriptedTrajectory | None = None
        self.tick = 0
        self._gravity = np.array([0.0, 0.0, -self.params.gravity_m_s2])
        self._accel_sum = np.zeros(3)
        self._gyro_sum = np.zeros(3)
        self._n_sum = 1
        self._capture_seq = -1
        self._pending: deque[tuple[int, CameraRelease]] = deque()   # (publication tick, frame)
        self._state = self.physics.state()
        self._power = PowerReading(math.nan, math.nan)
        self._restart()

    # ------------------------------------------------------------------ starting a flight
    def start_at(self, position_enu_m, yaw_enu_rad: float, rotor_speeds_rad_s=None) -> None:
        """Place the vehicle level at rest (z = 0: on the ground); rotors stopped unless given."""
        self.trajectory = None
        self.physics.reset(np.asarray(position_enu_m, dtype=float), yaw_enu_rad, rotor_speeds_rad_s)
        self._restart()

    def start_scripted(self, flight: ScriptedFlight) -> None:
        """Fly ``flight`` kinematically from its first waypoint; motor commands are ignored."""
        self.trajectory = ScriptedTrajectory(flight.route_enu_m, flight.altitude_m, flight.speed_m_s,
                                             flight.turn_radius_m)
        st = self.trajectory.state(0.0)
        self.physics.reset(st.position_enu_m, heading_to_enu_yaw(st.heading_rad))
        self._restart()

    def _restart(self) -> None:
        state = self.physics.state()
        self._state = state
        self._accel_sum[:] = state.specific_force_flu_m_s2
        self._gyro_sum[:] = state.angular_velocity_flu_rad_s
        self._n_sum = 1
        self._power = self.battery.step(state.rotor_speeds_rad_s, 0.0)

    # ------------------------------------------------------------------ one tick
    @property
    def time_us(self) -> int:
        """Simulated time of the current tick, microseconds."""
        return self.tick * self.tick_us

    @property
    def route_complete(self) -> bool:
        """Scripted flights: the current tick lies beyond the end of the route."""
        return self.trajectory is not None and self.time_us * 1e-6 > self.trajectory.duration_s

    def sense(self) -> TickOutput:
        """The outputs due at the current tick (call once per tick, before ``advance``)."""
        tick = self.tick
        t_us = self.time_us
        if self.trajectory is not None:
            self._scripted_pose(t_us * 1e-6)
        state = self._state
        dt_tick_s = 1.0 / self.tick_rate_hz
        pos = np.asarray(state.position_enu_m, dtype=float)
        vel = np.asarray(state.velocity_enu_m_s, dtype=float)
        heading = heading_from_quat(state.q_wxyz)
        truth = TruthPose(t_us, tuple(pos), tuple(vel), tuple(np.asarray(state.q_wxyz, dtype=float)),
                          tuple(np.asarray(state.angular_velocity_flu_rad_s, dtype=float)), heading)
        throttle = self._throttle(state)
        acc, gyr = self.imu.sample(self._accel_sum / self._n_sum, self._gyro_sum / self._n_sum, dt_tick_s,
                                   throttle)
        imu = ImuSample(t_us, tick, dt_tick_s, (float(acc[0]), float(acc[1]), float(acc[2])),
                        (float(gyr[0]), float(gyr[1]), float(gyr[2])))
        baro = compass = gps = power = flow = None
        if self.rate_baro.due(tick):
            surface_m = self.surface.height_at(float(pos[0]), float(pos[1])) if self.surface else 0.0
            alt, pa = self.baro.sample(float(pos[2]), float(pos[2]) - surface_m, throttle > 0.0)
            baro = BaroSample(t_us, float(alt), float(pa))
        if self.rate_compass.due(tick):
            compass = CompassSample(t_us, float(self.compass.sample(heading, state.q_wxyz,
                                                                    self._power.current_a, pos)))
        if self.sim.gps.enabled and self.rate_gps.due(tick):
            g = self.gps.sample(pos, vel, self.origin_lat_deg, self.origin_lon_deg)
            v = g.velocity_enu_m_s
            gps = GpsSample(t_us, g.lat_deg, g.lon_deg, g.alt_m, (float(v[0]), float(v[1]), float(v[2])),
                            g.eph_m, g.epv_m, int(g.fix_type), int(g.satellites))
        if self.rate_power.due(tick):
            reading = self.power_module.sample(self._power)
            power = PowerSample(t_us, float(reading.voltage_v), float(reading.current_a))
        if self.sim.flow.enabled and self.rate_flow.due(tick):
            f = self.flow.sample(pos, vel, state.q_wxyz, state.angular_velocity_flu_rad_s)
            flow = FlowSample(t_us, self.rate_flow.every_ticks * self.tick_us, f.flow_flu_rad_s,
                              f.body_rate_flu_rad_s, f.distance_m, f.quality)
        request = None
        if self.rate_camera.due(tick):
            self._capture_seq += 1
            request = CameraRequest(self._capture_seq, t_us, state.position_enu_m, state.q_wxyz,
                                    state.velocity_enu_m_s, state.angular_velocity_flu_rad_s)
            self._pending.append((tick + self.camera_latency_ticks,
                                  CameraRelease(self._capture_seq, t_us)))
        release = None
        if self._pending and self._pending[0][0] == tick:
            release = self._pending.popleft()[1]
        return TickOutput(tick, t_us, truth, imu, baro, compass, gps, power, flow, request, release, state)

    def advance(self, motor_command) -> VehicleState:
        """Run the tick's physics sub-steps with ``motor_command`` and move to the next tick."""
        if self.trajectory is None:
            state, accel_sum, gyro_sum = self.physics.step_many(motor_command, self.substeps)
            self._accel_sum[:] = accel_sum
            self._gyro_sum[:] = gyro_sum
            self._n_sum = self.substeps
            self._state = state
        self._power = self.battery.step(self._state.rotor_speeds_rad_s, 1.0 / self.tick_rate_hz)
        self.tick += 1
        return self._state

    def camera_frame(self, release: CameraRelease, image_rgb: np.ndarray) -> CameraFrame:
        """The published frame: the camera effects applied to the rendered image of ``release``, then
        the JPEG compression (``jpeg_quality``); stamped with the camera's clock (the capture tick plus
        ``clock_offset_s``); its header carries the calibration (intrinsics, distortion)."""
        image = self.effects.apply(image_rgb)
        cam = self.sim.camera
        if cam.jpeg_quality > 0:
            image = jpeg_roundtrip(image, cam.jpeg_quality)
        w, h = image.shape[1], image.shape[0]
        return CameraFrame(release.capture_us + self.camera_clock_offset_us, release.seq, w, h,
                           ImageEncoding.RGB8.value, cam.fov_deg, cam.mount.value,
                           intrinsics_px(w, h, cam.fov_deg),
                           tuple(float(c) for c in cam.distortion_k1_k2_p1_p2),  # type: ignore[arg-type]
                           image)

    def state(self) -> VehicleState:
        """The truth of the current tick (after ``sense`` for scripted flights)."""
        return self._state

    def close(self) -> None:
        self.physics.close()

    # ------------------------------------------------------------------ internals
    def _throttle(self, state: VehicleState) -> float:
        """Mean rotor speed over its maximum (0..1): what scales the motor vibration."""
        speeds = np.asarray(state.rotor_speeds_rad_s, dtype=float).tolist()
        if not speeds:
            return 0.0
        # plain floats, summed in order as numpy's mean of so few values does (same bits): 1.5 us
        # a tick instead of 20 (np.mean) on the simulator's critical path
        total = 0.0
        for w in speeds:
            total += abs(w)
        return min(1.0, max(0.0, total / len(speeds) / self.params.max_rotor_speed_rad_s))

    def _scripted_pose(self, t_s: float) -> None:
        assert self.trajectory is not None
        ks = self.trajectory.state(t_s)
        q = np.array(quat_from_yaw(heading_to_enu_yaw(ks.heading_rad)))
        self._state = self.physics.set_pose(ks.position_enu_m, q, ks.velocity_enu_m_s)
        self._accel_sum[:] = quat_to_rotation_matrix(q).T @ (ks.acceleration_enu_m_s2 - self._gravity)
        self._gyro_sum[:] = np.array([0.0, 0.0, -self.trajectory.state(t_s).yaw_rate_rad_s])
        self._n_sum = 1
