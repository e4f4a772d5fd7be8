"""Closed loop: navigation filter + guidance + cascaded controller + mixer flying the simulator's core.

The plant is ``sitl.core.SimulatorCore`` (``support.sim_flight.SimPlant``): the pybullet rigid body
at 400 Hz with the rotor/drag model of ``sitl.dynamics`` and the Iris constants of ``sitl/vehicle.py``
(motor lag, rotor thrust and reaction torques, quadratic body drag on the air-relative velocity),
mean wind plus Gauss-Markov gusts, flat ground at z = 0, and the simulator's sensor models with
their default noise and turn-on biases.

The autopilot's algorithms run at 100 Hz on the navigation filter's estimate only: they see the
core's tick-averaged IMU samples, its 20 Hz barometer and compass, its 5 Hz GPS (or 10 Hz vision
fixes made here from the truth with noise). Truth is used only in the assertions.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.sim_flight import CONTROL_HZ, DT, ORIGIN_LAT_DEG, ORIGIN_LON_DEG, SimPlant, sim_config

from autopilot_bridge.config import GuidanceConfig, PositionSource
from autopilot_bridge.control import FlightController, PositionTarget
from autopilot_bridge.ekf import NavFilter
from autopilot_bridge.guidance_law import Lander, Waypoint, WaypointTracker, make_takeoff
from autopilot_bridge.mixer import QuadXMixer
from scenenav.core.frames import geodetic_to_enu

#: ENU yaw of the start (23 deg north of east): the filter must not rely on a special heading.
START_YAW_ENU_RAD = 0.4


class Flight:
    """Simulator core + autopilot algorithms, ticked at the control rate."""

    def __init__(self, seed: int, wind_enu=(0.0, 0.0, 0.0), gust_std_m_s: float = 0.0) -> None:
        self.rng = np.random.default_rng(seed)
        self.model = SimPlant(seed, sim_config(wind_enu, gust_std_m_s), yaw_enu_rad=START_YAW_ENU_RAD)
        self.gps_velocity_std_m_s = max(self.model.core.sim.gps.velocity_noise_std_m_s, 0.1)
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

    def _fuse(self, out) -> None:
        if out.baro is not None:
            self.nav.fuse_baro(out.baro.altitude_m)
        if out.compass is not None:
            self.nav.fuse_compass(out.compass.heading_rad)
        if self.gps and out.gps is not None:
            g = out.gps
            x, y = geodetic_to_enu(g.lat_deg, g.lon_deg, ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
            self.nav.fuse_gps_position((float(x), float(y), g.alt_m), g.eph_m)
            self.nav.fuse_gps_velocity(np.array(g.velocity_enu_m_s), self.gps_velocity_std_m_s)
        rng = self.rng
        if self.vision and self.tick_count % 10 == 0 and rng.random() > 0.1:      # 10 % of fixes dropped
            fix = self.model.p[:2] + rng.normal(0.0, self.vision_std_m, 2)
            self.nav.fuse_vision_position(fix, np.eye(2) * self.vision_std_m ** 2)

    def align(self) -> None:
        """One second at rest on the ground: average the samples, initialise the filter, arm."""
        accel, gyro, baro, heading, gps = [], [], [], [], []
        for _ in range(CONTROL_HZ):
            out = self.model.sense()
            accel.append(out.imu.accel_flu_m_s2)
            gyro.append(out.imu.gyro_flu_rad_s)
            if out.baro is not None:
                baro.append(out.baro.altitude_m)
            if out.compass is not None:
                heading.append(out.compass.heading_rad)
            if out.gps is not None:
                g = out.gps
                x, y = geodetic_to_enu(g.lat_deg, g.lon_deg, ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
                gps.append((float(x), float(y), g.alt_m))
            self.model.advance(self.commands)
            self.tick_count += 1
        self.nav.initialise(np.mean(accel, axis=0), float(np.angle(np.mean(np.exp(1j * np.array(heading))))) % (2 * np.pi),
                            float(np.mean(baro)), gyro_flu_rad_s=np.mean(gyro, axis=0),
                            gps_position_enu_m=np.mean(gps, axis=0))
        self.fc.reset(self.nav.state(), landed=True)
        self.armed = True

    def tick(self, law) -> tuple:
        out = self.model.sense()
        accel = np.array(out.imu.accel_flu_m_s2)
        gyro = np.array(out.imu.gyro_flu_rad_s)
        self.nav.predict(accel, gyro, DT)
        self._fuse(out)
        est = self.nav.state()
        target: PositionTarget = law.update(est, DT)
        ctl = self.fc.update_position(est, gyro, target, DT)
        if ctl.touchdown:
            self.armed = False
        if self.armed:
            mix = self.mixer.mix(ctl.thrust_n, ctl.torque_flu_n_m)
            self.fc.set_mixer_limits(mix.limits)
            self.commands = mix.commands
        else:
            self.commands = np.zeros(4)
        self.model.advance(self.commands)
        self.tick_count += 1
        self.log.append((self.t, self.model.p.copy(), self.model.v.copy(), est.position_enu_m.copy(), target))
        return target, ctl

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
    assert r["max_speed"] < 11.5
    assert r["xtrack_rms"] < 1.0
    assert r["xtrack_max"] < 2.5
    assert r["transit_s"] < 35.0


@pytest.mark.xfail(strict=True, reason=(
    "the simulator's rotor drag (c_D, iris.sdf) is not in the former test plant: at 10 m/s in a 5 m/s "
    "crosswind the airframe and rotor drag need ~4.5 m/s^2 of the 5 m/s^2 horizontal acceleration cap "
    "(ControlConfig.max_accel_xy_m_s2); cross-track priority lets the along-track speed give way, so the "
    "vehicle cruises at about 9.0 m/s (10.0 m/s with the cap at 10 m/s^2, or with rotor drag off), as "
    "docs/autopilot-control.md, 'Crosswind tracking', describes"))
def test_transit_cruise_speed_is_the_commanded_10m_s(gps_mission):
    assert gps_mission["cruise_speed_mean"] == pytest.approx(10.0, abs=0.7)


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
