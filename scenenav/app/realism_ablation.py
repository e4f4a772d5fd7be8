"""``python -m scenenav.app.realism_ablation``: what makes the fixes false on a realism profile.

Usage: ``python -m scenenav.app.realism_ablation --realism realistic [--set KEY=VALUE ...] [--probe
truth-heading ...] [--method none|cnn|...] [--max-survey-s 90] [--json OUT] [--frames-csv OUT]``
(docs/realism.md, "What breaks matching on `realistic`", has the table it made).

One Table-2 mission is flown in-process, deterministic and without the bus: the simulator's core
(``sitl.core.SimulatorCore``, the one every caller drives) ticked at the clock rate, the autopilot's
``FlightCore`` flying the scenario's own route mission the way the autopilot node does (sensor
samples as they arrive, one ``step`` per tick with the tick's IMU sample, the commands drive the next
tick), the camera rendered in-process by ``sitl.render_worker.CameraPipeline`` with the core's optics
seed, and the camera effects and header of ``SimulatorCore.camera_frame``. Every released frame goes
to one or more perception pipelines (``perception.node.make_pipeline``), fed as the perception node
feeds its own: the newest compass and baro samples at or before the frame's time stamp and, for a
FIXED-mount frame with ``perception.alignment: homography``, the roll and pitch of the newest
``NavEstimate`` the autopilot node would have published (``autopilot.estimate_rate_hz``) at or before
it; never truth.

*Probes* (``--probe``) are extra pipelines on the same frames that replace one alignment input by
the truth (``truth-tilt``, ``truth-heading``, ``truth-height``) or by the autopilot's own estimate
(``ekf-heading``): they split the alignment error into its inputs without another flight. Truth goes
only into these probes and into the scoring.

Scoring is ``scenenav experiment table2``'s: a fix's error is against the true position at the
frame's time stamp after undoing the reference misregistration; only frames whose true height is
within ``SURVEY_BAND_M`` of the flight altitude count; a fix is false when it is valid and more than
``threshold_m`` off. With GPS off (``sim.gps.enabled=false``) the first pipeline's accepted fixes
are handed to the autopilot (external navigation), so the flight closes the loop like
``scenarios/gps_denied*.yaml``; with GPS on the fixes never steer and every probe sees the same
flight.

Use training or fitting worlds only (docs/cnn.md, docs/perception.md: never tune on the held-out
seeds).
"""

from __future__ import annotations

import argparse
import bisect
import dataclasses
import json
import logging
import math
import sys
import time
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np

from scenenav.app.experiment import SURVEY_BAND_M, table2_scenario
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)


class Probe(str, Enum):
    """Which alignment input a probe pipeline replaces (``NODE``: none, what the node does)."""

    NODE = "node"                      # compass heading, baro height, estimated roll/pitch
    TRUTH_TILT = "truth-tilt"          # true roll/pitch at the capture
    TRUTH_HEADING = "truth-heading"    # true heading at the capture
    TRUTH_HEIGHT = "truth-height"      # true height at the capture
    EKF_HEADING = "ekf-heading"        # the autopilot's estimated heading instead of the raw compass
    TRUTH_ALL = "truth-all"            # true tilt, heading and height


@dataclass
class _History:
    """(timestamp_us, value) samples; the newest at or before a time (the node's ``_at``)."""

    times: list[int] = field(default_factory=list)
    values: list = field(default_factory=list)

    def add(self, t_us: int, value) -> None:
        self.times.append(t_us)
        self.values.append(value)

    def at(self, t_us: int):
        if not self.times:
            return None
        i = bisect.bisect_right(self.times, t_us) - 1
        return self.values[max(i, 0)]


