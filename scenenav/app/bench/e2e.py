"""``scenenav bench e2e``: the whole stack in lockstep through the real launcher, and where the time goes.

The flight is a fixed short GPS-denied mission: ``scenarios/gps_denied.yaml`` (GPS off, the autopilot
navigates on the perception node's fixes with the online CNN and the combined decision rule, the
guidance node plans around the bad areas of the world's assistant map and uploads the mission over
MAVLink, landing at the end) cut to one leg out and back (home -> (-150, 185) m -> home at 100 m, about 480 m). Every
node runs as its own process, started by ``scenenav.app.launcher.run`` exactly as ``scenenav run``
starts it: simulator, autopilot, perception, guidance, recorder.

Figures:

* real-time factor: simulated seconds over the wall seconds of the simulator's loop (its
  ``sim_stats.json``; start-up, CNN loading and shutdown are not in it, they are ``run_wall_time_s``);
* CPU seconds per simulated second of each process (utime + stime from ``/proc/<pid>/stat``,
  sampled every ``sample_period_s`` and interpolated to the simulator loop's start and end; the
  simulator's forked render worker is listed apart as ``sim/render_worker``, ``launcher`` is this
  process, sampling included);
* per control tick, the simulator's wall time: physics, render wait, publishing, waiting on the
  bus (lockstep answers), the rest of its loop; then what the members measured inside that wait:
  each member's mean answer time (publish -> ack, round trip plus its work, from the lockstep
  barrier), the autopilot's flight-core step (EKF, mode logic, control, mixer), and the perception
  node's per-frame stages (alignment, NCC matching, CNN, map lookup; from ``fixes.csv``).

Speed targets live here, never in tests (issue 13: full loop 2.1-2.4x before, target >= 6x).
"""

from __future__ import annotations

import argparse
import bisect
import csv
import json
import logging
import math
import os
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from scenenav.app.json_output import emit_json
from scenenav.core.bus import free_port
from scenenav.core.config import check
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

GPS_DENIED = Path(__file__).resolve().parents[3] / "scenarios" / "gps_denied.yaml"
#: The mission: ``scenarios/gps_denied.yaml`` with its four goals cut to the first one and home.
GOALS_ENU_M = ((-150.0, 185.0), (0.0, 0.0))
BENCH_SEED = 2                      # the seed of scenarios/gps_denied.yaml
CLK_TCK = os.sysconf("SC_CLK_TCK")
RENDER_WORKER = "render_worker"
#: Issue 13, measured before: scenarios/gps_denied.yaml, full loop with the online CNN.
BEFORE_RTF = "2.1-2.4x"
TARGET_RTF = 6.0


@dataclass(frozen=True)
class E2eBenchConfig:
    """Bench settings; ``duration_s`` caps the simulated time (the mission ends the run first)."""

    seed: int = BENCH_SEED
    duration_s: float = 400.0
    sample_period_s: float = 0.2

    def __post_init__(self) -> None:
        check(isinstance(self.seed, int) and self.seed >= 0, "seed", self.seed, "an integer >= 0")
        check(math.isfinite(self.duration_s) and 1.0 <= self.duration_s <= 3600.0, "duration_s",
              self.duration_s, "1 .. 3600 simulated s")
        check(0.05 <= self.sample_period_s <= 5.0, "sample_period_s", self.sample_period_s,
              "0.05 .. 5 s")


def scenario(cfg: E2eBenchConfig, mavlink_tcp_port: int) -> dict:
    """The bench scenario: scenarios/gps_denied.yaml itself (its world, camera, reference, CNN and
    guidance settings) with the goals cut to the first one and home, as scenario YAML data."""
    return {
        "base": str(GPS_DENIED),
        "name": "bench_e2e",
        "seed": cfg.seed,
        "duration_s": cfg.duration_s,
        "autopilot": {"mavlink_tcp_port": mavlink_tcp_port, "mavlink_udp_out": "none"},
        "guidance": {"goals_enu_m": [list(g) for g in GOALS_ENU_M]},
    }


