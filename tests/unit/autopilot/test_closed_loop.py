"""Closed loop: navigation filter + guidance + cascaded controller + mixer flying a test-only quadrotor model.

The model (below, test-only, independent of sitl/dynamics.py) is a 6-DOF rigid body at 400 Hz with the
Iris constants of sitl/vehicle.py: first-order motor lag (separate up/down time constants), rotor thrust
k w^2 along body z, r x F torques plus rotor reaction torques -dir * c * T, gyroscopic term, quadratic body
drag on the air-relative velocity (constant wind plus a gust process), and a flat ground at z = 0.

The autopilot runs at 100 Hz on the navigation filter's estimate only: it sees tick-averaged IMU samples
with bias and noise, a 20 Hz barometer and compass, 5 Hz GPS (or 10 Hz vision fixes). Truth is used only
in the assertions.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.quad_model import (  # noqa: F401
    ACCEL_BIAS,
    ACCEL_NOISE,
    CONTROL_HZ,
    DT,
    DT_PHYS,
    GYRO_BIAS,
    GYRO_NOISE,
    PHYSICS_HZ,
    SUBSTEPS,
    QuadModel,
)

from autopilot_bridge.config import GuidanceConfig, PositionSource
from autopilot_bridge.control import FlightController, PositionTarget
from autopilot_bridge.ekf import NavFilter
from autopilot_bridge.guidance_law import Lander, Waypoint, WaypointTracker, make_takeoff
from autopilot_bridge.mixer import QuadXMixer
from scenenav.core.rotations import heading_from_quat, quat_from_rotation_vector
from sitl.vehicle import VehicleParams


class Flight:
    """Model + sensors + autopilot algorithms, ticked at the control rate."""

    def __init__(self, seed: int, wind_enu=(0.0, 0.0, 0.0), gust_std_m_s: float = 0.0) -> None:
        self.rng = np.random.default_rng(seed)
        self.par = VehicleParams()
        self.model = QuadModel(self.par)
        self.model.q = quat_from_rotation_vector(0.0, 0.0, 0.4)
        self.wind_mean = np.array(wind_enu, dtype=float)
        self.gust = np.zeros(3)
        self.gust_std = gust_std_m_s
        self.nav = NavFilter()
        self.fc = FlightController()
        self.mixer = QuadXMixer()
        self.gcfg = GuidanceConfig()
        self.commands = np.zeros(4)
        self.tick_count = 0
        self.armed = False
        self.gps = True
        self.vision = False
        self.vision_std_m = 1.5
        self.log: list[tuple] = []

    @property
    def t(self) -> float:
        return self.tick_count * DT

    def _wind(self) -> np.ndarray:
        if self.gust_std > 0.0:
            # Ornstein-Uhlenbeck gusts, 2 s correlation time.
            a = math.exp(-DT_PHYS / 2.0)
            self.gust = a * self.gust + self.rng.normal(0.0, self.gust_std * math.sqrt(1 - a * a), 3)
            self.gust[2] *= 0.3
        return self.wind_mean + self.gust

    def _imu(self):
        f_sum = np.zeros(3)
        w_sum = np.zeros(3)
        for _ in range(SUBSTEPS):
            f, w = self.model.step(self.commands, self._wind())
            f_sum += f
            w_sum += w
        accel = f_sum / SUBSTEPS + ACCEL_BIAS + self.rng.normal(0.0, ACCEL_NOISE, 3)
        gyro = w_sum / SUBSTEPS + GYRO_BIAS + self.rng.normal(0.0, GYRO_NOISE, 3)
        return accel, gyro

    def _fuse(self) -> None:
        m, rng, k = self.model, self.rng, self.tick_count
        if k % 5 == 0:
            self.nav.fuse_baro(m.p[2] + rng.normal(0.0, 0.3))
            self.nav.fuse_compass((heading_from_quat(m.q) + rng.normal(0.0, 0.01)) % (2 * math.pi))
        if self.gps and k % 20 == 0:
            self.nav.fuse_gps_position(m.p + rng.normal(0.0, 0.5, 3), 0.5)
            self.nav.fuse_gps_velocity(m.v + rng.normal(0.0, 0.1, 3), 0.1)
        if self.vision and k % 10 == 0 and rng.random() > 0.1:      # 10 % of fixes dropped
            fix = m.p[:2] + rng.normal(0.0, self.vision_std_m, 2)
            self.nav.fuse_vision_position(fix, np.eye(2) * self.vision_std_m ** 2)

    def align(self) -> None:
        samples = []
        for _ in range(CONTROL_HZ):
            samples.append(self._imu())
            self.tick_count += 1
        accel = np.mean([s[0] for s in samples], axis=0)
        gyro = np.mean([s[1] for s in samples], axis=0)
        baro = float(np.mean(self.model.p[2] + self.rng.normal(0.0, 0.3, 20)))
        heading = heading_from_quat(self.model.q) + self.rng.normal(0.0, 0.01)
        gps = np.mean(self.model.p + self.rng.normal(0.0, 0.5, (5, 3)), axis=0)
        self.nav.initialise(accel, heading, baro, gyro_flu_rad_s=gyro, gps_position_enu_m=gps)
        self.fc.reset(self.nav.state(), landed=True)
        self.armed = True

    def tick(self, law) -> tuple:
        accel, gyro = self._imu()
        self.tick_count += 1
        self.nav.predict(accel, gyro, DT)
        self._fuse()
        est = self.nav.state()
        target: PositionTarget = law.update(est, DT)
        out = self.fc.update_position(est, gyro, target, DT)
        if out.touchdown:
            self.armed = False
        if self.armed:
            mix = self.mixer.mix(out.thrust_n, out.torque_flu_n_m)
            self.fc.set_mixer_limits(mix.limits)
            self.commands = mix.commands
        else:
            self.commands = np.zeros(4)
        self.log.append((self.t, self.model.p.copy(), self.model.v.copy(), est.position_enu_m.copy(), target))
        return target, out

    def run_until(self, law, done, timeout_s: float) -> float:
        start = self.t
        while self.t - start < timeout_s:
            self.tick(law)
            if done():
                return self.t - start
        raise AssertionError(f"not done within {timeout_s} s (t = {self.t:.1f} s, truth {self.model.p})")


@pytest.fixture(scope="module")
def gps_mission():
    """Take off to 20 m, hold, fly 200 m east at 10 m/s, hold in a 5 m/s crosswind, land."""
    f = Flight(seed=11, wind_enu=(0.0, -5.0, 0.0), gust_std_m_s=0.5)
    f.align()
    results = {}
    home = f.nav.state().position_enu_m.copy()
    takeoff = make_takeoff(f.gcfg, home, 20.0)
    results["takeoff_s"] = f.run_until(takeoff, lambda: takeoff.complete, 40.0)
    hold_point = np.array(home) + [0.0, 0.0, 20.0]
    for _ in range(5 * CONTROL_HZ):
        f.tick(takeoff)
    results["hold1_err"] = np.linalg.norm(f.model.p - hold_point)

    goal = np.array([200.0, 0.0, hold_point[2]])
    tracker = WaypointTracker(f.gcfg, [Waypoint(tuple(goal))], hold_point)
    i0 = len(f.log)
    results["transit_s"] = f.run_until(tracker, lambda: tracker.complete, 60.0)
    transit = f.log[i0:]
    # Cross-track error of the truth from the commanded straight line, while cruising at full speed.
    u = (goal - hold_point) / np.linalg.norm(goal - hold_point)
    cruise = [(p, v) for (_, p, v, _, tgt) in transit if np.linalg.norm(tgt.velocity_enu_m_s) > 9.9]
    xtrack = np.array([np.linalg.norm((p - hold_point) - np.dot(p - hold_point, u) * u) for p, _ in cruise])
    results["cruise_ticks"] = len(cruise)
    results["xtrack_rms"] = float(np.sqrt(np.mean(xtrack ** 2)))
    results["xtrack_max"] = float(xtrack.max())
    results["cruise_speed_mean"] = float(np.mean([np.linalg.norm(v[:2]) for _, v in cruise]))
    results["max_speed"] = float(max(np.linalg.norm(v[:2]) for (_, _, v, _, _) in transit))

    i1 = len(f.log)
    for _ in range(20 * CONTROL_HZ):
        f.tick(tracker)
    hold = f.log[i1 + 5 * CONTROL_HZ:]
    err = np.array([np.linalg.norm(p[:2] - goal[:2]) for (_, p, _, _, _) in hold])
    results["hold_rms"] = float(np.sqrt(np.mean(err ** 2)))
    results["hold_max"] = float(err.max())
    results["hold_z_max"] = float(max(abs(p[2] - goal[2]) for (_, p, _, _, _) in hold))

    lander = Lander(f.gcfg, goal, ground_z_m=float(home[2]))
    results["land_s"] = f.run_until(lander, lambda: not f.armed, 90.0)
    results["landed_pos"] = f.model.p.copy()
    results["touchdown_speed"] = f.model.touchdown_speed_m_s
    results["on_ground"] = f.model.on_ground
    results["ekf_healthy"] = f.nav.is_healthy()
    return results


def test_takeoff_and_hold(gps_mission):
    assert gps_mission["takeoff_s"] < 20.0
    assert gps_mission["hold1_err"] < 1.5


def test_transit_200m_at_10m_s_in_crosswind(gps_mission):
    r = gps_mission
    assert r["cruise_ticks"] > 5 * CONTROL_HZ            # several seconds at full speed
    assert r["cruise_speed_mean"] == pytest.approx(10.0, abs=0.7)
    assert r["max_speed"] < 11.5
    assert r["xtrack_rms"] < 1.0
    assert r["xtrack_max"] < 2.5
    assert r["transit_s"] < 35.0


def test_hold_in_5m_s_wind(gps_mission):
    assert gps_mission["hold_rms"] < 1.0
    assert gps_mission["hold_max"] < 1.5
    assert gps_mission["hold_z_max"] < 1.0


def test_land_and_disarm(gps_mission):
    r = gps_mission
    assert r["on_ground"]
    assert np.linalg.norm(r["landed_pos"][:2] - np.array([200.0, 0.0])) < 2.0
    assert r["touchdown_speed"] is not None and r["touchdown_speed"] < 1.0
    assert r["ekf_healthy"]


def test_gps_to_vision_switch_in_flight():
    """Take off on GPS, switch the position source to EXTNAV (vision fixes, GPS lost), fly 100 m and hold."""
    f = Flight(seed=12, wind_enu=(3.0, 0.0, 0.0), gust_std_m_s=0.3)
    f.vision = True
    f.align()
    home = f.nav.state().position_enu_m.copy()
    takeoff = make_takeoff(f.gcfg, home, 20.0)
    f.run_until(takeoff, lambda: takeoff.complete, 40.0)
    before = f.nav.state().position_enu_m.copy()
    f.nav.set_position_source(PositionSource.EXTNAV)
    f.gps = False
    i0 = len(f.log)
    hold_point = np.array(home) + [0.0, 0.0, 20.0]
    goal = hold_point + [0.0, 100.0, 0.0]
    tracker = WaypointTracker(f.gcfg, [Waypoint(tuple(goal))], hold_point)
    f.run_until(tracker, lambda: tracker.complete, 60.0)
    # Continuity: the estimate error (estimate - truth) changes by a few decimetres per tick at most
    # (ordinary vision-fix corrections); a reset would show up as a metre-scale step.
    errors = [e[3][:2] - e[1][:2] for e in f.log[i0:]]
    steps = [float(np.linalg.norm(b - a)) for a, b in zip(errors, errors[1:], strict=False)]
    assert max(steps) < 1.0
    i1 = len(f.log)
    for _ in range(15 * CONTROL_HZ):
        f.tick(tracker)
    err = np.array([np.linalg.norm(p[:2] - goal[:2]) for (_, p, _, _, _) in f.log[i1 + 5 * CONTROL_HZ:]])
    assert float(np.sqrt(np.mean(err ** 2))) < 2.0
    assert err.max() < 4.0
    assert f.nav.position_source == PositionSource.EXTNAV and f.nav.position_reset_count == 0
    assert np.linalg.norm(before - f.log[i0][3]) < 0.5