@dataclass
class FrameRecord:
    t_s: float
    truth_xyz_m: tuple[float, float, float]
    truth_tilt_rad: tuple[float, float]
    est_tilt_rad: tuple[float, float] | None
    truth_heading_rad: float
    compass_heading_rad: float | None
    ekf_heading_rad: float | None
    baro_m: float | None
    heading_correction_rad: float = math.nan     # the first probe's learned correction (if learning)
    match: tuple = ()                            # the first probe's (peak, psr, spr, quality_ok, search)
    estimate_xy_m: tuple[float, float] = (math.nan, math.nan)   # the autopilot's position estimate
    fixes: dict[str, tuple[bool, bool, float, float]] = field(default_factory=dict)  # valid, accepted, x, y


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def ablation_settings(realism: str, seed: int, world: str | None, overrides: tuple[str, ...]):
    """The scenario (``ScenarioConfig``), world and route of the Table-2 autopilot flight on
    ``realism`` with ``overrides`` (``KEY=VALUE``, laid over everything like ``--set``)."""
    _sets, cfg, w = table2_scenario(world, seed, realism, False, overrides)
    return cfg, w, cfg.flight.route_enu_m


def fly(cfg, world, *, probes: tuple[Probe, ...] = (Probe.NODE,), method: str = "none",
        weights: str | None = None, max_survey_s: float | None = None,
        progress: bool = False) -> list[FrameRecord]:
    """Fly the scenario's autopilot mission in-process (module docstring); one record per frame."""
    import cv2

    from autopilot_bridge.config import PositionSource
    from autopilot_bridge.flight_core import FlightCore
    from autopilot_bridge.fusion import GpsReading, ImuReading, flow_reading
    from autopilot_bridge.modes import CopterMode
    from autopilot_bridge.param_specs import PARAM_SPECS
    from autopilot_bridge.params import ParameterStore
    from autopilot_bridge.route_mission import build_route_mission
    from perception.alignment import BadInput
    from perception.config import PerceptionNodeConfig
    from perception.node import make_pipeline
    from scenenav.app.nodes import _perception_weights, autopilot_setup
    from scenenav.core.frames import heading_to_enu_yaw
    from scenenav.core.rotations import aviation_euler_from_quat
    from sitl.core import SimulatorCore
    from sitl.node import sensor_surface
    from sitl.render_worker import CameraPipeline

    cv2.setNumThreads(1)
    m = world.manifest
    sim = cfg.sim
    core = SimulatorCore(sim, cfg.clock.tick_rate_hz, cfg.seed, m.origin_lat_deg, m.origin_lon_deg,
                         surface=sensor_surface(sim, world))
    cam_cfg = dataclasses.replace(sim.camera, render_in_worker=False)
    camera = CameraPipeline(world.orthophoto, world.m_per_px, cam_cfg, heights_m=world.dsm_m,
                            facade_rgb=world.facade_rgb, optics_seed=core.optics_seed)
    sx, sy = cfg.flight.start_enu_m
    core.start_at(np.array([sx, sy, 0.0]), heading_to_enu_yaw(math.radians(cfg.flight.start_heading_deg)))

    setup = autopilot_setup(cfg, (m.origin_lat_deg, m.origin_lon_deg))
    defaults: dict[str, float] = {}
    if setup.position_source == PositionSource.EXTNAV:
        defaults.update({"EK3_SRC1_POSXY": int(PositionSource.EXTNAV),
                         "EK3_SRC1_VELXY": int(PositionSource.NONE)})
    defaults.update(cfg.autopilot.params)
    ap = FlightCore(ParameterStore(PARAM_SPECS, defaults=defaults), setup.core)
    if not sim.gps.enabled:
        ap.set_vision_available(True)      # the perception node is live (the node tells the core so)
    est_period_us = int(round(1e6 / cfg.autopilot.estimate_rate_hz))
    next_est_us = 0

    pweights = weights if weights is not None else _perception_weights(cfg.perception)
    # the method, the reference and the heading learning of the scenario; every other perception key
    # at its default (the harness's measurements were taken so)
    pipes = {p: make_pipeline(world, PerceptionNodeConfig(
                method=method, reference=cfg.perception.reference,
                heading_learning=cfg.perception.heading_learning and p is not Probe.TRUTH_HEADING
                and p is not Probe.TRUTH_ALL), fov_deg=sim.camera.fov_deg, weights=pweights)
             for p in probes}
    homography = cfg.perception.alignment == "homography"
    gps_on = sim.gps.enabled

    from perception.tracker import prior_search_radius_m
    headings, altitudes, tilts, ekf_headings = _History(), _History(), _History(), _History()
    priors = _History()
    use_prior = cfg.perception.prior_from_estimate
    truth_at_capture: dict[int, tuple] = {}
    records: list[FrameRecord] = []
    mission_loaded = started = False
    reached = False
    survey_start_s = None
    alt = cfg.flight.altitude_m
    t_wall = time.perf_counter()
    max_ticks = int(cfg.duration_s * cfg.clock.tick_rate_hz)
    try:
        for _ in range(max_ticks):
            out = core.sense()
            t_s = out.timestamp_us * 1e-6
            if out.baro is not None:
                ap.on_baro(t_s, out.baro.altitude_m)
                altitudes.add(out.timestamp_us, out.baro.altitude_m)
            if out.compass is not None:
                ap.on_compass(t_s, out.compass.heading_rad)
                headings.add(out.timestamp_us, out.compass.heading_rad)
            if out.gps is not None and gps_on:
                g = out.gps
                ap.on_gps(GpsReading(t_s, g.lat_deg, g.lon_deg, g.alt_m, tuple(g.velocity_enu_m_s),
                                     g.eph_m, g.epv_m, g.fix_type, g.satellites))
            if out.power is not None:
                ap.on_power(t_s, out.power.voltage_v, out.power.current_a)
            if out.flow is not None:
                ap.on_flow(flow_reading(out.flow))
            if out.camera_request is not None:
                req = out.camera_request
                camera.request(req.seq, req.position_enu_m, req.q_wxyz, capture_s=req.capture_us * 1e-6,
                               velocity_enu_m_s=req.velocity_enu_m_s,
                               body_rates_flu_rad_s=req.body_rates_flu_rad_s)
                r, p, h = aviation_euler_from_quat(req.q_wxyz)
                truth_at_capture[req.seq] = (tuple(float(c) for c in req.position_enu_m), (r, p), h)
            if out.camera_release is not None:
                rel = out.camera_release
                frame = core.camera_frame(rel, camera.result(rel.seq))
                pos, ttilt, thead = truth_at_capture.pop(rel.seq)
                rec = FrameRecord(frame.timestamp_us * 1e-6, pos, ttilt,
                                  tilts.at(frame.timestamp_us), thead, headings.at(frame.timestamp_us),
                                  ekf_headings.at(frame.timestamp_us), altitudes.at(frame.timestamp_us))
                fixed = homography and frame.mount == "fixed"
                prior = priors.at(frame.timestamp_us) if use_prior else None
                prior_xy = None if prior is None or prior[2] is None else (prior[0], prior[1])
                nav = ap.estimate()
                if nav is not None:
                    rec.estimate_xy_m = (float(nav.position_enu_m[0]), float(nav.position_enu_m[1]))
                for probe, pipe in pipes.items():
                    heading, height, tilt = rec.compass_heading_rad, rec.baro_m, rec.est_tilt_rad
                    if probe in (Probe.TRUTH_TILT, Probe.TRUTH_ALL):
                        tilt = ttilt
                    if probe in (Probe.TRUTH_HEADING, Probe.TRUTH_ALL):
                        heading = thead
                    if probe in (Probe.TRUTH_HEIGHT, Probe.TRUTH_ALL):
                        height = pos[2]
                    if probe is Probe.EKF_HEADING:
                        heading = rec.ekf_heading_rad
                    if probe is probes[0] and pipe.heading_deviation is not None and heading is not None:
                        rec.heading_correction_rad = pipe.heading_deviation.correction_rad(heading)
                    if heading is None or height is None:
                        rec.fixes[probe.value] = (False, False, math.nan, math.nan)
                        continue
                    try:
                        res = pipe.process(frame.pixels, heading, height, rec.t_s, prior_xy,
                                           fov_deg=frame.fov_deg, tilt_rad=tilt if fixed else None,
                                           intrinsics_px=frame.intrinsics_fx_fy_cx_cy_px,
                                           distortion=frame.distortion_k1_k2_p1_p2,
                                           prior_radius_m=None if prior_xy is None else prior[2])
                    except BadInput:
                        rec.fixes[probe.value] = (False, False, math.nan, math.nan)
                        continue
                    x, y = res.position_enu_m
                    if probe is probes[0]:
                        mm = res.metrics
                        rec.match = (float(mm.peak), float(mm.psr), float(mm.second_peak_ratio),
                                     int(res.quality_ok), res.search.value if res.search is not None else "",
                                     res.run)
                    rec.fixes[probe.value] = (bool(res.valid), bool(res.accepted), float(x), float(y))
                    if probe is probes[0] and not gps_on:
                        ap.on_vision_fix(rec.t_s, (x, y), res.covariance_m2, bool(res.valid),
                                         bool(res.accepted), "perception")
                records.append(rec)
                if abs(pos[2] - alt) <= SURVEY_BAND_M:
                    survey_start_s = rec.t_s if survey_start_s is None else survey_start_s
                    reached = True
                elif reached and pos[2] < alt - SURVEY_BAND_M:
                    break    # the descent: nothing more is scored
                if max_survey_s is not None and survey_start_s is not None \
                        and rec.t_s - survey_start_s > max_survey_s:
                    break
                if progress and len(records) % 200 == 0:
                    log.info("frame %d, t %.0f s, %.0f s wall", len(records), t_s, time.perf_counter() - t_wall)
            imu = out.imu
            cmd = ap.step(imu.dt_s, ImuReading(imu.accel_flu_m_s2, imu.gyro_flu_rad_s), t_s)
            if out.timestamp_us >= next_est_us:
                next_est_us = out.timestamp_us + est_period_us
                est = ap.estimate()
                if est is not None:
                    r, p, _h = aviation_euler_from_quat(est.q_wxyz)
                    tilts.add(out.timestamp_us, (r, p))
                    pipe0 = pipes[probes[0]]
                    priors.add(out.timestamp_us, (float(est.position_enu_m[0]), float(est.position_enu_m[1]),
                                                  prior_search_radius_m(est.position_std_m, pipe0.m_per_px,
                                                                        cfg.perception.prior_margin_px,
                                                                        pipe0.cfg.matcher.max_search_radius_px)))
                    ekf_headings.add(out.timestamp_us, float(est.heading_rad))
            if setup.mission is not None and not started and ap.aligned:
                if not mission_loaded:
                    ap.mission_changed(build_route_mission(ap.geo, setup.mission.route_enu_m,
                                                           setup.mission.altitude_m,
                                                           cfg.autopilot.mission_end))
                    mission_loaded = True
                if not ap.armed:
                    ap.set_mode(CopterMode.GUIDED)
                    ap.arm(False)
                if ap.armed and ap.set_mode(CopterMode.AUTO).ok:
                    started = True
            core.advance(cmd)
            if ap.status().mission_complete:
                break
    finally:
        camera.close()
        core.close()
    return records