# ------------------------------------------------------------------ CPU time of the processes
def _read_cpu_s(pid: int) -> tuple[float, str] | None:
    """(utime + stime in s, command name) of a process, or None when it is gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            text = f.read()
    except OSError:
        return None
    close = text.rfind(")")
    name = text[text.find("(") + 1:close]
    fields = text[close + 2:].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK, name


def _children(pid: int) -> list[int]:
    """Child processes of ``pid`` (forked by any of its threads)."""
    out: list[int] = []
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tasks:
        try:
            with open(f"/proc/{pid}/task/{tid}/children", encoding="ascii") as f:
                out.extend(int(x) for x in f.read().split())
        except OSError:
            continue
    return out


class CpuSampler:
    """Samples the CPU time of the run's nodes (``logs/pids.json``), their descendants and this
    process every ``period_s`` on a thread, with the wall time (``time.time()``) of each sample."""

    def __init__(self, run_dir: Path, period_s: float) -> None:
        self.run_dir = run_dir
        self.period_s = period_s
        self.series: dict[str, list[tuple[float, float]]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="cpu-sampler", daemon=True)

    def __enter__(self) -> CpuSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def _roots(self) -> dict[str, int]:
        try:
            return {str(k): int(v) for k, v in
                    json.loads((self.run_dir / "logs" / "pids.json").read_text()).items()}
        except (OSError, ValueError):
            return {}

    def sample(self) -> None:
        now = time.time()
        found: dict[str, float] = {}
        me = _read_cpu_s(os.getpid())
        if me is not None:
            found["launcher"] = me[0]
        for name, pid in self._roots().items():
            got = _read_cpu_s(pid)
            if got is None:
                continue
            found[name] = got[0]
            stack = [(pid, name)]
            while stack:           # descendants, e.g. the simulator's render worker
                parent, label = stack.pop()
                for child in _children(parent):
                    sub = _read_cpu_s(child)
                    if sub is None:
                        continue
                    child_label = f"{name}/{RENDER_WORKER}" if name == "sim" else f"{label}/{sub[1]}"
                    found[child_label] = found.get(child_label, 0.0) + sub[0]
                    stack.append((child, child_label))
        for name, cpu in found.items():
            self.series.setdefault(name, []).append((now, cpu))

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(self.period_s)
        self.sample()

    def cpu_between(self, name: str, t0: float, t1: float) -> float:
        """CPU seconds ``name`` used between wall times t0 and t1 (linear between samples; 0
        before its first sample, its last value after its last one)."""
        s = self.series.get(name, [])
        return _at(s, t1) - _at(s, t0)


def _at(series: list[tuple[float, float]], t: float) -> float:
    if not series or t < series[0][0]:
        return 0.0
    i = bisect.bisect_right([p[0] for p in series], t)
    if i >= len(series):
        return series[-1][1]
    (ta, ca), (tb, cb) = series[i - 1], series[i]
    return ca + (cb - ca) * (t - ta) / (tb - ta) if tb > ta else cb


# ------------------------------------------------------------------ reading the run folder
def _finish_wall_time(sim_log: Path) -> float | None:
    """Wall time (epoch s) of the simulator's "simulation finished" log line (end of its loop)."""
    try:
        lines = sim_log.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        if "simulation finished" in line:
            try:
                stamp, ms = line[:23].split(",")
                return time.mktime(time.strptime(stamp, "%Y-%m-%d %H:%M:%S")) + int(ms) / 1000.0
            except ValueError:
                return None
    return None


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def _perception_stages(fixes_csv: Path) -> tuple[int, dict[str, float], dict[str, float]]:
    """(frames, mean ms per frame, sum ms) per stage of the perception node's fixes."""
    stages = ("align", "ncc", "cnn", "lookup", "total")
    sums = dict.fromkeys(stages, 0.0)
    n = 0
    try:
        with fixes_csv.open(newline="", encoding="utf-8") as f:
            for row in csv.DictReader(f):
                if row.get("node_id") != "perception":
                    continue
                n += 1
                for s in stages:
                    try:
                        v = float(row[f"time_{s}_ms"])
                    except (KeyError, ValueError):
                        continue
                    if math.isfinite(v):
                        sums[s] += v
    except OSError:
        pass
    return n, {s: sums[s] / n if n else math.nan for s in stages}, sums


