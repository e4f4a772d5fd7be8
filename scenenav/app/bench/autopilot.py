"""``scenenav bench autopilot``: cost and accuracy of the autopilot's algorithms, in-process.

The pure algorithm modules (``ekf.NavFilter``, ``control.FlightController``, ``mixer.QuadXMixer``,
``guidance_law.WaypointTracker``) fly the simulator's core (``sitl.core.SimulatorCore``: the pybullet
rigid body with the rotor/drag model of ``sitl.dynamics``, mean wind + Gauss-Markov gusts, the sensor
models with the simulator's default noise), without the bus: the same physics sub-steps, sensor
rates and tick-averaged IMU samples as a flight of the stack (physics at 400 Hz, the autopilot at
100 Hz, baro and compass at 20 Hz, GPS at 5 Hz). Per control tick the core's samples go to the EKF
(predict, then fuse what arrived), guidance, controller and mixer run on the estimate, and the
mixer's commands drive the core's next tick. The flight starts hovering at altitude.

Figures (truth is used only for them):

* cost: CPU time (this thread) of the EKF (predict + fusions + state) and of the control cascade
  (guidance + position/velocity/attitude/rate loops + mixer) per simulated second;
* position hold in wind from the north (``wind_speed_m_s``, ``gust_std_m_s`` gusts), GPS on: after
  ``settle_s``, the RMS / max horizontal distance of the truth from the hold point over ``hold_s``;
* waypoint tracking at ``cruise_speed_m_s`` around a rectangle from the hold point: east
  ``leg_m`` (crosswind), north ``leg_m`` / 1.5 (headwind), west ``leg_m`` (crosswind), south
  (tailwind). While the target moves at cruise speed: cross-track RMS / max of the truth from the
  leg, the mean along-track offset of the truth from the target (negative = behind), and the mean
  downwind offset on the crosswind legs.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import logging
import math
import sys
import time
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from autopilot_bridge.airframe import Airframe
from autopilot_bridge.config import ControlConfig, EkfConfig, GuidanceConfig
from autopilot_bridge.control import FlightController, PositionTarget
from autopilot_bridge.ekf import NavFilter
from autopilot_bridge.guidance_law import Waypoint, WaypointTracker
from autopilot_bridge.mixer import QuadXMixer
from scenenav.app.json_output import emit_json
from scenenav.core.config import check
from scenenav.core.errors import UserError
from scenenav.core.frames import geodetic_to_enu
from scenenav.core.geometry import distance_to_polyline_m
from sitl.config import SimConfig, WindConfig

log = logging.getLogger(__name__)

BENCH_SEED = 7
ORIGIN_LAT_DEG = 47.397742          # any origin: the GPS model needs one for its fixes
ORIGIN_LON_DEG = 8.545594
CRUISE_FRACTION = 0.95              # "cruising": target speed at least this fraction of the cruise speed
HEADWIND_LEG_FRACTION = 1.0 / 1.5


@dataclass(frozen=True)
class AutopilotBenchConfig:
    """Bench settings; durations are simulated seconds."""

    seed: int = BENCH_SEED
    settle_s: float = 10.0
    hold_s: float = 60.0
    wind_speed_m_s: float = 5.0          # mean wind, blowing from the north (towards -y)
    gust_std_m_s: float = 0.5
    gust_time_constant_s: float = 2.0
    cruise_speed_m_s: float = 10.0
    leg_m: float = 150.0                 # crosswind leg length
    altitude_m: float = 20.0
    physics_rate_hz: float = 400.0
    control_rate_hz: float = 100.0

    def __post_init__(self) -> None:
        check(self.settle_s >= 0.0 and math.isfinite(self.settle_s), "settle_s", self.settle_s,
              "a number of seconds >= 0")
        check(0.1 <= self.hold_s <= 3600.0, "hold_s", self.hold_s, "0.1 .. 3600 s")
        check(0.0 <= self.wind_speed_m_s <= 15.0, "wind_speed_m_s", self.wind_speed_m_s, "0 .. 15 m/s")
        check(0.0 <= self.gust_std_m_s <= 5.0, "gust_std_m_s", self.gust_std_m_s, "0 .. 5 m/s")
        check(self.gust_time_constant_s > 0.0, "gust_time_constant_s", self.gust_time_constant_s, "> 0 s")
        check(1.0 <= self.cruise_speed_m_s <= 20.0, "cruise_speed_m_s", self.cruise_speed_m_s,
              "1 .. 20 m/s (WPNAV_SPEED range)")
        check(10.0 <= self.leg_m <= 5000.0, "leg_m", self.leg_m, "10 .. 5000 m")
        check(5.0 <= self.altitude_m <= 500.0, "altitude_m", self.altitude_m, "5 .. 500 m")
        check(self.physics_rate_hz >= self.control_rate_hz > 0.0
              and float(self.physics_rate_hz / self.control_rate_hz).is_integer(),
              "physics_rate_hz", self.physics_rate_hz, "a whole multiple of control_rate_hz")


class _Timer:
    """Accumulated CPU time of this thread, seconds."""

    def __init__(self) -> None:
        self.total_s = 0.0
        self._t0 = 0.0

    def __enter__(self) -> _Timer:
        self._t0 = time.thread_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.total_s += time.thread_time() - self._t0


class BenchFlight:
    """The simulator core + autopilot algorithms, hovering at ``altitude_m`` at the start."""

    def __init__(self, cfg: AutopilotBenchConfig) -> None:
        from sitl.core import SimulatorCore  # pybullet: imported only when the bench runs
        self.cfg = cfg
        wind = WindConfig((0.0, -cfg.wind_speed_m_s, 0.0), cfg.gust_std_m_s, cfg.gust_time_constant_s)
        sim = dataclasses.replace(SimConfig(), physics_rate_hz=cfg.physics_rate_hz, wind=wind)
        self.core = SimulatorCore(sim, cfg.control_rate_hz, cfg.seed, ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
        self.veh = self.core.params
        self.dyn = self.core.physics.dynamics      # the rotor model (hover command)
        self.dt = 1.0 / cfg.control_rate_hz
        self.gps_velocity_std_m_s = max(sim.gps.velocity_noise_std_m_s, 0.1)
        # truth: level hover, heading north (ENU yaw 90 deg), rotors at hover speed
        self.core.start_at(np.array([0.0, 0.0, cfg.altitude_m]), 0.5 * math.pi,
                           np.full(4, self.veh.hover_rotor_speed_rad_s))
        # autopilot
        self.nav = NavFilter(EkfConfig())
        self.fc = FlightController(ControlConfig(), Airframe())    # the autopilot's own model
        self.mixer = QuadXMixer(Airframe())
        self.commands = np.full(4, self.dyn.hover_command)
        self.ticks = 0
        self.ekf_cpu = _Timer()
        self.control_cpu = _Timer()
        self.model_cpu = _Timer()
        first = self.core.sense()          # tick 0: every sensor is due
        assert first.compass is not None and first.baro is not None
        self.nav.initialise(np.array(first.imu.accel_flu_m_s2), first.compass.heading_rad,
                            first.baro.altitude_m, gyro_flu_rad_s=np.array(first.imu.gyro_flu_rad_s),
                            position_enu_m=self.p.copy(), at_rest=False)   # starts hovering
        self.fc.reset(self.nav.state(), landed=False)
        self.core.advance(self.commands)

    @property
    def t_s(self) -> float:
        return self.ticks * self.dt

    @property
    def p(self) -> np.ndarray:
        """True position (ENU, m) after the last tick."""
        return np.asarray(self.core.state().position_enu_m, dtype=float)

    @property
    def v(self) -> np.ndarray:
        """True velocity (ENU, m/s) after the last tick."""
        return np.asarray(self.core.state().velocity_enu_m_s, dtype=float)

    # ------------------------------------------------------------------ one control tick
    def tick(self, law) -> PositionTarget:
        with self.model_cpu:
            out = self.core.sense()
        accel = np.array(out.imu.accel_flu_m_s2)
        gyro = np.array(out.imu.gyro_flu_rad_s)
        with self.ekf_cpu:
            nav = self.nav
            nav.predict(accel, gyro, self.dt)
            if out.baro is not None:
                nav.fuse_baro(out.baro.altitude_m)
            if out.compass is not None:
                nav.fuse_compass(out.compass.heading_rad)
            if out.gps is not None:
                g = out.gps
                x, y = geodetic_to_enu(g.lat_deg, g.lon_deg, ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
                nav.fuse_gps_position((float(x), float(y), g.alt_m), g.eph_m)
                nav.fuse_gps_velocity(np.array(g.velocity_enu_m_s), self.gps_velocity_std_m_s)
            est = nav.state()
        with self.control_cpu:
            target = law.update(est, self.dt)
            out_ctl = self.fc.update_position(est, gyro, target, self.dt)
            mix = self.mixer.mix(out_ctl.thrust_n, out_ctl.torque_flu_n_m)
            self.fc.set_mixer_limits(mix.limits)
            self.commands = np.asarray(mix.commands, dtype=float)
        with self.model_cpu:
            self.core.advance(self.commands)
        self.ticks += 1
        return target

    def close(self) -> None:
        self.core.close()


# ------------------------------------------------------------------ the runs

class _HoldLaw:
    """A fixed position target (LOITER at a point)."""

    def __init__(self, target: PositionTarget) -> None:
        self.target = target

    def update(self, nav, dt_s: float) -> PositionTarget:
        return self.target


def _hold(flight: BenchFlight, cfg: AutopilotBenchConfig) -> dict:
    hold_point = (0.0, 0.0, cfg.altitude_m)
    target = _HoldLaw(PositionTarget(hold_point, heading_rad=0.0))
    for _ in range(int(round(cfg.settle_s * cfg.control_rate_hz))):
        flight.tick(target)
    err_h, err_z = [], []
    for _ in range(int(round(cfg.hold_s * cfg.control_rate_hz))):
        flight.tick(target)
        err_h.append(math.hypot(flight.p[0] - hold_point[0], flight.p[1] - hold_point[1]))
        err_z.append(flight.p[2] - hold_point[2])
    h = np.array(err_h)
    z = np.array(err_z)
    return {"hold_rms_m": float(np.sqrt(np.mean(h ** 2))), "hold_max_m": float(h.max()),
            "hold_z_rms_m": float(np.sqrt(np.mean(z ** 2)))}


def route(cfg: AutopilotBenchConfig) -> list[tuple[float, float, float]]:
    """The tracking rectangle from the hold point: E (crosswind), N (headwind), W (crosswind), S."""
    a, leg, north = cfg.altitude_m, cfg.leg_m, cfg.leg_m * HEADWIND_LEG_FRACTION
    return [(leg, 0.0, a), (leg, north, a), (0.0, north, a), (0.0, 0.0, a)]


def _track(flight: BenchFlight, cfg: AutopilotBenchConfig) -> dict:
    pts = [(0.0, 0.0, cfg.altitude_m)] + route(cfg)                 # from the hold point
    gcfg = GuidanceConfig(wp_speed_m_s=cfg.cruise_speed_m_s)
    tracker = WaypointTracker(gcfg, [Waypoint(p) for p in pts[1:]], pts[0])
    legs = [(np.array(a[:2]), np.array(b[:2])) for a, b in itertools.pairwise(pts)]
    downwind = np.array([0.0, -1.0])
    xtrack, along, downwind_cross, speeds = [], [], [], []
    limit_s = 4.0 * sum(float(np.linalg.norm(b - a)) for a, b in legs) / cfg.cruise_speed_m_s + 30.0
    end_s = flight.t_s + limit_s
    while not tracker.complete:
        target = flight.tick(tracker)
        if flight.t_s > end_s:
            raise RuntimeError(f"tracking did not finish within {limit_s:.0f} simulated s")
        tv = np.asarray(target.velocity_enu_m_s[:2], dtype=float)
        if float(np.linalg.norm(tv)) < CRUISE_FRACTION * cfg.cruise_speed_m_s:
            continue
        tp = np.asarray(target.position_enu_m[:2], dtype=float)
        a, b = min(legs, key=lambda ab: float(distance_to_polyline_m(tp, ab)[0]))
        u = (b - a) / np.linalg.norm(b - a)
        n = np.array([-u[1], u[0]])
        rel = flight.p[:2] - a
        cross = float(rel @ n)
        xtrack.append(cross)
        along.append(float((flight.p[:2] - tp) @ u))
        speeds.append(float(np.linalg.norm(flight.v[:2])))
        if abs(float(u @ downwind)) < 0.1:                     # a crosswind leg
            downwind_cross.append(float(cross * (n @ downwind)))
    x = np.abs(np.array(xtrack)) if xtrack else np.zeros(1)
    return {
        "crosstrack_rms_m": float(np.sqrt(np.mean(x ** 2))),
        "crosstrack_max_m": float(x.max()),
        "crosswind_downwind_mean_m": float(np.mean(downwind_cross)) if downwind_cross else 0.0,
        "along_track_mean_offset_m": float(np.mean(along)) if along else 0.0,
        "cruise_speed_mean_m_s": float(np.mean(speeds)) if speeds else 0.0,
        "cruise_s": len(xtrack) / cfg.control_rate_hz,
    }


def run_bench(cfg: AutopilotBenchConfig | None = None, json_out: bool = False,
              out: TextIO | None = None) -> dict:
    """Fly hold + route once; write a table (or the JSON) to ``out``
    (default stdout; with ``--json`` the real stdout, see ``scenenav.app.json_output``) and return the figures."""
    cfg = cfg if cfg is not None else AutopilotBenchConfig()
    flight = BenchFlight(cfg)
    try:
        report = _fly(flight, cfg)
    finally:
        flight.close()
    if json_out:
        emit_json(report, out)
    else:
        (out or sys.stdout).write(_table(report))
    return report


def _fly(flight: BenchFlight, cfg: AutopilotBenchConfig) -> dict:
    report: dict = {"bench": "autopilot", "seed": cfg.seed, "wind_m_s": cfg.wind_speed_m_s,
                    "gust_std_m_s": cfg.gust_std_m_s, "cruise_speed_m_s": cfg.cruise_speed_m_s,
                    "leg_m": cfg.leg_m, "hold_s": cfg.hold_s}
    report.update(_hold(flight, cfg))
    report.update(_track(flight, cfg))
    sim_s = flight.t_s
    report.update(sim_s=sim_s,
                  ekf_ms_per_sim_s=1e3 * flight.ekf_cpu.total_s / sim_s,
                  controller_ms_per_sim_s=1e3 * flight.control_cpu.total_s / sim_s,
                  models_ms_per_sim_s=1e3 * flight.model_cpu.total_s / sim_s)
    return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in report.items()}


def _table(r: dict) -> str:
    rows = [
        ("EKF (predict + fusions)", f"{r['ekf_ms_per_sim_s']:.1f}", "CPU ms per simulated s"),
        ("control (guidance..mixer)", f"{r['controller_ms_per_sim_s']:.1f}", "CPU ms per simulated s"),
        ("models (dynamics, sensors)", f"{r['models_ms_per_sim_s']:.1f}", "CPU ms per simulated s"),
        (f"hold RMS ({r['wind_m_s']:g} m/s wind)", f"{r['hold_rms_m']:.2f}", "m horizontal"),
        ("hold max", f"{r['hold_max_m']:.2f}", "m horizontal"),
        ("hold vertical RMS", f"{r['hold_z_rms_m']:.2f}", "m"),
        (f"cross-track RMS ({r['cruise_speed_m_s']:g} m/s)", f"{r['crosstrack_rms_m']:.2f}", "m"),
        ("cross-track max", f"{r['crosstrack_max_m']:.2f}", "m"),
        ("crosswind legs, downwind mean", f"{r['crosswind_downwind_mean_m']:+.2f}", "m (+ = downwind)"),
        ("along-track mean offset", f"{r['along_track_mean_offset_m']:+.2f}", "m (- = behind target)"),
        ("cruise speed mean", f"{r['cruise_speed_mean_m_s']:.2f}", "m/s"),
    ]
    width = max(len(a) for a, _, _ in rows)
    lines = [f"autopilot bench: seed {r['seed']}, {r['sim_s']:.0f} simulated s "
             f"(hold {r['hold_s']:g} s, route {r['leg_m']:g} m legs, {r['cruise_s']:.0f} s cruising)\n"]
    lines += [f"  {a:<{width}}  {b:>7}  {c}\n" for a, b, c in rows]
    return "".join(lines)


def _cmd_bench_autopilot(args: argparse.Namespace) -> int:
    try:
        cfg = AutopilotBenchConfig(seed=args.seed, settle_s=args.settle_s, hold_s=args.hold_s,
                                   wind_speed_m_s=args.wind_m_s, cruise_speed_m_s=args.speed_m_s,
                                   leg_m=args.leg_m)
    except UserError as exc:
        raise UserError(f"bench autopilot: {exc}") from None
    run_bench(cfg, json_out=args.json)
    return 0


def register_bench(bench_subparsers) -> None:
    """Add ``autopilot`` to the ``scenenav bench`` sub-commands."""
    d = AutopilotBenchConfig()
    p = bench_subparsers.add_parser(
        "autopilot", help="EKF/controller CPU cost, position hold and waypoint tracking in wind",
        description="Fly the autopilot's pure algorithms (EKF, guidance, cascaded controller, mixer) "
                    "against the simulator's pure models (rotor/drag dynamics, wind with gusts, "
                    "noisy IMU/baro/compass/GPS) in-process, without the bus. Prints the CPU time "
                    "of the EKF and of the control cascade per simulated second, the position-hold "
                    "error in wind after settling, and the cross-track / along-track errors of a "
                    "rectangle flown at cruise speed (east and west legs across the wind). Truth "
                    "is used only for the figures. See docs/autopilot-control.md.")
    p.add_argument("--json", action="store_true", help="print only one JSON object on stdout instead of a table")
    p.add_argument("--seed", type=int, default=d.seed, help=f"random seed (default {d.seed})")
    p.add_argument("--hold-s", type=float, default=d.hold_s,
                   help=f"simulated seconds of position hold measured (default {d.hold_s:g})")
    p.add_argument("--settle-s", type=float, default=d.settle_s,
                   help=f"simulated seconds of hold before measuring (default {d.settle_s:g})")
    p.add_argument("--wind-m-s", type=float, default=d.wind_speed_m_s,
                   help=f"mean wind from the north, m/s (default {d.wind_speed_m_s:g}; gusts "
                        f"{d.gust_std_m_s:g} m/s)")
    p.add_argument("--speed-m-s", type=float, default=d.cruise_speed_m_s,
                   help=f"cruise speed of the route, m/s (default {d.cruise_speed_m_s:g})")
    p.add_argument("--leg-m", type=float, default=d.leg_m,
                   help=f"length of the crosswind legs, m (default {d.leg_m:g})")
    p.set_defaults(func=_cmd_bench_autopilot)