def score(records: list[FrameRecord], world, altitude_m: float, threshold_m: float = 5.0) -> dict[str, dict]:
    """Per probe: fixes, false share, RMS over all valid fixes and over accepted fixes, median."""
    ref = world.manifest.reference
    survey = [r for r in records if abs(r.truth_xyz_m[2] - altitude_m) <= SURVEY_BAND_M]
    out: dict[str, dict] = {}
    if not survey:
        return out
    tx = np.array([r.truth_xyz_m[0] for r in survey])
    ty = np.array([r.truth_xyz_m[1] for r in survey])
    ox, oy = ref.offset_m(tx, ty)
    for probe in survey[0].fixes:
        f = np.array([r.fixes.get(probe, (False, False, math.nan, math.nan)) for r in survey], dtype=float)
        valid, acc = f[:, 0] > 0.5, (f[:, 0] > 0.5) & (f[:, 1] > 0.5)
        err = np.hypot(f[:, 2] - tx - ox, f[:, 3] - ty - oy)
        false = valid & (err > threshold_m)
        n = int(valid.sum())
        out[probe] = {
            "frames": len(survey), "fixes": n, "false": int(false.sum()),
            "false_share": float(false.sum() / n) if n else None,
            "rms_all_m": float(np.sqrt(np.mean(err[valid] ** 2))) if n else None,
            "median_m": float(np.median(err[valid])) if n else None,
            "rms_true_m": float(np.sqrt(np.mean(err[valid & ~false] ** 2))) if (valid & ~false).any() else None,
            "accepted": int(acc.sum()),
            "rms_accepted_m": float(np.sqrt(np.mean(err[acc] ** 2))) if acc.any() else None,
            "false_accepted": int((false & acc).sum()),
            "recall": float((false & ~acc).sum() / false.sum()) if false.any() else None,
            "precision": float((false & valid & ~acc).sum() / (valid & ~acc).sum()) if (valid & ~acc).any() else None,
        }
    return out