# ------------------------------------------------------------------ the bench
def run_e2e_bench(cfg: E2eBenchConfig | None = None, out_dir: str | None = None,
                  progress: bool = True, overrides: tuple[str, ...] = ()) -> dict:
    """Fly the bench mission through the launcher; return the figures (see the module docstring).
    ``out_dir``: keep the bench folder there (the scenario and the run folder ``run/``); default a
    temporary folder, removed afterwards. ``overrides``: ``KEY=VALUE`` scenario overrides (as
    ``scenenav run --set``), checked before anything starts."""
    from scenenav.app.launcher import run
    from scenenav.app.scenario import load_scenario
    cfg = cfg if cfg is not None else E2eBenchConfig()
    keep = out_dir is not None
    base = Path(out_dir) if keep else Path(tempfile.mkdtemp(prefix="scenenav-bench-e2e-"))
    if keep and base.exists() and any(base.iterdir()):
        raise UserError(f"--out {base}: folder exists and is not empty (choose a new one)")
    base.mkdir(parents=True, exist_ok=True)
    run_dir = base / "run"
    scenario_path = base / "bench_e2e.yaml"
    scenario_path.write_text(yaml.safe_dump(scenario(cfg, free_port()), sort_keys=False))
    try:
        load_scenario(scenario_path, overrides)    # a bad --set: one line, before any process starts
    except UserError as exc:
        if not keep:
            shutil.rmtree(base, ignore_errors=True)
        raise UserError("bench e2e --set: " + str(exc).split("(with --set overrides): ", 1)[-1]) from None
    wall0 = time.time()
    try:
        with CpuSampler(run_dir, cfg.sample_period_s) as sampler:
            summary = run(str(scenario_path), str(run_dir), overrides=overrides, progress=progress)
        report = _report(cfg, run_dir, summary, sampler, time.time() - wall0)
    finally:
        if not keep:
            shutil.rmtree(base, ignore_errors=True)
    report["run_dir"] = str(run_dir) if keep else None
    report["overrides"] = list(overrides)
    return report


def _report(cfg: E2eBenchConfig, run_dir: Path, summary: dict, sampler: CpuSampler,
            run_wall_s: float) -> dict:
    sim = _read_json(run_dir / "sim_stats.json")
    if not sim.get("ticks"):
        raise UserError(f"bench e2e: the simulator did not run (see {run_dir / 'logs' / 'sim.log'})")
    ap = _read_json(run_dir / "autopilot_stats.json").get("node", {})
    ticks = int(sim["ticks"])
    sim_s = float(sim["sim_time_s"])
    loop_wall_s = float(sim["wall_time_s"])
    t_end = _finish_wall_time(run_dir / "logs" / "sim.log")
    if t_end is None:                                   # fall back: the last sample of the simulator
        t_end = sampler.series.get("sim", [(time.time(), 0.0)])[-1][0]
    t_start = t_end - loop_wall_s
    cpu = {name: sampler.cpu_between(name, t_start, t_end) / sim_s for name in sorted(sampler.series)}

    def per_tick_ms(seconds: float) -> float:
        return 1e3 * seconds / ticks

    parts = {"physics": per_tick_ms(sim["time_physics_s"]), "render_wait": per_tick_ms(sim["time_render_s"]),
             "publish": per_tick_ms(sim["time_publish_s"]), "bus_wait": per_tick_ms(sim["time_bus_wait_s"])}
    total = per_tick_ms(loop_wall_s)
    parts["rest_of_loop"] = total - sum(parts.values())
    parts["total"] = total
    frames, stage_mean, stage_sum = _perception_stages(run_dir / "fixes.csv")
    ap_ticks = int(ap.get("ticks", 0))
    members = {
        "answer_ms_mean": {k: round(v, 3) for k, v in sim.get("member_answer_ms_mean", {}).items()},
        "answers": sim.get("member_answers", {}),
        "autopilot_step_ms_per_tick": (1e-3 * ap["tick_work_us"] / ap_ticks) if ap_ticks else None,
        "perception_frames": frames,
        "perception_ms_per_frame": {k: round(v, 3) for k, v in stage_mean.items()},
        "perception_ms_per_tick": round(stage_sum["total"] / ticks, 3),
    }
    return {
        "bench": "e2e",
        "scenario": "gps_denied, one leg out and back (home -> (-150, 185) m -> home), online CNN",
        "seed": cfg.seed,
        "real_time_factor": round(sim_s / loop_wall_s, 3) if loop_wall_s > 0 else None,
        "real_time_factor_before": BEFORE_RTF,
        "real_time_factor_target": TARGET_RTF,
        "sim_time_s": sim_s,
        "loop_wall_time_s": round(loop_wall_s, 3),
        "run_wall_time_s": round(run_wall_s, 3),
        "end_reason": sim.get("end_reason"),
        "mission_completed": summary.get("mission_completed"),
        "rms_error_m": summary.get("rms_error_m"),
        "ticks": ticks,
        "camera_frames": sim.get("camera_frames"),
        "ack_timeouts": sim.get("ack_timeouts"),
        "cpu_s_per_sim_s": {k: round(v, 4) for k, v in cpu.items()},
        "cpu_s_per_sim_s_total": round(sum(cpu.values()), 4),
        "sim_ms_per_tick": {k: round(v, 4) for k, v in parts.items()},
        "members": members,
        "failed_nodes": summary.get("failed_nodes", []),
    }


