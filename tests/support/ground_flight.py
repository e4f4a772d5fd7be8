"""``GroundFlight``: the flight core flying the simulator's pure models in-process, on flat ground.

Rotor dynamics with motor lag and body drag, the IMU / baro / compass models with ``SimConfig``
defaults (turn-on biases, white noise); the vehicle starts at the origin heading north, on the
ground. The plant is the simulator's truth (``sitl.vehicle.VehicleParams``); the autopilot flies its
own airframe model (``autopilot_bridge.airframe``, from the parameters given).
"""

from __future__ import annotations

import math

import numpy as np

from autopilot_bridge.config import FlightCoreConfig
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.fusion import ImuReading
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from scenenav.core.rotations import heading_from_quat, quat_from_rotation_vector, quat_multiply, quat_normalise
from sitl.config import SimConfig
from sitl.dynamics import QuadrotorDynamics, rotation_rows
from sitl.sensors import BaroModel, CompassModel, ImuModel
from sitl.vehicle import VehicleParams

PHYSICS_HZ = 400
CONTROL_HZ = 100
SUBSTEPS = PHYSICS_HZ // CONTROL_HZ
DT_PHYS = 1.0 / PHYSICS_HZ
DT = 1.0 / CONTROL_HZ


class GroundFlight:
    """FlightCore on sitl's pure models, starting on flat ground at the origin, heading north."""

    def __init__(self, seed: int, **params) -> None:
        sim = SimConfig()
        streams = np.random.default_rng(seed).spawn(4)
        self.veh = VehicleParams()
        self.dyn = QuadrotorDynamics(self.veh)
        self.imu = ImuModel(sim.imu, streams[0])
        self.baro = BaroModel(sim.baro, streams[1])
        self.compass = CompassModel(sim.compass, streams[2])
        self.every_baro = int(round(CONTROL_HZ / sim.baro.rate_hz))
        self.every_compass = int(round(CONTROL_HZ / sim.compass.rate_hz))
        self.p = np.zeros(3)
        self.v = np.zeros(3)
        self.q = quat_from_rotation_vector(0.0, 0.0, 0.5 * math.pi)
        self.w = np.zeros(3)
        self.on_ground = True
        self._inertia = np.array(self.veh.inertia_kg_m2)
        self._gravity = np.array([0.0, 0.0, -self.veh.gravity_m_s2])
        self.params = ParameterStore(PARAM_SPECS, defaults={"EK3_SRC1_POSXY": 6, **params})
        self.core = FlightCore(self.params, FlightCoreConfig(origin_lat_deg=48.1, origin_lon_deg=11.5))
        self.core.set_vision_available(True)      # a perception node is followed (no fix arrives)
        self.cmd = np.zeros(4)
        self.k = 0

    @property
    def t(self) -> float:
        return self.k * DT

    def _physics_step(self) -> tuple[np.ndarray, np.ndarray]:
        self.dyn.step_motors(self.cmd, DT_PHYS)
        rot = np.array(rotation_rows(self.q))
        force_b, torque_b = self.dyn.wrench_body(rot.T @ self.v)
        specific_b = force_b / self.veh.mass_kg
        accel = rot @ specific_b + self._gravity
        if self.on_ground:
            if accel[2] <= 0.0:
                return rot.T @ -self._gravity, np.zeros(3)     # resting: the ground carries it
            self.on_ground = False
        w = self.w
        self.w = w + (torque_b - np.cross(w, self._inertia * w)) / self._inertia * DT_PHYS
        self.v = self.v + accel * DT_PHYS
        self.p = self.p + self.v * DT_PHYS
        self.q = quat_normalise(quat_multiply(self.q, quat_from_rotation_vector(*(self.w * DT_PHYS))))
        if self.p[2] <= 0.0 and self.v[2] < 0.0:
            self.p[2] = 0.0
            self.v[:] = 0.0
            self.w[:] = 0.0
            self.on_ground = True
        return specific_b, self.w

    def tick(self) -> None:
        f_sum, w_sum = np.zeros(3), np.zeros(3)
        for _ in range(SUBSTEPS):
            f, w = self._physics_step()
            f_sum += f
            w_sum += w
        self.k += 1
        c = self.core
        if self.k % self.every_baro == 0:
            c.on_baro(self.t, self.baro.sample(float(self.p[2]))[0])
        if self.k % self.every_compass == 0:
            c.on_compass(self.t, float(self.compass.sample(heading_from_quat(np.array(self.q)))))
        accel, gyro = self.imu.sample(f_sum / SUBSTEPS, w_sum / SUBSTEPS, DT)
        self.cmd = c.step(DT, ImuReading(tuple(accel), tuple(gyro)), self.t)