def estimate_errors(records: list[FrameRecord], altitude_m: float) -> dict[str, float | None]:
    """The autopilot's horizontal position error over the survey frames (RMS, max, m)."""
    e = np.array([math.hypot(r.estimate_xy_m[0] - r.truth_xyz_m[0], r.estimate_xy_m[1] - r.truth_xyz_m[1])
                  for r in records if abs(r.truth_xyz_m[2] - altitude_m) <= SURVEY_BAND_M])
    e = e[np.isfinite(e)]
    if not len(e):
        return {"rms_m": None, "max_m": None}
    return {"rms_m": float(np.sqrt(np.mean(e ** 2))), "max_m": float(e.max())}


def attitude_errors(records: list[FrameRecord], altitude_m: float) -> dict[str, float]:
    """RMS / mean of the alignment inputs' errors over the survey frames (degrees, metres)."""
    s = [r for r in records if abs(r.truth_xyz_m[2] - altitude_m) <= SURVEY_BAND_M
         and r.est_tilt_rad is not None and r.compass_heading_rad is not None]
    if not s:
        return {}
    d = math.degrees
    roll = np.array([d(_wrap(r.est_tilt_rad[0] - r.truth_tilt_rad[0])) for r in s])
    pitch = np.array([d(_wrap(r.est_tilt_rad[1] - r.truth_tilt_rad[1])) for r in s])
    comp = np.array([d(_wrap(r.compass_heading_rad - r.truth_heading_rad)) for r in s])
    ekf = np.array([d(_wrap(r.ekf_heading_rad - r.truth_heading_rad)) for r in s if r.ekf_heading_rad is not None])
    baro = np.array([r.baro_m - r.truth_xyz_m[2] for r in s if r.baro_m is not None])
    tp = np.array([d(r.truth_tilt_rad[1]) for r in s])

    def stats(a: np.ndarray) -> dict[str, float]:
        return {"mean": float(a.mean()), "rms": float(np.sqrt(np.mean(a ** 2)))} if len(a) else {}
    return {"roll_err_deg": stats(roll), "pitch_err_deg": stats(pitch), "compass_err_deg": stats(comp),
            "ekf_heading_err_deg": stats(ekf), "baro_err_m": stats(baro), "true_pitch_deg": stats(tp)}