def format_table(r: dict) -> str:
    """The figures of ``run_e2e_bench`` as text (newline-terminated)."""
    t = r["sim_ms_per_tick"]
    m = r["members"]
    lines = [f"bench e2e: {r['scenario']}, seed {r['seed']}",
             f"  real-time factor {r['real_time_factor']:.2f}x  ({r['sim_time_s']:.1f} simulated s in "
             f"{r['loop_wall_time_s']:.1f} s of the simulator loop; whole run {r['run_wall_time_s']:.1f} s; "
             f"before {r['real_time_factor_before']}, target >= {r['real_time_factor_target']:g}x)",
             f"  end: {r['end_reason']}; mission completed: {r['mission_completed']}; "
             f"{r['ticks']} ticks, {r['camera_frames']} frames, {r['ack_timeouts']} ack timeouts",
             "  CPU s per simulated s:"]
    width = max(len(k) for k in r["cpu_s_per_sim_s"]) if r["cpu_s_per_sim_s"] else 8
    for name, v in r["cpu_s_per_sim_s"].items():
        lines.append(f"    {name:<{width}}  {v:7.3f}")
    lines.append(f"    {'total':<{width}}  {r['cpu_s_per_sim_s_total']:7.3f}  (2 cores: at most 2.0 per wall s)")
    lines.append("  simulator wall ms per tick:")
    for name in ("physics", "render_wait", "publish", "bus_wait", "rest_of_loop", "total"):
        lines.append(f"    {name:<14} {t[name]:7.3f}")
    lines.append("  inside the bus wait (members):")
    for name, v in m["answer_ms_mean"].items():
        lines.append(f"    {name:<14} {v:7.3f} ms mean answer (publish -> ack)")
    if m["autopilot_step_ms_per_tick"] is not None:
        lines.append(f"    autopilot flight-core step (EKF, modes, control, mixer) "
                     f"{m['autopilot_step_ms_per_tick']:.3f} ms per tick")
    pf = m["perception_ms_per_frame"]
    lines.append(f"    perception per frame ({m['perception_frames']} frames): " + ", ".join(
        f"{k} {v:.2f} ms" for k, v in pf.items() if isinstance(v, float) and math.isfinite(v))
        + f"; {m['perception_ms_per_tick']:.3f} ms per tick")
    if r["failed_nodes"]:
        lines.append(f"  failed nodes: {', '.join(r['failed_nodes'])}")
    return "\n".join(lines) + "\n"


def _cmd_bench_e2e(args: argparse.Namespace) -> int:
    try:
        cfg = E2eBenchConfig(seed=args.seed, duration_s=args.duration_s)
    except UserError as exc:
        raise UserError(f"bench e2e: {exc}") from None
    report = run_e2e_bench(cfg, out_dir=args.out, progress=not args.quiet, overrides=tuple(args.set or ()))
    if args.json:
        emit_json(report)
    else:
        sys.stdout.write(format_table(report))
    return 0 if not report["failed_nodes"] else 1


def register_bench(bench_subparsers) -> None:
    """Add ``e2e`` to the ``scenenav bench`` sub-commands."""
    d = E2eBenchConfig()
    p = bench_subparsers.add_parser(
        "e2e", help="full GPS-denied loop (every node, lockstep, online CNN): real-time factor, CPU, "
                    "where each tick's time goes",
        description="Fly a fixed short GPS-denied mission (scenarios/gps_denied.yaml cut to one leg "
                    "out and back, about 480 m at 100 m, landing home) with every node as its own "
                    "process, in lockstep, through the same launcher as `scenenav run`: simulator, "
                    "autopilot, perception (online CNN), guidance, recorder. Prints the real-time "
                    "factor of the simulator loop, the CPU seconds per simulated second of each "
                    "process, and per control tick where the simulator's wall time goes (physics, "
                    "render wait, publishing, bus wait) with what the members measured inside the "
                    "wait (answer times, the autopilot's flight-core step, perception's alignment / "
                    "NCC / CNN / lookup). 170 simulated s: 1-3 minutes on 2 shared cores.")
    p.add_argument("--json", action="store_true", help="print only one JSON object on stdout instead of a table")
    p.add_argument("--seed", type=int, default=d.seed, help=f"scenario seed (default {d.seed})")
    p.add_argument("--duration-s", type=float, default=d.duration_s,
                   help=f"cap on the simulated seconds (default {d.duration_s:g}; the mission ends sooner)")
    p.add_argument("--out", metavar="DIR",
                   help="keep the bench scenario and the run folder here (default: a temporary folder, "
                        "removed afterwards)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a key of the bench scenario, as `scenenav run --set` (e.g. "
                        "--set clock.camera_answer_ticks=0); the JSON records the overrides")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_bench_e2e)

