"""Evaluation of a run folder: ``summary.json`` and the trajectory plot.

Reads only files (truth.csv, fixes.csv, estimates.csv, status.csv, sim_stats.json), so it also
works on a run that was interrupted. Definitions:

* a fix's error is the horizontal distance between its position and the true position of the
  vehicle (``truth.csv``: the vehicle's body origin, not a point on a roof under it) at the fix's
  capture time (truth interpolated linearly), after undoing the reference misregistration the
  world states: a perfect match of a capture over (x, y) reports (x, y) +
  ``manifest.reference.offset_m(x, y)`` (scenenav/core/formats/world_manifest.py), so the error is
  ``|fix - truth - offset_m(truth)|``. The autopilot's estimate is compared with the truth itself
  (a misregistration it fused is a real navigation error);
* ``fix_errors_by_height``: the valid fixes' errors split by the mean building height in the
  camera footprint at the capture (scenenav/app/height_split.py), ``..._accepted`` the same over
  the accepted fixes;
* a fix is *false* when it is valid and its error exceeds ``evaluation.false_fix_threshold_m``
  (default 5 m); an invalid fix (no match computed) is neither true nor false;
* ``mission_succeeded``: ``mission_completed`` and, for a guided flight, an end within
  ``evaluation.goal_tolerance_m`` of the last goal (``end_distance_to_goal_m``);
* ``rms_error_m`` / ``max_error_m`` are of the autopilot's own estimate against truth (horizontal),
  null when the run had no autopilot, over the whole run; ``rms_error_airborne_m`` /
  ``max_error_airborne_m`` the same over the estimates taken while the vehicle was more than
  ``AIRBORNE_HEIGHT_M`` above where it started (the time at rest before take-off and after landing,
  40-60 s of a GPS-denied mission, would otherwise dilute the RMS); ``fix_rms_error_accepted_m`` is over accepted fixes.

Faults (docs/faults.md): ``end_reason`` says when the simulator died instead of finishing (its
``sim_stats.json`` is missing); ``node_failures`` lists every node that exited on its own with a
non-zero code, when, and the last error line of its log; ``recording_ended_early`` is true when
the recorder stopped before the simulator (its files end at ``recording_end_s``).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import signal
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scenenav.app.height_split import HeightSplit, footprint_mean_height_m, split_by_height
from scenenav.core.errors import UserError
from scenenav.core.formats.atomic_file import write_atomic
from scenenav.core.formats.route_file import RouteFile, read_route_file
from scenenav.core.formats.world_manifest import ReferenceInfo
from scenenav.core.frames import wrap_pi

log = logging.getLogger(__name__)


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """A CSV as columns; numeric columns as float arrays (empty cells -> NaN)."""
    if not path.is_file():
        return {}
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows:
        return {}
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    cols: dict[str, Any] = {}
    for i, name in enumerate(header):
        vals = [r[i] for r in body]
        try:
            cols[name] = np.array([float(v) if v != "" else math.nan for v in vals])
        except ValueError:
            cols[name] = np.array(vals, dtype=object)
    return cols


def exit_description(code: int) -> str:
    """``exit code 2`` or ``killed by SIGKILL`` for a Popen return code."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


@dataclass(frozen=True)
class NodeFailure:
    """A node of the run that exited on its own with a non-zero code (seen by the launcher)."""

    node: str
    exit_code: int
    wall_time_s: float            # since the launch
    sim_time_s: float | None      # newest simulated time in truth.csv when it was seen
    last_error: str               # the last error line of its log ("" if none)

    def describe(self) -> str:
        at = f" at t={self.sim_time_s:.1f} s" if self.sim_time_s is not None else ""
        why = f": {self.last_error}" if self.last_error else ""
        return f"{self.node} {exit_description(self.exit_code)}{at}{why}"


def _last_row(path: Path) -> list[bytes] | None:
    """The last complete row of a CSV the recorder is appending to (read from its end), None if
    it has no row after its header."""
    try:
        with path.open("rb") as f:
            f.seek(max(0, f.seek(0, 2) - 2000))
            lines = [ln for ln in f.read().splitlines() if ln.strip()]
    except OSError:
        return None
    for line in reversed(lines):
        fields = line.split(b",")
        try:
            float(fields[0])
        except ValueError:
            continue
        return fields
    return None


def last_sim_time_s(run_dir: Path) -> float | None:
    """The newest simulated time of truth.csv, None if it has no row."""
    row = _last_row(Path(run_dir) / "truth.csv")
    return None if row is None else float(row[0])


@dataclass(frozen=True)
class RecordedStatus:
    """The autopilot's newest status row in status.csv (t_s, armed, mode, landed, ...)."""

    armed: bool
    landed: bool


def last_status(run_dir: Path) -> RecordedStatus | None:
    """status.csv's newest row, None while it has none."""
    from scenenav.app.recorder import STATUS_COLUMNS
    row = _last_row(Path(run_dir) / "status.csv")
    if row is None or len(row) != len(STATUS_COLUMNS):
        return None
    armed, landed = (row[STATUS_COLUMNS.index(c)].strip() == b"1" for c in ("armed", "landed"))
    return RecordedStatus(armed=armed, landed=landed)


