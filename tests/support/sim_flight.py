"""Closed-loop test flights on the simulator's pure core: no second integrator.

``SimPlant`` is ``sitl.core.SimulatorCore`` (the pybullet rigid body with the rotor/drag model of
``sitl.dynamics``, wind, the sensor models) ticked at the control rate, with the truth the tests
assert on (position, velocity, attitude, touchdown speed). ``CoreFlight`` flies the autopilot's
``FlightCore`` on it the way the autopilot node does (``autopilot_bridge/node.py``: baro, compass,
GPS and power samples as they arrive, then one ``FlightCore.step`` per tick with the tick's IMU
sample, and the motor command drives the next tick), as ``scenenav/app/bench/autopilot.py`` drives
the algorithms. Truth is used only by the tests' assertions.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from autopilot_bridge.config import FlightCoreConfig
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.fusion import CameraFlowReading, GpsReading, ImuReading, flow_reading
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from scenenav.core.rotations import heading_from_quat, quat_to_rotation_matrix
from sitl.config import SimConfig, WindConfig
from sitl.core import SimulatorCore, TickOutput

CONTROL_HZ = 100
DT = 1.0 / CONTROL_HZ
ORIGIN_LAT_DEG = 48.1          # any origin: the GPS model and the autopilot share it
ORIGIN_LON_DEG = 11.5
NORTH_ENU_YAW_RAD = 0.5 * math.pi
#: Truth altitude below which the vehicle counts as on the ground (z = 0 when it rests there).
GROUND_Z_M = 0.02


def sim_config(wind_enu_m_s=(0.0, 0.0, 0.0), gust_std_m_s: float = 0.0, gps: bool = True) -> SimConfig:
    """The simulator's defaults (sensor noise and biases, 400 Hz physics) with this wind."""
    base = SimConfig()
    return dataclasses.replace(
        base, wind=WindConfig(tuple(float(w) for w in wind_enu_m_s), gust_std_m_s, 2.0),
        gps=dataclasses.replace(base.gps, enabled=gps))