def write_frames_csv(path: Path, records: list[FrameRecord], world) -> None:
    """One row per frame: truth, alignment inputs and each probe's fix and error (m)."""
    ref = world.manifest.reference
    probes = list(records[0].fixes) if records else []
    cols = ["t_s", "x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "heading_deg", "est_roll_deg",
            "est_pitch_deg", "compass_deg", "ekf_heading_deg", "baro_m", "correction_deg", "peak", "psr", "spr", "quality_ok",
            "search", "run"]
    cols += [f"{p}_{c}" for p in probes for c in ("valid", "accepted", "err_m")]
    d = math.degrees
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(cols) + "\n")
        for r in records:
            x, y, z = r.truth_xyz_m
            ox, oy = ref.offset_m(np.array([x]), np.array([y]))
            est = r.est_tilt_rad or (math.nan, math.nan)
            vals = [r.t_s, x, y, z, d(r.truth_tilt_rad[0]), d(r.truth_tilt_rad[1]), d(r.truth_heading_rad),
                    d(est[0]), d(est[1]),
                    d(r.compass_heading_rad) if r.compass_heading_rad is not None else math.nan,
                    d(r.ekf_heading_rad) if r.ekf_heading_rad is not None else math.nan,
                    r.baro_m if r.baro_m is not None else math.nan, d(r.heading_correction_rad),
                    *(r.match or (math.nan, math.nan, math.nan, 0, "", 0))]
            for p in probes:
                v, a, fx, fy = r.fixes[p]
                vals += [int(v), int(a), math.hypot(fx - x - float(ox[0]), fy - y - float(oy[0]))]
            fh.write(",".join(f"{v:.4f}" if isinstance(v, float) else str(v) for v in vals) + "\n")


