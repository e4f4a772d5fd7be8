"""pybullet shell around the pure vehicle model: rigid-body integration, gravity and ground contact.

One ``PhysicsWorld`` owns one pybullet client in DIRECT mode (never the GUI) holding a ground plane
at z = 0 and the quadrotor as a single box-shaped rigid body (size, mass and inertia from
``VehicleParams``). Every ``step`` advances the motors (``QuadrotorDynamics.step_motors``) and the wind
(``WindModel``), applies the rotor/drag wrench at the centre of mass in the world frame, and lets
pybullet integrate one fixed step of 1/physics_rate_hz with gravity and contacts.

Reported position: ENU metres of the body origin (centre of mass) *minus the resting height* (half the
collision-box height), so z = 0 when the vehicle sits on the ground.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pybullet as p

from scenenav.core.rotations import heading_from_quat, quat_from_yaw
from sitl.config import SimConfig
from sitl.dynamics import QuadrotorDynamics, rotation_rows
from sitl.vehicle import VehicleParams
from sitl.wind import WindModel

logger = logging.getLogger(__name__)

# Ground and airframe contact: a rigid landing (no bounce) with rubber-on-concrete-like friction.
# Values chosen for a stable, non-bouncing touchdown; not from iris.sdf (which uses ODE defaults).
_GROUND_LATERAL_FRICTION = 1.0
_RESTITUTION = 0.0


@dataclass(frozen=True, eq=False)   # numpy fields: compare fields explicitly, not with ==
class VehicleState:
    """Truth state of the vehicle after a physics step.

    ``q_wxyz`` rotates body FLU vectors into ENU. ``specific_force_flu_m_s2`` is what an ideal
    accelerometer reads (total non-gravitational force / mass, body frame): +g on body z when resting
    level on the ground or hovering, 0 in free fall.
    """

    time_s: float
    position_enu_m: np.ndarray            # (3,)
    velocity_enu_m_s: np.ndarray          # (3,)
    q_wxyz: np.ndarray                    # (4,)
    angular_velocity_flu_rad_s: np.ndarray  # (3,)
    specific_force_flu_m_s2: np.ndarray   # (3,)
    rotor_speeds_rad_s: np.ndarray        # (4,)
    wind_enu_m_s: np.ndarray              # (3,) wind at the vehicle during the step

    @property
    def heading_rad(self) -> float:
        """Compass heading of body +x, clockwise from north, [0, 2*pi)."""
        return heading_from_quat(self.q_wxyz)


class PhysicsWorld:
    """The simulated vehicle in its own pybullet DIRECT client."""

    def __init__(self, params: VehicleParams, cfg: SimConfig, rng: np.random.Generator) -> None:
        self.params = params
        self.cfg = cfg
        self.dt_s = 1.0 / cfg.physics_rate_hz
        self.dynamics = QuadrotorDynamics(params)
        self.wind = WindModel(cfg.wind, rng)
        self._gravity_world = np.array([0.0, 0.0, -params.gravity_m_s2])
        self._rest_height_m = 0.5 * params.collision_box_m[2]

        self.client_id = p.connect(p.DIRECT)
        if self.client_id < 0:
            raise RuntimeError("pybullet: cannot open a DIRECT client")
        cid = self.client_id
        p.setGravity(0.0, 0.0, -params.gravity_m_s2, physicsClientId=cid)
        p.setTimeStep(self.dt_s, physicsClientId=cid)
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
        self.ground_id = p.createMultiBody(0.0, plane, -1, [0.0, 0.0, 0.0], physicsClientId=cid)
        p.changeDynamics(self.ground_id, -1, lateralFriction=_GROUND_LATERAL_FRICTION,
                         restitution=_RESTITUTION, physicsClientId=cid)
        half = [0.5 * s for s in params.collision_box_m]
        box = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid)
        self.body_id = p.createMultiBody(params.mass_kg, box, -1, [0.0, 0.0, self._rest_height_m],
                                         physicsClientId=cid)
        # pybullet's default damping would add drag the model already has; sleeping would freeze a
        # vehicle resting on the ground and ignore its thrust.
        p.changeDynamics(self.body_id, -1, mass=params.mass_kg,
                         localInertiaDiagonal=list(params.inertia_kg_m2),
                         linearDamping=0.0, angularDamping=0.0,
                         lateralFriction=_GROUND_LATERAL_FRICTION, restitution=_RESTITUTION,
                         activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)
        self._steps = 0
        self._pos_com = (0.0, 0.0, self._rest_height_m)
        self._q = np.array([1.0, 0.0, 0.0, 0.0])
        self._vel = np.zeros(3)
        self._state: VehicleState | None = None
        self._wind = self.wind.velocity_enu_m_s(0.0)
        self.reset(np.zeros(3), 0.0)

    # ------------------------------------------------------------------ control
    def reset(self, position_enu_m: np.ndarray, yaw_enu_rad: float,
              rotor_speeds_rad_s: np.ndarray | None = None) -> None:
        """Place the vehicle level at ``position_enu_m`` with ENU yaw ``yaw_enu_rad``, at rest.

        ``position_enu_m[2]`` is the height above the resting height: 0 puts the vehicle on the
        ground. Rotors stop unless ``rotor_speeds_rad_s`` is given (e.g. hover speed for an air start).
        Time restarts at 0.
        """
        pos = np.asarray(position_enu_m, dtype=float).reshape(3)
        if pos[2] < 0.0:
            raise ValueError(f"position_enu_m z = {pos[2]}: expected >= 0 (0 = on the ground)")
        self.dynamics.reset()
        if rotor_speeds_rad_s is not None:
            self.dynamics.set_rotor_speeds(rotor_speeds_rad_s)
        q = np.array(quat_from_yaw(yaw_enu_rad))
        self._steps = 0
        self._place(pos, q, np.zeros(3), np.zeros(3))
        # At rest on the ground the accelerometer reads the ground reaction; in the air, the thrust.
        if pos[2] == 0.0:
            f_body = np.array(rotation_rows(q)).T @ -self._gravity_world
        else:
            f_body = self.dynamics.wrench_body(np.zeros(3))[0] / self.params.mass_kg
        self._state = self._make_state(f_body, np.zeros(3))

    def set_pose(self, position_enu_m: np.ndarray, q_wxyz: np.ndarray, velocity_enu_m_s: np.ndarray,
                 angular_velocity_flu_rad_s: np.ndarray | None = None,
                 acceleration_enu_m_s2: np.ndarray | None = None) -> VehicleState:
        """Kinematic override (scripted trajectories): teleport the body, set its velocities.

        Does not advance time or the physics. The returned state's specific force is
        R^T (acceleration - gravity), with the acceleration defaulting to zero (steady flight).
        """
        pos = np.asarray(position_enu_m, dtype=float).reshape(3)
        q = np.asarray(q_wxyz, dtype=float).reshape(4)
        q = q / np.linalg.norm(q)
        vel = np.asarray(velocity_enu_m_s, dtype=float).reshape(3)
        rot = np.array(rotation_rows(q))
        omega_b = (np.zeros(3) if angular_velocity_flu_rad_s is None
                   else np.asarray(angular_velocity_flu_rad_s, dtype=float).reshape(3))
        accel = (np.zeros(3) if acceleration_enu_m_s2 is None
                 else np.asarray(acceleration_enu_m_s2, dtype=float).reshape(3))
        self._place(pos, q, vel, rot @ omega_b)
        self._state = self._make_state(rot.T @ (accel - self._gravity_world), omega_b)
        return self._state

    def step(self, motor_command: np.ndarray) -> VehicleState:
        """One physics step of 1/physics_rate_hz with ``motor_command`` ((4,) normalised, [0, 1])."""
        return self.step_many(motor_command, 1)[0]

    def step_many(self, motor_command, steps: int) -> tuple[VehicleState, tuple[float, float, float],
                                                             tuple[float, float, float]]:
        """``steps`` physics steps with one ``motor_command``: the state after the last, and the sums
        over the steps of the specific force and of the body rates (FLU), for the IMU's average.

        The simulator's hot path (a control tick's sub-steps): plain floats between the pybullet
        calls, arrays only for the returned state; the same arithmetic, in the same order, as
        ``steps`` calls of ``step``.
        """
        cid = self.client_id
        body = self.body_id
        dt = self.dt_s
        dynamics = self.dynamics
        wind_model = self.wind
        inv_dt = self.cfg.physics_rate_hz
        gravity = self.params.gravity_m_s2
        world = p.WORLD_FRAME
        command = np.asarray(motor_command, dtype=float).tolist()
        q = self._q.tolist()
        rows = rotation_rows(q)
        v_old = self._vel.tolist()
        pos = self._pos_com
        wind = self._wind
        fx = fy = fz = wx = wy = wz = 0.0
        sum_f = [0.0, 0.0, 0.0]
        sum_w = [0.0, 0.0, 0.0]
        for _ in range(steps):
            dynamics.advance_motors(command, dt)
            wind = wind_model.velocity_enu_m_s(dt)
            f0, f1, f2, t0, t1, t2 = dynamics.wrench_world(rows, v_old, wind.tolist())
            p.applyExternalForce(body, -1, (f0, f1, f2), pos, world, physicsClientId=cid)
            p.applyExternalTorque(body, -1, (t0, t1, t2), world, physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
            pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
            lin, ang = p.getBaseVelocity(body, physicsClientId=cid)
            # Specific force = R^T (dv/dt - g): exact for pybullet's semi-implicit Euler step, and
            # it includes contact reactions.
            ax = (lin[0] - v_old[0]) * inv_dt
            ay = (lin[1] - v_old[1]) * inv_dt
            az = (lin[2] - v_old[2]) * inv_dt + gravity
            q = (orn[3], orn[0], orn[1], orn[2])
            rows = rotation_rows(q)
            (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
            v_old = lin
            fx = r00 * ax + r10 * ay + r20 * az
            fy = r01 * ax + r11 * ay + r21 * az
            fz = r02 * ax + r12 * ay + r22 * az
            ox, oy, oz = ang
            wx = r00 * ox + r10 * oy + r20 * oz
            wy = r01 * ox + r11 * oy + r21 * oz
            wz = r02 * ox + r12 * oy + r22 * oz
            sum_f[0] += fx
            sum_f[1] += fy
            sum_f[2] += fz
            sum_w[0] += wx
            sum_w[1] += wy
            sum_w[2] += wz
        self._steps += steps
        self._pos_com = pos
        self._q = np.array(q)
        self._vel = np.array(v_old)
        self._wind = wind
        self._state = self._make_state(np.array([fx, fy, fz]), np.array([wx, wy, wz]))
        return self._state, (sum_f[0], sum_f[1], sum_f[2]), (sum_w[0], sum_w[1], sum_w[2])

    def state(self) -> VehicleState:
        """The state after the last reset, set_pose or step."""
        assert self._state is not None
        return self._state

    def close(self) -> None:
        """Disconnect the pybullet client (idempotent)."""
        if self.client_id >= 0:
            try:
                p.disconnect(physicsClientId=self.client_id)
            except p.error as exc:   # already disconnected
                logger.debug("pybullet disconnect: %s", exc)
            self.client_id = -1

    def __enter__(self) -> "PhysicsWorld":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _place(self, pos: np.ndarray, q: np.ndarray, vel: np.ndarray, omega_world: np.ndarray) -> None:
        cid = self.client_id
        com = (float(pos[0]), float(pos[1]), float(pos[2]) + self._rest_height_m)
        p.resetBasePositionAndOrientation(self.body_id, com, (q[1], q[2], q[3], q[0]), physicsClientId=cid)
        p.resetBaseVelocity(self.body_id, vel.tolist(), omega_world.tolist(), physicsClientId=cid)
        self._pos_com = com
        self._q = q.copy()
        self._vel = vel.copy()

    def _make_state(self, specific_force_flu: np.ndarray, omega_flu: np.ndarray) -> VehicleState:
        x, y, z = self._pos_com
        return VehicleState(
            time_s=self._steps * self.dt_s,
            position_enu_m=np.array([x, y, z - self._rest_height_m]),
            velocity_enu_m_s=self._vel,      # fresh arrays every step/placement, never mutated
            q_wxyz=self._q,
            angular_velocity_flu_rad_s=omega_flu,
            specific_force_flu_m_s2=specific_force_flu,
            rotor_speeds_rad_s=self.dynamics.rotor_speeds_rad_s.copy(),
            wind_enu_m_s=self._wind,
        )


def hover_motor_command(params: VehicleParams) -> np.ndarray:
    """(4,) normalised command that holds the rotors at hover speed."""
    return np.full(len(params.rotor_positions_flu_m), params.hover_rotor_speed_rad_s / params.max_rotor_speed_rad_s)