class SimPlant:
    """The simulator core at rest on flat ground at the origin (heading north unless given)."""

    def __init__(self, seed: int, sim: SimConfig | None = None,
                 yaw_enu_rad: float = NORTH_ENU_YAW_RAD) -> None:
        self.core = SimulatorCore(sim if sim is not None else sim_config(), CONTROL_HZ, seed,
                                  ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
        self.core.start_at(np.zeros(3), yaw_enu_rad)
        self.touchdown_speed_m_s: float | None = None
        self._airborne = False

    @property
    def t(self) -> float:
        """Simulated time of the current tick, s."""
        return self.core.time_us * 1e-6

    @property
    def p(self) -> np.ndarray:
        return np.asarray(self.core.state().position_enu_m, dtype=float)

    @property
    def v(self) -> np.ndarray:
        return np.asarray(self.core.state().velocity_enu_m_s, dtype=float)

    @property
    def q(self) -> np.ndarray:
        return np.asarray(self.core.state().q_wxyz, dtype=float)

    @property
    def on_ground(self) -> bool:
        return float(self.p[2]) < GROUND_Z_M

    def sense(self) -> TickOutput:
        return self.core.sense()

    def advance(self, command) -> None:
        """Run the tick's physics with ``command``; record the speed of a touchdown (the truth
        speed of the last tick before the vehicle reached the ground)."""
        before = self.v
        self.core.advance(np.asarray(command, dtype=float))
        if not self.on_ground:
            self._airborne = True
        elif self._airborne:
            self._airborne = False
            self.touchdown_speed_m_s = float(np.linalg.norm(before))

    def close(self) -> None:
        self.core.close()


class CoreFlight:
    """``FlightCore`` (parameters ``params`` over the defaults) flying ``SimPlant``.

    ``gps``: GPS samples are delivered (the simulator makes them either way, from its own random
    stream). ``vision``: every 10th tick a position fix (truth + ``vision_std_m`` noise from the
    test's own stream, capture time 50 ms earlier) is handed to the core, as a perception node's
    would be. ``core``: ``FlightCoreConfig`` fields over the test defaults.
    """

    def __init__(self, seed: int = 3, gps: bool = True, sim: SimConfig | None = None,
                 core: dict | None = None, **params) -> None:
        self.plant = SimPlant(seed, sim)
        self.params = ParameterStore(PARAM_SPECS, defaults=params)
        self.core = FlightCore(self.params, FlightCoreConfig(origin_lat_deg=ORIGIN_LAT_DEG,
                                                             origin_lon_deg=ORIGIN_LON_DEG,
                                                             **(core or {})))
        #: added to every compass reading: f(height of the vehicle above the ground plane, m) -> rad
        self.compass_error = None
        self.gps = gps
        self.vision = False
        self.vision_std_m = 0.7
        #: the fixes carry the true heading plus noise of this 1-sigma (rad; None: no heading)
        self.vision_heading_std_rad: float | None = None
        #: added to every fix (a false lock) and the covariance published with it
        self.vision_offset_m = np.zeros(2)
        self.vision_cov_m2 = np.eye(2) * 0.5
        self.rng = np.random.default_rng(seed + 1000)
        #: every 10th tick the camera's flow over the last 10 ticks is handed to the core (as a
        #: perception node's VisionFix carries it) with this white noise (rad/s; None: no camera flow)
        self.camera_flow_std_rad_s: float | None = None
        self._flow_sum = np.zeros(2)
        self._flow_n = 0
        self.cmd = np.zeros(4)
        self.k = 0

    @property
    def t(self) -> float:
        return self.plant.t

    @property
    def p(self) -> np.ndarray:
        return self.plant.p

    @property
    def v(self) -> np.ndarray:
        return self.plant.v

    def tick(self) -> None:
        out = self.plant.sense()
        t = out.timestamp_us * 1e-6
        c = self.core
        if out.baro is not None:
            c.on_baro(t, out.baro.altitude_m)
        if out.compass is not None:
            extra = 0.0 if self.compass_error is None else self.compass_error(float(self.plant.p[2]))
            c.on_compass(t, out.compass.heading_rad + extra)
        if out.gps is not None and self.gps:
            g = out.gps
            c.on_gps(GpsReading(t, g.lat_deg, g.lon_deg, g.alt_m, tuple(g.velocity_enu_m_s), g.eph_m,
                                g.epv_m, g.fix_type, g.satellites))
        if out.power is not None:
            c.on_power(t, out.power.voltage_v, out.power.current_a)
        if out.flow is not None:
            c.on_flow(flow_reading(out.flow))
        if self.vision and self.k % 10 == 0:
            xy = self.plant.p[:2] + self.rng.normal(0.0, self.vision_std_m, 2) + self.vision_offset_m
            hdg = hdg_std = math.nan
            if self.vision_heading_std_rad is not None:
                hdg_std = self.vision_heading_std_rad
                hdg = heading_from_quat(self.plant.q) + float(self.rng.normal(0.0, hdg_std))
            c.on_vision_fix(t - 0.05, xy, self.vision_cov_m2, True, True, "test", hdg, hdg_std)
        if self.camera_flow_std_rad_s is not None:
            self._camera_flow(t)
        self.k += 1
        imu = out.imu
        self.cmd = c.step(imu.dt_s, ImuReading(imu.accel_flu_m_s2, imu.gyro_flu_rad_s), t)
        self.plant.advance(self.cmd)

    def _camera_flow(self, t: float) -> None:
        """Accumulate this tick's true image flow at the image centre over flat ground (FlowSample's
        convention, the body rotation in it); hand the 10-tick mean to the core every 10th tick."""
        st = self.plant.core.state()
        rot = quat_to_rotation_matrix(np.asarray(st.q_wxyz, dtype=float))
        vb = rot.T @ np.asarray(st.velocity_enu_m_s, dtype=float)
        w = np.asarray(st.angular_velocity_flu_rad_s, dtype=float)
        r = max(float(st.position_enu_m[2]), 0.1) / max(float(rot[2, 2]), 0.1)
        self._flow_sum += (-vb[1] / r - w[0], vb[0] / r - w[1])
        self._flow_n += 1
        if self._flow_n == 10:
            flow = self._flow_sum / 10 + self.rng.normal(0.0, float(self.camera_flow_std_rad_s), 2)
            self.core.on_camera_flow(CameraFlowReading(t, (float(flow[0]), float(flow[1])), 10 * DT, 0.9))
            self._flow_sum[:] = 0.0
            self._flow_n = 0

    def run(self, seconds: float, until=None) -> bool:
        """Tick for ``seconds`` (or until ``until()`` is true: then True)."""
        for _ in range(int(round(seconds / DT))):
            self.tick()
            if until is not None and until():
                return True
        return until is None

    def arm_in_guided(self, timeout_s: float = 30.0) -> None:
        """Align (1.5 s at rest), switch to GUIDED and arm, retrying while the gyro bias is still
        being learnt at rest (as the node's and the guidance node's start retry)."""
        c = self.core
        self.run(1.5)
        assert c.aligned and c.set_mode(CopterMode.GUIDED).ok
        while not c.arm(False).ok:
            self.run(0.5)
            assert self.t < timeout_s, "the vehicle could not be armed"

    def close(self) -> None:
        self.plant.close()


def vision_cruise(seed: int = 6, *, compass_bias_rad: float = 0.0,
                  vision_heading_std_rad: float | None = None, sim: SimConfig | None = None,
                  height_m: float = 20.0, cruise_s: float = 15.0,
                  camera_flow_std_rad_s: float | None = None, **params) -> CoreFlight:
    """A GPS-denied flight on vision fixes (EK3_SRC1_POSXY 6, fixes used from 10 m, SN_VIS_TIMEOUT
    3 s, SN_VIS_FS_LAND 5 s, WPNAV_SPEED 10 m/s; ``params`` over these) on ``sim`` (None: the
    simulator's defaults): take off to ``height_m`` and cruise north in GUIDED towards a point 600 m
    away for ``cruise_s``; the fixes still on. The compass reads ``compass_bias_rad`` too much; the
    fixes carry a heading when ``vision_heading_std_rad`` is given (``CoreFlight.vision_heading_std_rad``);
    the camera flow is handed over with ``camera_flow_std_rad_s`` (``CoreFlight.camera_flow_std_rad_s``)."""
    from autopilot_bridge.vehicle_interface import AltFrame
    f = CoreFlight(seed, gps=False, sim=sim, **{"EK3_SRC1_POSXY": 6, "EK3_SRC1_VELXY": 0, "SN_VIS_MIN_ALT": 10,
                                                "SN_VIS_TIMEOUT": 3, "SN_VIS_FS_LAND": 5, "WPNAV_SPEED": 1000,
                                                **params})
    f.vision = True
    f.vision_heading_std_rad = vision_heading_std_rad
    f.camera_flow_std_rad_s = camera_flow_std_rad_s
    if compass_bias_rad:
        f.compass_error = lambda _height_m: compass_bias_rad
    c = f.core
    c.set_vision_available(True)
    f.arm_in_guided()
    assert c.takeoff(height_m).ok
    assert f.run(2.0 * height_m, until=lambda: f.p[2] > height_m - 1.0), \
        f"the climb did not reach {height_m - 1.0:g} m"
    est = c.estimate()
    lat, lon = c.geo.to_geodetic(float(est.position_enu_m[0]), float(est.position_enu_m[1]) + 600.0)
    assert c.reposition(lat, lon, height_m, AltFrame.RELATIVE_HOME, None, None).ok
    f.run(cruise_s)
    assert math.hypot(float(f.v[0]), float(f.v[1])) > 7.0         # cruising
    return f