def run_ablation(realism: str, overrides: tuple[str, ...], seed: int = 0, world: str | None = None,
                 probes: tuple[Probe, ...] = (Probe.NODE,), method: str = "none",
                 max_survey_s: float | None = None, progress: bool = False,
                 frames_csv: Path | None = None) -> dict:
    cfg, w, _route = ablation_settings(realism, seed, world, overrides)
    t0 = time.perf_counter()
    recs = fly(cfg, w, probes=probes, method=method, max_survey_s=max_survey_s, progress=progress)
    if frames_csv is not None:
        write_frames_csv(frames_csv, recs, w)
    return {"realism": realism, "overrides": list(overrides), "seed": seed, "world": w.manifest.name,
            "method": method, "wall_s": time.perf_counter() - t0,
            "scores": score(recs, w, cfg.flight.altitude_m),
            "inputs": attitude_errors(recs, cfg.flight.altitude_m),
            "estimate": estimate_errors(recs, cfg.flight.altitude_m),
            "survey_frames": sum(1 for r in recs if abs(r.truth_xyz_m[2] - cfg.flight.altitude_m) <= SURVEY_BAND_M),
            "reached_landing_descent": bool(recs) and recs[-1].truth_xyz_m[2] < cfg.flight.altitude_m - SURVEY_BAND_M}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenenav.app.realism_ablation", description=__doc__.split("\n")[0])
    ap.add_argument("--realism", default="realistic")
    ap.add_argument("--set", action="append", default=[], dest="sets", metavar="KEY=VALUE")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--world", default=None)
    ap.add_argument("--probe", action="append", default=[], choices=[p.value for p in Probe])
    ap.add_argument("--method", default="none")
    ap.add_argument("--max-survey-s", type=float, default=None)
    ap.add_argument("--json", default=None, help="write the result here too")
    ap.add_argument("--frames-csv", default=None, help="one row per frame: inputs and errors")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    probes = tuple(Probe(p) for p in (args.probe or ["node"]))
    try:
        res = run_ablation(args.realism, tuple(args.sets), args.seed, args.world, probes, args.method,
                           args.max_survey_s, progress=True,
                           frames_csv=Path(args.frames_csv) if args.frames_csv else None)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    text = json.dumps(res, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
