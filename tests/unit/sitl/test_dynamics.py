"""Rotor/airframe model, wind, and the pybullet shell, on small hand-checked cases.

Sign conventions (body FLU, right-handed): a positive torque about body +x raises the left side
(+y) and lowers the right side, i.e. rolls RIGHT; a positive torque about +y lowers the nose;
a positive torque about +z yaws the nose to the left (counter-clockwise seen from above).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from scenenav.core.rotations import (
    heading_from_quat,
    quat_from_euler_zyx,
    quat_from_yaw,
    quat_to_rotation_matrix,
)
from sitl.config import SimConfig, WindConfig
from sitl.dynamics import QuadrotorDynamics
from sitl.physics import PhysicsWorld, hover_motor_command
from sitl.vehicle import SpinDirection, VehicleParams
from sitl.wind import WindModel

PARAMS = VehicleParams()
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
ZERO = np.zeros(3)


def _dynamics_at(speeds_rad_s) -> QuadrotorDynamics:
    dyn = QuadrotorDynamics(PARAMS)
    dyn.set_rotor_speeds(np.asarray(speeds_rad_s, dtype=float))
    return dyn


def test_quaternion_helpers():
    q = quat_from_yaw(math.pi / 2.0)             # facing north
    rot = quat_to_rotation_matrix(q)
    assert rot @ np.array([1.0, 0.0, 0.0]) == pytest.approx([0.0, 1.0, 0.0], abs=1e-12)
    assert heading_from_quat(q) == pytest.approx(0.0, abs=1e-12)
    assert heading_from_quat(quat_from_yaw(0.0)) == pytest.approx(math.pi / 2.0)   # facing east
    # Positive roll lowers the right side: body -y (right) points down.
    right = quat_to_rotation_matrix(quat_from_euler_zyx(0.0, 0.0, 0.3)) @ np.array([0.0, -1.0, 0.0])
    assert right[2] < 0.0
    # Positive pitch lowers the nose.
    nose = quat_to_rotation_matrix(quat_from_euler_zyx(0.0, 0.3, 0.0)) @ np.array([1.0, 0.0, 0.0])
    assert nose[2] < 0.0


def test_hover_speed_carries_the_weight():
    hover = PARAMS.hover_rotor_speed_rad_s
    force, torque = _dynamics_at([hover] * 4).wrench(LEVEL, ZERO, ZERO)
    vertical_accel = force[2] / PARAMS.mass_kg - PARAMS.gravity_m_s2
    assert vertical_accel == pytest.approx(0.0, abs=1e-9)
    assert force[:2] == pytest.approx([0.0, 0.0], abs=1e-12)
    # Opposite spin directions cancel the yaw reaction torques.
    assert torque[2] == pytest.approx(0.0, abs=1e-12)


def test_open_loop_hover_holds_altitude_in_pybullet():
    with PhysicsWorld(PARAMS, SimConfig(), np.random.default_rng(0)) as world:
        world.reset(np.array([0.0, 0.0, 50.0]), 0.0,
                    rotor_speeds_rad_s=np.full(4, PARAMS.hover_rotor_speed_rad_s))
        assert world.state().specific_force_flu_m_s2 == pytest.approx([0.0, 0.0, PARAMS.gravity_m_s2])
        command = hover_motor_command(PARAMS)
        for _ in range(200):                      # 0.5 s at 400 Hz
            state = world.step(command)
        assert state.time_s == pytest.approx(0.5)
        assert state.position_enu_m[2] == pytest.approx(50.0, abs=1e-3)
        assert abs(state.velocity_enu_m_s[2]) < 1e-3
        assert state.specific_force_flu_m_s2 == pytest.approx([0.0, 0.0, PARAMS.gravity_m_s2], abs=1e-6)


def test_motor_lag_reaches_63_percent_after_one_time_constant():
    dyn = QuadrotorDynamics(PARAMS)
    tau_up = PARAMS.motor_time_constant_up_s
    for _ in range(10):
        speeds = dyn.step_motors(np.ones(4), tau_up / 10.0)
    assert speeds / PARAMS.max_rotor_speed_rad_s == pytest.approx(np.full(4, 1.0 - math.exp(-1.0)))
    # Slowing down uses the (slower) fall time constant.
    dyn.set_rotor_speeds(np.full(4, PARAMS.max_rotor_speed_rad_s))
    tau_down = PARAMS.motor_time_constant_down_s
    for _ in range(5):
        speeds = dyn.step_motors(np.zeros(4), tau_down / 5.0)
    assert speeds / PARAMS.max_rotor_speed_rad_s == pytest.approx(np.full(4, math.exp(-1.0)))


def test_motor_command_is_clipped_and_nan_stops():
    dyn = QuadrotorDynamics(PARAMS)
    for _ in range(400):
        speeds = dyn.step_motors(np.array([2.0, -1.0, np.nan, 0.5]), 0.0025)
    assert speeds == pytest.approx([PARAMS.max_rotor_speed_rad_s, 0.0, 0.0, 0.5 * PARAMS.max_rotor_speed_rad_s])
    with pytest.raises(ValueError):
        dyn.step_motors(np.ones(3), 0.0025)


def _left_right_rotors() -> tuple[list[int], list[int]]:
    left = [i for i, (_, y) in enumerate(PARAMS.rotor_positions_flu_m) if y > 0.0]
    right = [i for i, (_, y) in enumerate(PARAMS.rotor_positions_flu_m) if y < 0.0]
    return left, right


def test_more_thrust_on_the_left_rolls_right():
    hover = PARAMS.hover_rotor_speed_rad_s
    left, _ = _left_right_rotors()
    speeds = np.full(4, hover)
    speeds[left] *= 1.05
    _, torque = _dynamics_at(speeds).wrench(LEVEL, ZERO, ZERO)
    assert torque[0] > 0.0          # about body +x: left side up, right side down
    # The same in pybullet: after a short time the right side (body -y) points below the horizon.
    with PhysicsWorld(PARAMS, SimConfig(), np.random.default_rng(0)) as world:
        world.reset(np.array([0.0, 0.0, 20.0]), 0.0, rotor_speeds_rad_s=speeds)
        command = speeds / PARAMS.max_rotor_speed_rad_s
        for _ in range(40):
            state = world.step(command)
        assert state.angular_velocity_flu_rad_s[0] > 0.1
        right_axis = quat_to_rotation_matrix(state.q_wxyz) @ np.array([0.0, -1.0, 0.0])
        assert right_axis[2] < -0.01


def test_more_thrust_on_the_front_pitches_nose_up():
    hover = PARAMS.hover_rotor_speed_rad_s
    front = [i for i, (x, _) in enumerate(PARAMS.rotor_positions_flu_m) if x > 0.0]
    speeds = np.full(4, hover)
    speeds[front] *= 1.05
    _, torque = _dynamics_at(speeds).wrench(LEVEL, ZERO, ZERO)
    assert torque[1] < 0.0          # negative about +y: nose up


def test_yaw_reaction_torque_opposes_the_spin():
    hover = PARAMS.hover_rotor_speed_rad_s
    speeds = np.array([hover if d is SpinDirection.CCW else 0.0 for d in PARAMS.rotor_directions])
    _, torque = _dynamics_at(speeds).wrench(LEVEL, ZERO, ZERO)
    # Counter-clockwise rotors push the airframe clockwise seen from above: negative about +z.
    thrust = PARAMS.motor_constant_n_per_rad2_s2 * hover ** 2
    assert torque[2] == pytest.approx(-2.0 * PARAMS.moment_constant_m * thrust)
    speeds = np.array([hover if d is SpinDirection.CW else 0.0 for d in PARAMS.rotor_directions])
    _, torque = _dynamics_at(speeds).wrench(LEVEL, ZERO, ZERO)
    assert torque[2] > 0.0


def test_torque_is_returned_in_the_world_frame():
    left, _ = _left_right_rotors()
    speeds = np.full(4, PARAMS.hover_rotor_speed_rad_s)
    speeds[left] *= 1.05
    dyn = _dynamics_at(speeds)
    _, torque_body = dyn.wrench(LEVEL, ZERO, ZERO)
    q_north = quat_from_yaw(math.pi / 2.0)        # body +x along world +y
    force, torque = dyn.wrench(q_north, ZERO, ZERO)
    assert torque == pytest.approx(quat_to_rotation_matrix(q_north) @ torque_body)
    assert torque[1] == pytest.approx(torque_body[0])


def test_body_drag_opposes_the_airspeed():
    dyn = QuadrotorDynamics(PARAMS)               # rotors stopped: airframe drag only
    for velocity in ([5.0, 0.0, 0.0], [0.0, -3.0, 0.0], [2.0, 1.0, -4.0]):
        v = np.array(velocity)
        force, _ = dyn.wrench(LEVEL, v, ZERO)
        assert force @ v < 0.0
    force, _ = dyn.wrench(LEVEL, np.array([4.0, 3.0, 0.0]), ZERO)
    # Equal x and y areas: exactly opposite, 0.5 rho CdA |v|^2.
    expected = 0.5 * PARAMS.air_density_kg_m3 * PARAMS.body_drag_cd_area_m2[0] * 25.0
    assert force == pytest.approx(-expected * np.array([0.8, 0.6, 0.0]))


def test_rotor_drag_adds_to_body_drag_when_spinning():
    v = np.array([5.0, 0.0, 0.0])
    still, _ = QuadrotorDynamics(PARAMS).wrench(LEVEL, v, ZERO)
    spinning, _ = _dynamics_at(np.full(4, PARAMS.hover_rotor_speed_rad_s)).wrench(LEVEL, v, ZERO)
    extra = spinning[0] - still[0]
    assert extra == pytest.approx(-PARAMS.rotor_drag_coefficient * 4 * PARAMS.hover_rotor_speed_rad_s * 5.0)


def test_wind_changes_the_airspeed():
    dyn = _dynamics_at(np.full(4, PARAMS.hover_rotor_speed_rad_s))
    wind = np.array([5.0, 0.0, 0.0])
    in_wind, torque_wind = dyn.wrench(LEVEL, ZERO, wind)
    moving, torque_moving = dyn.wrench(LEVEL, -wind, ZERO)
    assert in_wind == pytest.approx(moving)
    assert torque_wind == pytest.approx(torque_moving)
    assert in_wind[0] > 0.0                      # pushed downwind
    calm, _ = dyn.wrench(LEVEL, ZERO, ZERO)
    assert calm[0] == pytest.approx(0.0)


def test_wind_model_statistics_and_determinism():
    cfg = WindConfig(mean_velocity_enu_m_s=(3.0, -1.0, 0.0), gust_std_m_s=1.5, gust_time_constant_s=0.5)
    a = WindModel(cfg, np.random.default_rng(7))
    b = WindModel(cfg, np.random.default_rng(7))
    samples = np.array([a.velocity_enu_m_s(0.05) for _ in range(20000)])
    again = np.array([b.velocity_enu_m_s(0.05) for _ in range(20000)])
    assert np.array_equal(samples, again)
    assert samples.mean(axis=0) == pytest.approx([3.0, -1.0, 0.0], abs=0.15)
    assert samples.std(axis=0) == pytest.approx([1.5] * 3, rel=0.1)
    # Lag-one correlation exp(-dt/T) for the first-order Gauss-Markov process.
    g = samples[:, 0] - samples[:, 0].mean()
    assert np.corrcoef(g[:-1], g[1:])[0, 1] == pytest.approx(math.exp(-0.1), abs=0.02)
    calm = WindModel(WindConfig(), np.random.default_rng(0))
    assert np.array_equal(calm.velocity_enu_m_s(0.1), np.zeros(3))


def _fly(seed: int) -> np.ndarray:
    cfg = SimConfig(wind=WindConfig(mean_velocity_enu_m_s=(2.0, 0.0, 0.0), gust_std_m_s=1.0))
    with PhysicsWorld(PARAMS, cfg, np.random.default_rng(seed)) as world:
        world.reset(np.array([0.0, 0.0, 30.0]), 0.3,
                    rotor_speeds_rad_s=np.full(4, PARAMS.hover_rotor_speed_rad_s))
        command = hover_motor_command(PARAMS) * np.array([1.01, 1.0, 0.99, 1.0])
        for _ in range(100):
            state = world.step(command)
        return np.concatenate([state.position_enu_m, state.velocity_enu_m_s, state.q_wxyz])


def test_simulation_is_deterministic_with_a_seed():
    assert np.array_equal(_fly(3), _fly(3))
    assert not np.array_equal(_fly(3), _fly(4))


def test_resting_on_the_ground_reads_plus_g_on_body_z():
    with PhysicsWorld(PARAMS, SimConfig(), np.random.default_rng(0)) as world:
        world.reset(np.array([5.0, -3.0, 0.0]), 1.0)
        assert world.state().specific_force_flu_m_s2 == pytest.approx([0.0, 0.0, PARAMS.gravity_m_s2])
        for _ in range(400):
            state = world.step(np.zeros(4))
        assert state.specific_force_flu_m_s2 == pytest.approx([0.0, 0.0, PARAMS.gravity_m_s2], abs=0.05)
        assert abs(state.position_enu_m[2]) < 0.01          # resting height is z = 0
        assert np.linalg.norm(state.velocity_enu_m_s) < 1e-3


def test_dropped_vehicle_falls_with_g():
    with PhysicsWorld(PARAMS, SimConfig(), np.random.default_rng(0)) as world:
        world.reset(np.array([0.0, 0.0, 40.0]), 0.0)
        for _ in range(40):                          # 0.1 s, drag still negligible
            state = world.step(np.zeros(4))
        t = state.time_s
        assert state.position_enu_m[2] == pytest.approx(40.0 - 0.5 * PARAMS.gravity_m_s2 * t * t, abs=2e-3)
        assert state.velocity_enu_m_s[2] == pytest.approx(-PARAMS.gravity_m_s2 * t, rel=0.01)
        assert np.linalg.norm(state.specific_force_flu_m_s2) < 0.1     # free fall reads ~0


def test_vehicle_takes_off_after_resting():
    with PhysicsWorld(PARAMS, SimConfig(), np.random.default_rng(0)) as world:
        world.reset(np.zeros(3), 0.0)
        for _ in range(800):                          # 2 s on the ground: must not fall asleep
            world.step(np.zeros(4))
        for _ in range(400):
            state = world.step(np.full(4, 0.8))
        assert state.position_enu_m[2] > 0.5 and state.velocity_enu_m_s[2] > 1.0


def test_set_pose_is_kinematic():
    with PhysicsWorld(PARAMS, SimConfig(), np.random.default_rng(0)) as world:
        q = quat_from_euler_zyx(0.5, 0.1, 0.0)
        state = world.set_pose(np.array([10.0, 20.0, 100.0]), q, np.array([5.0, 0.0, 0.0]))
        assert state.position_enu_m == pytest.approx([10.0, 20.0, 100.0])
        assert state.q_wxyz == pytest.approx(q)
        assert state.velocity_enu_m_s == pytest.approx([5.0, 0.0, 0.0])
        up_in_body = quat_to_rotation_matrix(q).T @ np.array([0.0, 0.0, PARAMS.gravity_m_s2])
        assert state.specific_force_flu_m_s2 == pytest.approx(up_in_body)
        assert world.state() is state


def test_vehicle_params_are_the_iris_values():
    # The model reads these constants; a sanity check that hover is inside the motor range.
    assert 0.0 < QuadrotorDynamics(PARAMS).hover_command < 1.0
    assert dataclasses.asdict(PARAMS)["mass_kg"] == 1.5
