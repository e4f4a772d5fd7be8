"""A test-only 6-DOF quadrotor model (independent of sitl/dynamics.py) for closed-loop autopilot tests."""

from __future__ import annotations

import numpy as np

from scenenav.core.rotations import quat_from_rotation_vector, quat_multiply, quat_normalise, quat_to_rotation_matrix
from sitl.vehicle import VehicleParams

PHYSICS_HZ = 400
CONTROL_HZ = 100
SUBSTEPS = PHYSICS_HZ // CONTROL_HZ
DT_PHYS = 1.0 / PHYSICS_HZ
DT = 1.0 / CONTROL_HZ

ACCEL_NOISE = 0.1       # m/s^2 per 100 Hz sample
GYRO_NOISE = 0.003      # rad/s per sample
ACCEL_BIAS = np.array([0.04, -0.03, 0.10])
GYRO_BIAS = np.array([0.003, -0.004, 0.002])


class QuadModel:
    """Minimal 6-DOF quadrotor for tests (see the module docstring)."""

    def __init__(self, params: VehicleParams) -> None:
        self.par = params
        self.p = np.zeros(3)
        self.v = np.zeros(3)
        self.q = (1.0, 0.0, 0.0, 0.0)
        self.w = np.zeros(3)
        self.rotor = np.zeros(4)
        self.on_ground = True
        self.touchdown_speed_m_s: float | None = None
        self._xy = np.array(params.rotor_positions_flu_m)
        self._dir = np.array([int(d) for d in params.rotor_directions], dtype=float)
        self._inertia = np.array(params.inertia_kg_m2)
        self._drag = 0.5 * params.air_density_kg_m3 * np.array(params.body_drag_cd_area_m2)
        self._gravity = np.array([0.0, 0.0, -params.gravity_m_s2])

    def step(self, commands: np.ndarray, wind_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance DT_PHYS; return the true specific force (body) and body rate."""
        par = self.par
        target = np.clip(commands, 0.0, 1.0) * par.max_rotor_speed_rad_s
        tau = np.where(target > self.rotor, par.motor_time_constant_up_s, par.motor_time_constant_down_s)
        self.rotor += (target - self.rotor) * (1.0 - np.exp(-DT_PHYS / tau))
        thrusts = par.motor_constant_n_per_rad2_s2 * self.rotor ** 2
        rot = quat_to_rotation_matrix(self.q)
        air_b = rot.T @ (self.v - wind_enu)
        force_b = -self._drag * np.abs(air_b) * air_b
        force_b[2] += thrusts.sum()
        accel = rot @ force_b / par.mass_kg + self._gravity
        if self.on_ground:
            if accel[2] <= 0.0:
                # Resting on the ground: the ground reaction cancels everything.
                return rot.T @ -self._gravity, np.zeros(3)
            self.on_ground = False
        torque = np.array([self._xy[:, 1] @ thrusts, -(self._xy[:, 0] @ thrusts),
                           -par.moment_constant_m * (self._dir @ thrusts)])
        torque -= np.cross(self.w, self._inertia * self.w)
        self.v = self.v + accel * DT_PHYS
        self.p = self.p + self.v * DT_PHYS
        self.w = self.w + torque / self._inertia * DT_PHYS
        self.q = quat_normalise(quat_multiply(self.q, quat_from_rotation_vector(*(self.w * DT_PHYS))))
        if self.p[2] <= 0.0:
            # Touchdown: stop dead, keeping the attitude (the gyro must see every rotation).
            self.touchdown_speed_m_s = float(np.linalg.norm(self.v))
            self.p[2] = 0.0
            self.v = np.zeros(3)
            self.w = np.zeros(3)
            self.on_ground = True
        return rot.T @ (accel - self._gravity), self.w.copy()