def _interp_truth(truth: dict, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tt = truth["t_s"]
    return np.interp(t, tt, truth["x_m"]), np.interp(t, tt, truth["y_m"])


def _interp_heading_rad(truth: dict, t: np.ndarray) -> np.ndarray:
    """The true compass heading at ``t`` (interpolated on the circle); NaN without the column."""
    if "heading_deg" not in truth:
        return np.full(np.shape(t), np.nan)
    h = np.radians(truth["heading_deg"])
    s, c = np.interp(t, truth["t_s"], np.sin(h)), np.interp(t, truth["t_s"], np.cos(h))
    return np.mod(np.arctan2(s, c), 2.0 * math.pi)


def run_reference(run_dir: Path) -> ReferenceInfo:
    """The reference of the world a run flew over (its misregistration), read from the world's
    manifest named by the run's ``scenario.yaml``; a folder without a scenario (hand-made in a test)
    has no stated misregistration. Only the scenario's ``world`` is read, not the whole scenario
    validated: a finished run written by another version of scenenav (a key added or dropped since)
    is still evaluated (a campaign's report over such runs used to stop at the first one)."""
    from scenenav.core.config import load_yaml
    from scenenav.core.formats.world_manifest import read_manifest
    from worlds.default import world_folder
    path = Path(run_dir) / "scenario.yaml"
    if not path.is_file():
        log.debug("%s: no scenario.yaml, no reference misregistration to undo", run_dir)
        return ReferenceInfo()
    world = load_yaml(path).get("world", "default")
    if not isinstance(world, str) or not world:
        raise UserError(f"{path}: world = {world!r}; expected a world folder, 'default' or "
                        "'generated:seed=N,...'")
    return read_manifest(world_folder(world)).reference


def fix_table(run_dir: Path, threshold_m: float,
              reference: ReferenceInfo | None = None) -> dict[str, np.ndarray]:
    """fixes.csv joined with truth: error_m and is_false per fix.

    The error is against the vehicle's true position at the capture time, after undoing the
    ``reference`` misregistration (default: the one the run's world states, ``run_reference``).
    Added columns: truth_x_m, truth_y_m, truth_z_m, truth_heading_rad (at the capture),
    ref_offset_x_m, ref_offset_y_m (the misregistration there), error_m, is_false.
    """
    fixes = read_csv(run_dir / "fixes.csv")
    truth = read_csv(run_dir / "truth.csv")
    if not fixes or not truth or len(truth.get("t_s", [])) < 2 or len(fixes.get("t_s", [])) == 0:
        return {}
    if reference is None:
        reference = run_reference(run_dir)
    tx, ty = _interp_truth(truth, fixes["t_s"])
    ox, oy = reference.offset_m(tx, ty)
    err = np.hypot(fixes["x_m"] - tx - ox, fixes["y_m"] - ty - oy)
    valid = fixes["valid"] > 0.5
    fixes["error_m"] = np.where(valid, err, np.nan)
    fixes["is_false"] = valid & (err > threshold_m)
    fixes["truth_x_m"], fixes["truth_y_m"] = tx, ty
    fixes["truth_z_m"] = (np.interp(fixes["t_s"], truth["t_s"], truth["z_m"]) if "z_m" in truth
                          else np.full(len(tx), np.nan))
    fixes["truth_heading_rad"] = _interp_heading_rad(truth, fixes["t_s"])
    fixes["ref_offset_x_m"], fixes["ref_offset_y_m"] = np.asarray(ox), np.asarray(oy)
    return fixes


def fix_height_splits(fx: dict[str, np.ndarray], world, fov_deg: float,
                      threshold_m: float) -> tuple[HeightSplit, HeightSplit] | None:
    """The valid and the accepted fixes' errors split by the mean surface height in the camera
    footprint at the capture (true position, height and heading); None without fixes."""
    if not fx:
        return None
    valid = fx["valid"] > 0.5
    if world.dsm_m is None:               # flat: every footprint is 0 m high (no map-sized zeros)
        heights = np.where(np.isfinite(fx["truth_x_m"]), 0.0, np.nan)
    else:
        heights = footprint_mean_height_m(world.dsm_m, world.m_per_px, fx["truth_x_m"], fx["truth_y_m"],
                                          fx["truth_heading_rad"], fx["truth_z_m"], fov_deg)
    acc = valid & (fx["accepted"] > 0.5)
    return (split_by_height(fx["error_m"][valid], heights[valid], threshold_m),
            split_by_height(fx["error_m"][acc], heights[acc], threshold_m))


def fix_metrics(fx: dict[str, np.ndarray]) -> dict[str, Any]:
    if not fx:
        return {"fixes_total": 0, "fixes_valid": 0, "fixes_accepted": 0, "false_fixes": 0,
                "false_fixes_accepted": 0, "false_fixes_rejected": 0, "true_fixes_rejected": 0, "fix_time_ms_median": None,
                "fix_rms_error_accepted_m": None, "fix_rms_error_all_m": None,
                "fixes_with_heading": 0, "fix_heading_rms_error_deg": None}
    valid = fx["valid"] > 0.5
    acc = (fx["accepted"] > 0.5) & valid
    false = fx["is_false"].astype(bool)
    rejected = valid & ~acc
    err = fx["error_m"]

    def rms(mask):
        return float(np.sqrt(np.mean(err[mask] ** 2))) if mask.any() else None
    return {
        "fixes_total": int(len(valid)),
        "fixes_valid": int(valid.sum()),
        "fixes_accepted": int(acc.sum()),
        "fixes_accepted_true": int((acc & ~false).sum()),
        "false_fixes": int(false.sum()),
        "false_fixes_accepted": int((false & acc).sum()),
        "false_fixes_rejected": int((false & rejected).sum()),
        "true_fixes_rejected": int((~false & valid & rejected).sum()),
        "fix_time_ms_median": float(np.nanmedian(fx["time_total_ms"])) if len(valid) else None,
        "fix_rms_error_accepted_m": rms(acc),
        "fix_rms_error_all_m": rms(valid),
        **heading_metrics(fx),
    }


def heading_metrics(fx: dict[str, np.ndarray]) -> dict[str, Any]:
    """The headings the fixes carried (VisionFix version 2, fixes.csv ``heading_deg``): how many,
    and their RMS error against the true heading at the capture (degrees; None without any, e.g.
    a run folder recorded before the column existed)."""
    if "heading_deg" not in fx or "truth_heading_rad" not in fx:
        return {"fixes_with_heading": 0, "fix_heading_rms_error_deg": None}
    hdg = np.asarray(fx["heading_deg"], dtype=float)
    has = np.isfinite(hdg) & np.isfinite(fx["truth_heading_rad"])
    if not has.any():
        return {"fixes_with_heading": 0, "fix_heading_rms_error_deg": None}
    err = np.degrees(wrap_pi(np.radians(hdg[has]) - fx["truth_heading_rad"][has]))
    return {"fixes_with_heading": int(has.sum()),
            "fix_heading_rms_error_deg": float(np.sqrt(np.mean(err ** 2)))}


def _node_method(node_id: str, recorded: dict, methods: np.ndarray) -> str | None:
    """A perception node's method: what its NodeInfo said (the recorder's ``perception_nodes``),
    else the method its fixes name most often."""
    said = (recorded.get(node_id) or {}).get("method")
    if said:
        return str(said)
    if len(methods) == 0:
        return None
    names, counts = np.unique(methods.astype(str), return_counts=True)
    return str(names[int(np.argmax(counts))])


def perception_node_metrics(fx: dict[str, np.ndarray], recorded: dict | None = None) -> list[dict]:
    """The fix figures per perception node (fixes.csv ``node_id``), in the order of their first
    fix: node id, method, fixes, valid, accepted, false (valid with an error over the threshold),
    RMS error over the accepted fixes, the capture times of the first and last fix and the time
    between them (``time_live_s``). ``recorded``: the recorder's ``perception_nodes`` (the
    method each node's NodeInfo gave)."""
    if not fx or "node_id" not in fx:
        return []
    ids = fx["node_id"].astype(str)
    order = sorted(set(ids), key=lambda n: float(np.min(fx["t_s"][ids == n])))
    rows = []
    for node in order:
        mask = ids == node
        m = fix_metrics({k: v[mask] for k, v in fx.items()})
        t = fx["t_s"][mask]
        rows.append({
            "node_id": node,
            "method": _node_method(node, recorded or {}, fx["method"][mask] if "method" in fx
                                   else np.zeros(0)),
            "fixes_total": m["fixes_total"], "fixes_valid": m["fixes_valid"],
            "fixes_accepted": m["fixes_accepted"], "false_fixes": m["false_fixes"],
            "false_fixes_accepted": m["fixes_accepted"] - m["fixes_accepted_true"],
            "fix_rms_error_accepted_m": m["fix_rms_error_accepted_m"],
            "first_fix_s": float(t.min()), "last_fix_s": float(t.max()),
            "time_live_s": float(t.max() - t.min()),
        })
    return rows


def headline_method(cfg, nodes: list[dict]) -> str | None:
    """``perception_method`` of the summary: the method of the node that gave the fixes; after a
    swap the methods in the order they flew (``"cnn -> assistant-map"``); the scenario's when no
    node gave a fix (null without perception)."""
    methods = [n["method"] for n in nodes if n["method"]]
    if methods:
        return " -> ".join(methods)
    return cfg.perception.method if cfg.perception.enabled else None


#: An estimate counts as airborne when the vehicle was this far above its starting height (truth).
AIRBORNE_HEIGHT_M = 1.0


def _estimate_errors_and_airborne(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal error of every autopilot estimate against truth (m), and a mask of those taken
    more than ``AIRBORNE_HEIGHT_M`` above the start (all False without a truth height); both empty
    without an autopilot."""
    est = read_csv(Path(run_dir) / "estimates.csv")
    truth = read_csv(Path(run_dir) / "truth.csv")
    if not est or not truth or len(est.get("t_s", [])) == 0 or len(truth.get("t_s", [])) < 2:
        return np.zeros(0), np.zeros(0, dtype=bool)
    tx, ty = _interp_truth(truth, est["t_s"])
    err = np.hypot(est["x_m"] - tx, est["y_m"] - ty)
    if "z_m" not in truth:
        return err, np.zeros(len(err), dtype=bool)
    z = np.interp(est["t_s"], truth["t_s"], truth["z_m"])
    return err, z > float(truth["z_m"][0]) + AIRBORNE_HEIGHT_M


def estimate_errors(run_dir: Path, airborne_only: bool = False) -> np.ndarray:
    """Horizontal error of every autopilot estimate against truth (m); empty without an autopilot.
    ``airborne_only``: only the estimates taken more than ``AIRBORNE_HEIGHT_M`` above the start."""
    err, airborne = _estimate_errors_and_airborne(run_dir)
    return err[airborne] if airborne_only else err


def _rms_max(e: np.ndarray) -> tuple[float | None, float | None]:
    if len(e) == 0:
        return None, None
    return float(np.sqrt(np.mean(e ** 2))), float(np.max(e))


def estimate_metrics(run_dir: Path) -> dict[str, Any]:
    err, airborne = _estimate_errors_and_airborne(run_dir)
    rms, mx = _rms_max(err)
    rms_air, max_air = _rms_max(err[airborne])
    return {"rms_error_m": rms, "max_error_m": mx,
            "rms_error_airborne_m": rms_air, "max_error_airborne_m": max_air}


def _end_reason(sim_stats: dict, interrupted: bool, failures: tuple[NodeFailure, ...],
                abort_reason: str | None = None) -> str | None:
    if abort_reason:
        return abort_reason
    if interrupted:
        return "interrupted"
    reason = sim_stats.get("end_reason")
    if reason:
        return reason
    for f in failures:
        if f.node == "sim":
            return f"simulator died: {f.describe().removeprefix('sim ')}"
    return "unknown: the simulator left no sim_stats.json (it died or was killed)"


#: An external node's "node down" event later than this before the run's last simulated time is
#: the run's own end (every node leaves then), not the node leaving early.
EXTERNAL_END_MARGIN_S = 1.0


def external_nodes_left(run_dir: Path, cfg, end_s: float | None) -> list[dict]:
    """The external nodes (``external.nodes``; not started by the launcher, so no exit code is
    seen) whose liveliness token went away before the run's end and did not come back, from the
    recorder's ``node down: ROLE/ID`` / ``node up: ROLE/ID`` events: ``{"node": "perception:ID", "sim_time_s": t, "what": ...}``."""
    members = {f"{m.role}/{m.node_id}": m.spec for m in cfg.external.members()}
    if not members or end_s is None:
        return []
    try:
        with (run_dir / "events.csv").open(newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError:
        return []
    left: dict[str, float] = {}
    for row in rows:
        text = row.get("text") or ""
        state, _, key = text.partition(": ")
        if state not in ("node down", "node up") or key.strip() not in members:
            continue
        spec = members[key.strip()]
        try:
            t = float(row.get("t_s") or "nan")
        except ValueError:
            continue
        if state == "node up":
            left.pop(spec, None)          # back (a restart of its own): only a last departure counts
        elif t < end_s - EXTERNAL_END_MARGIN_S:
            left[spec] = t
    return [{"node": spec, "sim_time_s": t,
             "what": f"external node {spec} left the run at t={t:.1f} s, before its end"}
            for spec, t in left.items()]


def evaluate_run(run_dir: Path, cfg, world, wall_time_s: float | None, interrupted: bool = False,
                 failures: tuple[NodeFailure, ...] = (), recorder_stopped_early: bool | None = None,
                 abort_reason: str | None = None) -> dict:
    """Write summary.json and trajectory.png of a run folder. ``failures``: the nodes the launcher
    saw die; ``recorder_stopped_early``: None = judge from the folder (no recorder_stats.json);
    ``abort_reason``: why the launcher ended the run early (a full disk), else None."""
    run_dir = Path(run_dir)
    threshold = cfg.evaluation.false_fix_threshold_m
    fx = fix_table(run_dir, threshold, world.manifest.reference)
    summary: dict[str, Any] = {"scenario": cfg.name, "world": world.manifest.name}
    summary.update(estimate_metrics(run_dir))
    summary.update(fix_metrics(fx))
    rec = _read_json(run_dir / "recorder_stats.json")
    nodes = perception_node_metrics(fx, rec.get("perception_nodes"))
    summary["perception_nodes"] = nodes
    # the headline fix figures pool every node's fixes: say over which nodes
    summary["fix_metrics_nodes"] = [n["node_id"] for n in nodes]
    splits = fix_height_splits(fx, world, cfg.sim.camera.fov_deg, threshold)
    summary["world_has_dsm"] = world.manifest.has_dsm
    summary["reference_misregistration_max_m"] = (
        float(np.nanmax(np.hypot(fx["ref_offset_x_m"], fx["ref_offset_y_m"]))) if fx else None)
    summary["fix_errors_by_height"] = splits[0].to_dict() if splits else None
    summary["fix_errors_by_height_accepted"] = splits[1].to_dict() if splits else None
    status = read_csv(run_dir / "status.csv")
    sim_stats = _read_json(run_dir / "sim_stats.json")
    end_reason = sim_stats.get("end_reason")
    if status and len(status.get("t_s", [])):
        mission_completed = bool(status["mission_complete"][-1] > 0.5)
    else:
        mission_completed = end_reason == "scripted route complete"
    truth = read_csv(run_dir / "truth.csv")
    summary.update({
        "mission_completed": mission_completed,
        "gps_used": bool(status["gps_used"].max() > 0.5) if status and len(status.get("t_s", [])) else False,
        "sim_time_s": sim_stats.get("sim_time_s", float(truth["t_s"][-1]) if truth and len(truth["t_s"]) else 0.0),
        "wall_time_s": round(wall_time_s, 3) if wall_time_s is not None else None,
        "real_time_factor": sim_stats.get("real_time_factor"),
        "end_reason": _end_reason(sim_stats, interrupted, failures, abort_reason),
        "aborted": abort_reason is not None,
        "flight_mode": cfg.flight.mode.value,
        "perception_method": headline_method(cfg, nodes),
        "false_fix_threshold_m": cfg.evaluation.false_fix_threshold_m,
        "distance_flown_m": _distance(truth),
    })
    summary.update(_guidance_metrics(run_dir))
    summary.update(_end_position(cfg, truth, status))
    summary["goal_tolerance_m"] = cfg.evaluation.goal_tolerance_m
    summary["mission_succeeded"] = mission_succeeded(mission_completed, summary.get("end_distance_to_goal_m"),
                                                     cfg.evaluation.goal_tolerance_m)
    if recorder_stopped_early is None:
        recorder_stopped_early = not rec
    summary["recording_ended_early"] = bool(recorder_stopped_early or rec.get("write_failed"))
    if rec.get("write_failed"):
        summary["recording_error"] = rec["write_failed"]
    summary["recording_end_s"] = last_sim_time_s(run_dir)
    summary["node_failures"] = [dataclasses.asdict(f) | {"what": f.describe()} for f in failures]
    summary["external_nodes_left"] = external_nodes_left(run_dir, cfg, summary.get("sim_time_s"))
    write_atomic(run_dir / "summary.json", json.dumps(summary, indent=2))
    try:
        plot_run(run_dir, world, fx, split=splits[0] if splits else None,
                 plot_dsm=cfg.evaluation.plot_dsm)
    except Exception:  # a plot must never lose the summary
        log.exception("could not draw trajectory.png")
    return summary


#: Files of a complete run folder, what each holds (``scenenav summarize`` marks those missing).
RUN_FILES = {
    "truth.csv": "recorder: true pose", "fixes.csv": "recorder: vision fixes",
    "estimates.csv": "recorder: autopilot estimate", "status.csv": "recorder: autopilot status",
    "events.csv": "recorder: events", "bus.mcap": "recorder: every bus message",
    "sim_stats.json": "simulator: end reason and timing", "recorder_stats.json": "recorder: counts",
    "run.json": "launcher: namespace and ports",
}


def summarize_run(run_dir: Path) -> dict:
    """``scenenav summarize``: rebuild summary.json and trajectory.png of any run folder (complete,
    interrupted, or left by a killed launcher) from what was recorded; an unfinished bus.mcap is
    finished in place first. The summary's ``missing`` lists the files the run did not leave and
    ``rebuilt`` is true."""
    from scenenav.app.nodes import load_world_for
    from scenenav.app.recorder import mcap_is_complete, recover_mcap
    from scenenav.app.scenario import load_scenario
    run_dir = Path(run_dir)
    if not (run_dir / "scenario.yaml").is_file():
        raise UserError(f"{run_dir}: no scenario.yaml; expected a run folder written by "
                        "`scenenav run` or `scenenav sitl`")
    cfg = load_scenario(run_dir / "scenario.yaml")
    world = load_world_for(cfg)
    (run_dir / ".disk_reserve").unlink(missing_ok=True)   # left by a killed launcher
    notes = []
    mcap_path = run_dir / "bus.mcap"
    if mcap_path.is_file() and not mcap_is_complete(mcap_path):
        kept = recover_mcap(mcap_path)
        notes.append(f"bus.mcap had no footer: finished in place ({kept} messages kept)")
    missing = [f"{name} ({what})" for name, what in RUN_FILES.items() if not (run_dir / name).is_file()]
    sim_stats = _read_json(run_dir / "sim_stats.json")
    summary = evaluate_run(run_dir, cfg, world, wall_time_s=sim_stats.get("wall_time_s"))
    summary.update({"rebuilt": True, "missing": missing, "notes": notes})
    write_atomic(run_dir / "summary.json", json.dumps(summary, indent=2))
    return summary


def _read_json(path: Path) -> dict:
    """A JSON object file, {} when missing or unreadable (a crashed writer may leave it torn)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _routes(run_dir: Path) -> list[RouteFile]:
    """The guidance node's route files (route.json, route-1.json, ...) in order."""
    files = sorted(Path(run_dir).glob("route*.json"),
                   key=lambda p: int(p.stem.split("-")[1]) if "-" in p.stem else 0)
    out = []
    for f in files:
        try:
            out.append(read_route_file(f))
        except UserError:
            log.warning("unreadable route file %s", f)
    return out


def _guidance_metrics(run_dir: Path) -> dict[str, Any]:
    routes = _routes(run_dir)
    if not routes:
        return {}
    return {"route_length_m": routes[0].length_m,
            "route_min_clearance_m": routes[0].min_clearance_m,
            "replans": len(routes) - 1}


def _end_position(cfg, truth: dict, status: dict) -> dict[str, Any]:
    """Where the vehicle ended (true position) and, for a guided flight, how far from the last
    goal; whether it was on the ground at the end (the autopilot's last status)."""
    if not truth or len(truth.get("x_m", [])) == 0:
        return {}
    end = (float(truth["x_m"][-1]), float(truth["y_m"][-1]))
    out: dict[str, Any] = {"end_position_enu_m": [round(end[0], 2), round(end[1], 2)],
                           "landed": bool(status["landed"][-1] > 0.5)
                           if status and len(status.get("t_s", [])) else None}
    if cfg.guidance.enabled and cfg.guidance.goals_enu_m:
        goal = cfg.guidance.goals_enu_m[-1]
        out["goal_enu_m"] = [float(goal[0]), float(goal[1])]
        out["end_distance_to_goal_m"] = round(math.hypot(end[0] - goal[0], end[1] - goal[1]), 2)
    return out


def mission_succeeded(completed: bool, end_distance_to_goal_m: float | None, tolerance_m: float) -> bool:
    """Whether a mission succeeded: it was completed and, when it had goals (a guided flight), the
    vehicle ended within ``tolerance_m`` of the last one. A GPS-denied mission flown on a false lock
    completes its route where the estimate says, possibly hundreds of metres from where it was sent:
    completed, not succeeded."""
    if not completed:
        return False
    return end_distance_to_goal_m is None or end_distance_to_goal_m <= tolerance_m


def _distance(truth: dict) -> float:
    if not truth or len(truth.get("x_m", [])) < 2:
        return 0.0
    return float(np.sum(np.hypot(np.diff(truth["x_m"]), np.diff(truth["y_m"]))))


def hillshade(heights_m: np.ndarray, m_per_px: float, azimuth_deg: float = 315.0,
              altitude_deg: float = 45.0) -> np.ndarray:
    """Shaded relief of a height map in [0, 1] (sun from ``azimuth_deg`` clockwise from north,
    ``altitude_deg`` above the horizon; the usual cartographic 315 / 45, e.g. GDAL gdaldem)."""
    dz_dv, dz_du = np.gradient(np.asarray(heights_m, dtype=np.float64), m_per_px)
    dz_de, dz_dn = dz_du, -dz_dv                       # u east, v south
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    sun = (math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt))   # (e, n, up)
    # the unit normal (-dz/de, -dz/dn, 1) / |.| against the sun direction
    shade = (-dz_de * sun[0] - dz_dn * sun[1] + sun[2]) / np.sqrt(1.0 + dz_de ** 2 + dz_dn ** 2)
    return np.clip(shade, 0.0, 1.0)


def plot_run(run_dir: Path, world, fx: dict, split: HeightSplit | None = None,
             plot_dsm: bool = True) -> None:
    """trajectory.png: the trajectory over the orthophoto (and the DSM's hillshade and height
    contours when the world has one and ``plot_dsm``), the errors over time, and the errors by
    mean footprint height (``split``) as a small bar plot."""
    # matplotlib's object API without pyplot (whose import alone costs ~0.7 s of every run's end)
    from matplotlib.figure import Figure

    truth = read_csv(run_dir / "truth.csv")
    est = read_csv(run_dir / "estimates.csv")
    m = world.manifest
    half_w, half_h = m.width_px * m.m_per_px / 2, m.height_px * m.m_per_px / 2
    with_split = split is not None and split.overall.n > 0
    ratios = [1.1, 1, 0.55] if with_split else [1.1, 1]
    fig = Figure(figsize=(15 + (5 if with_split else 0), 7))
    axes = fig.subplots(1, len(ratios), gridspec_kw={"width_ratios": ratios})
    ax = axes[0]
    # the map panel is about 600 px wide at dpi 90: a finer image costs drawing time, shows nothing
    step = max(1, -(-max(m.width_px, m.height_px) // 700))
    extent = (-half_w, half_w, -half_h, half_h)
    ax.imshow(world.orthophoto[::step, ::step], extent=extent, origin="upper", alpha=0.8)
    if plot_dsm and world.dsm_m is not None:
        dsm = world.dsm_m[::step, ::step]
        ax.imshow(hillshade(dsm, m.m_per_px * step), extent=extent, origin="upper", cmap="gray",
                  alpha=0.45, vmin=0.0, vmax=1.0)
        top = float(dsm.max())
        if top > 0.0:
            ys = np.linspace(half_h, -half_h, dsm.shape[0])
            xs = np.linspace(-half_w, half_w, dsm.shape[1])
            levels = [lv for lv in (6.0, 12.0, 20.0, 30.0) if lv < top]
            if levels:
                # one legend entry per level instead of labels on the lines (clabel costs ~0.3 s)
                cs = ax.contour(xs, ys, dsm, levels=levels, linewidths=0.4, cmap="viridis", alpha=0.8)
                for lv, color in zip(levels, cs.get_edgecolor(), strict=False):
                    ax.plot([], [], c=color, lw=1, label=f"height {lv:g} m")
    for i, route in enumerate(_routes(run_dir)):
        xy = np.array(route.waypoints_xy_m)
        if len(xy):
            ax.plot(xy[:, 0], xy[:, 1], "--", c="magenta" if i == 0 else "purple", lw=1.2,
                    label="planned route" if i == 0 else ("replanned route" if i == 1 else None))
    if truth:
        ax.plot(truth["x_m"], truth["y_m"], "k-", lw=1.5, label="truth")
    if est and len(est.get("t_s", [])):
        ax.plot(est["x_m"], est["y_m"], "b-", lw=1, label="autopilot estimate")
    if fx:
        valid = fx["valid"] > 0.5
        acc = valid & (fx["accepted"] > 0.5)
        rej = valid & ~acc
        false = fx["is_false"].astype(bool)
        ax.scatter(fx["x_m"][acc], fx["y_m"][acc], s=8, c="lime", label="accepted fix")
        ax.scatter(fx["x_m"][rej], fx["y_m"][rej], s=14, c="red", marker="x", label="rejected fix")
        ax.scatter(fx["x_m"][false], fx["y_m"][false], s=40, facecolors="none", edgecolors="orange",
                   label="false fix (> threshold)")
    ax.set_xlim(-half_w, half_w)
    ax.set_ylim(-half_h, half_h)
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(f"{m.name}: trajectory")
    if ax.get_legend_handles_labels()[0]:     # a run stopped at once has nothing to label
        ax.legend(loc="upper right", fontsize=7)
    ax2 = axes[1]
    if fx:
        ax2.plot(fx["t_s"], fx["error_m"], ".", ms=3, c="gray", label="fix error (all valid)")
        acc = (fx["valid"] > 0.5) & (fx["accepted"] > 0.5)
        ax2.plot(fx["t_s"][acc], fx["error_m"][acc], ".", ms=4, c="green", label="accepted")
    if est and truth and len(est.get("t_s", [])):
        tx, ty = _interp_truth(truth, est["t_s"])
        ax2.plot(est["t_s"], np.hypot(est["x_m"] - tx, est["y_m"] - ty), "b-", lw=1,
                 label="estimate error")
    ax2.axhline(fx_threshold(run_dir), color="orange", ls="--", lw=1, label="false-fix threshold")
    ax2.set_ylim(bottom=0)
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("horizontal error (m)")
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=7)
    if with_split:
        _plot_height_bars(axes[2], split)
    # fixed margins: tight_layout measures every text first (~0.25 s)
    fig.subplots_adjust(left=0.05, right=0.985, bottom=0.13, top=0.94, wspace=0.2)
    # zlib level 1: faster encoding than the default level 6, for a somewhat larger file
    fig.savefig(run_dir / "trajectory.png", dpi=90, pil_kwargs={"compress_level": 1})


def _plot_height_bars(ax, split: HeightSplit) -> None:
    """Median error and share of false fixes per mean-footprint-height bin."""
    labels = [b.bin.label for b in split.bins]
    med = [b.stats.median_m or 0.0 for b in split.bins]
    false = [100.0 * (b.stats.share_over_threshold or 0.0) for b in split.bins]
    x = np.arange(len(labels))
    ax.bar(x - 0.2, med, 0.4, color="steelblue", label="median error (m)")
    ax.bar(x + 0.2, false, 0.4, color="orange", label=f"over {split.threshold_m:g} m (%)")
    for i, b in enumerate(split.bins):
        ax.text(x[i], max(med[i], false[i]), f"n={b.stats.n}", ha="center", va="bottom", fontsize=6)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=30, fontsize=7)
    ax.set_xlabel("mean building height in the footprint")
    ax.set_title("fix errors by height", fontsize=9)
    ax.legend(fontsize=7)


def fx_threshold(run_dir: Path) -> float:
    try:
        return float(json.loads((Path(run_dir) / "summary.json").read_text())["false_fix_threshold_m"])
    except (OSError, KeyError, ValueError):
        return 5.0


def format_summary(summary: dict) -> str:
    keys = ["scenario", "world", "flight_mode", "perception_method", "sim_time_s", "wall_time_s",
            "real_time_factor", "distance_flown_m", "fixes_total", "fixes_accepted", "false_fixes",
            "false_fixes_rejected", "true_fixes_rejected", "fix_rms_error_accepted_m",
            "fix_time_ms_median", "rms_error_m", "max_error_m", "rms_error_airborne_m",
            "max_error_airborne_m", "mission_completed", "mission_succeeded", "gps_used",
            "end_reason", "recording_ended_early"]
    lines = ["summary:"]
    for k in keys:
        v = summary.get(k)
        if isinstance(v, float):
            v = f"{v:.3f}"
        lines.append(f"  {k:26s} {v}")
    nodes = summary.get("perception_nodes") or []
    if len(nodes) > 1:
        lines.append(f"  {'':26s} (fix figures pooled over {len(nodes)} perception nodes; per node:)")
    for n in nodes:
        rms = n["fix_rms_error_accepted_m"]
        lines.append(f"  perception node {n['node_id']} ({n['method']}): {n['fixes_total']} fixes, "
                     f"{n['fixes_accepted']} accepted, {n['false_fixes']} false, RMS "
                     f"{'—' if rms is None else f'{rms:.2f} m'} over accepted, live "
                     f"{n['first_fix_s']:.1f}-{n['last_fix_s']:.1f} s")
    if summary.get("failed_nodes"):
        lines.append(f"  failed_nodes               {summary['failed_nodes']}")
    split = summary.get("fix_errors_by_height") or {}
    for b in split.get("bins") or ():
        if b["n"]:
            med = "—" if b["median_m"] is None else f"{b['median_m']:.2f} m"
            lines.append(f"  fixes over {b['label']:10s}      n={b['n']} median {med}, "
                         f"{100.0 * b['share_over_threshold']:.1f} % over {split['threshold_m']:g} m")
    for f in summary.get("node_failures") or ():
        lines.append(f"  node failure               {f['what']}")
    for r in summary.get("node_restarts") or ():
        lines.append(f"  node restart               {r['what']}")
    for e in summary.get("external_nodes_left") or ():
        lines.append(f"  external node left         {e['what']}")
    for m in summary.get("missing") or ():
        lines.append(f"  missing                    {m}")
    for n in summary.get("notes") or ():
        lines.append(f"  note                       {n}")
    return "\n".join(lines)


def _m(v: float | None) -> str:
    return "—" if v is None else f"{v:.1f} m"


def plain_summary(summary: dict, run_dir: Path | None = None) -> str:
    """What happened, in a few plain sentences (printed at the end of every ``scenenav run``)."""
    flew = f"The vehicle flew {summary.get('distance_flown_m', 0.0) / 1000:.2f} km in " \
           f"{summary.get('sim_time_s', 0.0):.0f} s of simulated time"
    wall = summary.get("wall_time_s")
    flew += f" ({wall:.0f} s of wall time)" if wall is not None else ""
    flew += ", with GPS." if summary.get("gps_used") else ", without GPS."
    lines = [flew]
    nodes = summary.get("perception_nodes") or []
    if summary.get("fixes_total"):
        who = ", ".join(f"{n['node_id']} ({n['method']})" for n in nodes) or "perception"
        acc = summary.get("fixes_accepted", 0)
        lines.append(f"Scene matching ({who}) gave {summary['fixes_total']} fixes; {acc} were "
                     f"accepted and {summary.get('false_fixes', 0)} were false (over "
                     f"{summary.get('false_fix_threshold_m', 5.0):g} m from the truth), "
                     f"{summary.get('false_fixes_rejected', 0)} of them rejected; the accepted fixes' "
                     f"error RMS is {_m(summary.get('fix_rms_error_accepted_m'))}.")
        if summary.get("fixes_with_heading"):
            lines.append(f"{summary['fixes_with_heading']} fixes carried the heading the map measured, "
                         f"{summary['fix_heading_rms_error_deg']:.2f} deg RMS off the truth.")
    if summary.get("rms_error_m") is not None:
        air = summary.get("rms_error_airborne_m")
        lines.append(f"The autopilot's position estimate was off by {_m(summary['rms_error_m'])} RMS "
                     f"and {_m(summary.get('max_error_m'))} at worst"
                     + (f" ({_m(air)} RMS in the air)." if air is not None else "."))
    if summary.get("route_length_m") is not None:
        replans = summary.get("replans", 0)
        lines.append(f"Guidance planned a {summary['route_length_m']:.0f} m route around the bad "
                     f"matching areas (clearance {_m(summary.get('route_min_clearance_m'))}"
                     f"{f', {replans} replans' if replans else ''}).")
    end = summary.get("end_position_enu_m")
    if end is not None:
        where = f"({end[0]:.0f}, {end[1]:.0f}) m east/north"
        state = "landed" if summary.get("landed") else "ended"
        text = f"It {state} at {where}"
        if summary.get("end_distance_to_goal_m") is not None:
            g = summary["goal_enu_m"]
            text += f", {summary['end_distance_to_goal_m']:.1f} m from the goal ({g[0]:.0f}, {g[1]:.0f})"
        if not summary.get("mission_completed"):
            mission = f"the run ended: {summary.get('end_reason')}"
        elif summary.get("mission_succeeded", True):
            mission = "the mission was completed"
        else:
            mission = (f"the mission was completed but did not succeed: it ended over "
                       f"{summary.get('goal_tolerance_m', 0.0):g} m from its last goal")
        lines.append(f"{text}; {mission}.")
    if run_dir is not None:
        pics = [p for p in ("trajectory.png",) if (Path(run_dir) / p).is_file()]
        files = [str(Path(run_dir) / p) for p in pics]
        lines.append("Pictures: " + (", ".join(files) if files else "none") +
                     f"; everything recorded: {Path(run_dir) / 'bus.mcap'} (Foxglove or "
                     "Lichtblick, layout docs/foxglove-layout.json or docs/lichtblick-layout.json).")
    return "\n".join(lines)
