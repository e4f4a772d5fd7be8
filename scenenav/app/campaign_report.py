"""A campaign's results: ``results.parquet`` and ``results.csv`` (one row per run) and ``report.md``.

Read only from files (``plan.json``, each ``runs/<id>/campaign_run.json`` and ``summary.json``), so
they are rewritten at the end of every invocation, interrupted or not, and always describe every
planned run (``run_status`` pending for one not flown yet). Columns: ``run_id``, ``override.<key>``
for every override of the run (the campaign's ``set`` and the run's point), ``run_<field>`` from the
task's record (status, exit status, attempts, host, worker, wall and CPU time, MAVLink port, log
tail), every figure of ``summary.json``, and per-run figures derived from the run folder:
``est_error_{median,p95}_m`` (autopilot estimate vs truth), ``fix_error_{median,p95}_m`` (accepted
fixes vs truth), ``fix_recall`` / ``fix_precision`` (of the false-fix rejection).

report.md groups the completed runs by the campaign's ``group_by`` columns and gives, per group, the
median / 95th percentile / max of the estimate error and of the accepted-fix error (all samples of
the group's runs pooled), the median fix RMS over runs, the pooled recall and precision, the
share of missions completed and the mission success rate (completed and ended within the scenario's
``evaluation.goal_tolerance_m`` of the last goal: a mission flown on a false lock completes its
route far from where it was sent), each with a 95 % bootstrap interval that resamples whole runs (samples within
a flight are correlated; the run is the independent unit). Plots: error CDFs per perception method,
success rate per group (PNG beside report.md).
"""

from __future__ import annotations

import csv
import json
import logging
import math
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from scenenav.app.campaign_spec import OVERRIDE_PREFIX, CampaignSpec, PlannedRun
from scenenav.core.formats.atomic_file import replace_atomic, write_atomic

log = logging.getLogger(__name__)

RECORD_FIELDS = ("status", "exit_status", "attempts", "host", "worker", "wall_s", "cpu_s",
                 "mavlink_tcp_port", "log_tail")
BOOTSTRAP_RESAMPLES = 1000
BOOTSTRAP_SEED = 0
CONFIDENCE = 0.95
#: Samples kept per run for the pooled statistics (evenly decimated; a 10-minute flight logs ~30 000
#: estimates, which would make the bootstrap slow without changing its percentiles noticeably).
MAX_SAMPLES_PER_RUN = 2000
PLOTS = ("error_cdf.png", "success_rate.png")


@dataclass(frozen=True)
class RunData:
    """What the report needs of one completed run."""

    row: dict
    est_errors_m: np.ndarray
    fix_errors_m: np.ndarray


def _parse_override(text: str) -> tuple[str, Any]:
    import yaml
    key, value = text.split("=", 1)
    return key, yaml.safe_load(value)


def _decimate(x: np.ndarray) -> np.ndarray:
    x = x[np.isfinite(x)]
    if len(x) <= MAX_SAMPLES_PER_RUN:
        return x
    return x[np.linspace(0, len(x) - 1, MAX_SAMPLES_PER_RUN).astype(int)]


def _ratio(num: float, den: float) -> float | None:
    return float(num) / float(den) if den else None


def _run_figures(run_dir: Path, summary: dict) -> tuple[dict, np.ndarray, np.ndarray]:
    from scenenav.app.evaluation import estimate_errors, fix_table
    est = estimate_errors(run_dir)
    fx = fix_table(run_dir, float(summary.get("false_fix_threshold_m") or 5.0))
    fix_err = np.zeros(0)
    if fx:
        acc = (fx["valid"] > 0.5) & (fx["accepted"] > 0.5)
        fix_err = fx["error_m"][acc]
    fr = summary.get("false_fixes_rejected") or 0
    figures = {
        "est_error_median_m": float(np.median(est)) if len(est) else None,
        "est_error_p95_m": float(np.percentile(est, 95)) if len(est) else None,
        "fix_error_median_m": float(np.median(fix_err)) if len(fix_err) else None,
        "fix_error_p95_m": float(np.percentile(fix_err, 95)) if len(fix_err) else None,
        "fix_recall": _ratio(fr, summary.get("false_fixes") or 0),
        "fix_precision": _ratio(fr, fr + (summary.get("true_fixes_rejected") or 0)),
    }
    return figures, _decimate(est), _decimate(fix_err)


def collect(out: Path, runs: list[PlannedRun]) -> list[RunData]:
    """One RunData per planned run, in plan order (a pending run has only its id and overrides)."""
    from scenenav.app.campaign_run import read_record
    data = []
    for r in runs:
        run_dir = out / "runs" / r.run_id
        row: dict[str, Any] = {"run_id": r.run_id, "run_index": r.index}
        for key, value in (_parse_override(o) for o in r.overrides):
            row[OVERRIDE_PREFIX + key] = value
        for key, value in r.point:       # labelled grid axes (their bundles are above)
            row.setdefault(OVERRIDE_PREFIX + key, value)
        rec = read_record(run_dir) or {"status": "pending"}
        for f in RECORD_FIELDS:
            row["run_" + f] = rec.get(f)
        row["run_dir"] = str(run_dir) if rec["status"] != "pending" else None
        est = fix = np.zeros(0)
        summary_file = run_dir / "summary.json"
        if rec["status"] == "ok" and summary_file.is_file():
            try:
                summary = json.loads(summary_file.read_text())
            except ValueError:
                summary = {}
            for k, v in summary.items():
                row.setdefault(k, v)
            figures, est, fix = _run_figures(run_dir, summary)
            row.update(figures)
        data.append(RunData(row, est, fix))
    return data


def _column_values(rows: list[dict], col: str) -> list[Any]:
    vals = [r.get(col) for r in rows]
    vals = [None if isinstance(v, float) and not math.isfinite(v) else v for v in vals]
    kinds = {type(v) for v in vals if v is not None}
    if kinds <= {int, float} or kinds in ({bool}, {str}):
        return vals
    # mixed types, lists or mappings: one JSON text per cell, so that every column has one type
    return [None if v is None else (v if isinstance(v, str) else json.dumps(v)) for v in vals]


def _columns(rows: list[dict]) -> list[str]:
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    tail = [c for c in ("run_log_tail", "run_dir") if c in cols]
    return [c for c in cols if c not in tail] + tail


def write_tables(out: Path, rows: list[dict]) -> None:
    """results.parquet and results.csv (each replaced atomically: readable after any stop)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    cols = _columns(rows)
    table = pa.table({c: pa.array(_column_values(rows, c)) for c in cols})
    replace_atomic(out / "results.parquet", lambda p: pq.write_table(table, p))

    def write_csv(p: Path) -> None:
        values = {c: _column_values(rows, c) for c in cols}
        with p.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(cols)
            for i in range(len(rows)):
                w.writerow(["" if values[c][i] is None else values[c][i] for c in cols])
    replace_atomic(out / "results.csv", write_csv)


# ------------------------------------------------------------------------------------------- report

def bootstrap(runs: list[RunData], stat: Callable[[list[RunData]], float | None],
              rng: np.random.Generator) -> tuple[float | None, float | None, float | None]:
    """``stat`` of the runs and its 95 % percentile interval over resamples of whole runs."""
    value = stat(runs)
    if value is None or len(runs) < 2:
        return value, None, None
    draws = []
    for _ in range(BOOTSTRAP_RESAMPLES):
        idx = rng.integers(len(runs), size=len(runs))
        v = stat([runs[i] for i in idx])
        if v is not None:
            draws.append(v)
    if not draws:
        return value, None, None
    a = (1.0 - CONFIDENCE) / 2.0
    return value, float(np.quantile(draws, a)), float(np.quantile(draws, 1.0 - a))


def _pooled(attr: str, fn: Callable[[np.ndarray], float]) -> Callable[[list[RunData]], float | None]:
    def stat(runs: list[RunData]) -> float | None:
        x = np.concatenate([getattr(r, attr) for r in runs]) if runs else np.zeros(0)
        return float(fn(x)) if len(x) else None
    return stat


def _median_of(col: str) -> Callable[[list[RunData]], float | None]:
    def stat(runs: list[RunData]) -> float | None:
        v = [r.row.get(col) for r in runs if r.row.get(col) is not None]
        return float(np.median(v)) if v else None
    return stat


def _pooled_ratio(num: str, extra: str | None, den: str | None) -> Callable[[list[RunData]], float | None]:
    def stat(runs: list[RunData]) -> float | None:
        n = sum(r.row.get(num) or 0 for r in runs)
        d = sum(r.row.get(den) or 0 for r in runs) if den else n + sum(r.row.get(extra) or 0 for r in runs)
        return n / d if d else None
    return stat


def _completed(runs: list[RunData]) -> float | None:
    return float(np.mean([bool(r.row.get("mission_completed")) for r in runs])) if runs else None


def _succeeded(row: dict) -> bool:
    """A run's ``mission_succeeded`` (completed and ended within ``goal_tolerance_m`` of its last
    goal, scenenav.app.evaluation.mission_succeeded); a summary written before that figure existed
    counts as its ``mission_completed``."""
    value = row.get("mission_succeeded")
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return bool(row.get("mission_completed"))
    return bool(value)


def _success(runs: list[RunData]) -> float | None:
    return float(np.mean([_succeeded(r.row) for r in runs])) if runs else None


METRICS: tuple[tuple[str, Callable[[list[RunData]], float | None], str], ...] = (
    ("estimate error median (m)", _pooled("est_errors_m", np.median), "{:.2f}"),
    ("estimate error p95 (m)", _pooled("est_errors_m", lambda x: np.percentile(x, 95)), "{:.2f}"),
    ("estimate error max (m)", _pooled("est_errors_m", np.max), "{:.2f}"),
    ("accepted-fix error median (m)", _pooled("fix_errors_m", np.median), "{:.2f}"),
    ("accepted-fix error p95 (m)", _pooled("fix_errors_m", lambda x: np.percentile(x, 95)), "{:.2f}"),
    ("accepted-fix error max (m)", _pooled("fix_errors_m", np.max), "{:.1f}"),
    ("fix RMS, median over runs (m)", _median_of("fix_rms_error_accepted_m"), "{:.2f}"),
    ("recall of false fixes", _pooled_ratio("false_fixes_rejected", None, "false_fixes"), "{:.3f}"),
    ("precision of rejections", _pooled_ratio("false_fixes_rejected", "true_fixes_rejected", None), "{:.3f}"),
    ("missions completed", _completed, "{:.2f}"),
    ("mission success rate", _success, "{:.2f}"),
)


def _group_label(row: dict, group_by: tuple[str, ...]) -> str:
    if not group_by:
        return "all runs"
    return ", ".join(f"{g}={_short(row.get(OVERRIDE_PREFIX + g))}" for g in group_by)


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return v if isinstance(v, str) else json.dumps(v)


def _fmt(value: float | None, lo: float | None, hi: float | None, fmt: str) -> str:
    if value is None:
        return "—"
    text = fmt.format(value)
    if lo is not None and hi is not None:
        text += f" [{fmt.format(lo)}, {fmt.format(hi)}]"
    return text


def group_table(data: list[RunData], group_by: tuple[str, ...]) -> list[dict]:
    """Per group: runs, failed, and every metric as (value, low, high)."""
    groups: dict[str, list[RunData]] = {}
    for d in data:
        groups.setdefault(_group_label(d.row, group_by), []).append(d)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    out = []
    for label, members in groups.items():
        ok = [d for d in members if d.row.get("run_status") == "ok"]
        entry: dict[str, Any] = {"group": label, "runs": len(members), "ok": len(ok),
                                 "failed": sum(d.row.get("run_status") in ("failed", "timeout") for d in members),
                                 "pending": sum(d.row.get("run_status") == "pending" for d in members)}
        for name, stat, _fmt_s in METRICS:
            entry[name] = bootstrap(ok, stat, rng)
        out.append(entry)
    return out


def _plot(out: Path, data: list[RunData], groups: list[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ok = [d for d in data if d.row.get("run_status") == "ok"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, attr, title in ((axes[0], "fix_errors_m", "accepted scene-matching fixes"),
                            (axes[1], "est_errors_m", "autopilot estimate (runs with an autopilot)")):
        by_method: dict[str, list[np.ndarray]] = {}
        for d in ok:
            by_method.setdefault(str(d.row.get("perception_method")), []).append(getattr(d, attr))
        drawn = False
        for method, arrays in sorted(by_method.items()):
            x = np.sort(np.concatenate(arrays))
            if len(x):
                ax.plot(np.maximum(x, 1e-3), np.arange(1, len(x) + 1) / len(x), label=f"{method} ({len(arrays)} runs)")
                drawn = True
        ax.set_title(f"error CDF: {title}")
        ax.set_xlabel("horizontal error (m)")
        ax.set_ylabel("fraction of samples")
        if drawn:
            ax.set_xscale("log")
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no samples in this campaign", ha="center", transform=ax.transAxes)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "error_cdf.png", dpi=80)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(max(6, 0.9 * len(groups) + 2), 4.5))
    key = "mission success rate"
    vals = [g[key][0] if g[key][0] is not None else 0.0 for g in groups]
    err = [[(v - g[key][1]) if g[key][1] is not None else 0 for v, g in zip(vals, groups, strict=True)],
           [(g[key][2] - v) if g[key][2] is not None else 0 for v, g in zip(vals, groups, strict=True)]]
    ax.bar(range(len(groups)), vals, yerr=err, capsize=4, color="tab:blue")
    ax.set_xticks(range(len(groups)), [g["group"] for g in groups], rotation=30, ha="right", fontsize=7)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("mission success rate (95 % bootstrap CI)")
    ax.set_title("mission success per group")
    fig.tight_layout()
    fig.savefig(out / "success_rate.png", dpi=80)
    plt.close(fig)


def report_markdown(spec: CampaignSpec, data: list[RunData], groups: list[dict], command: str,
                    full_count: int | None = None) -> str:
    status: dict[str, int] = {}
    for d in data:
        status[str(d.row.get("run_status"))] = status.get(str(d.row.get("run_status")), 0) + 1
    lines = [f"# Campaign `{spec.name}`", ""]
    if spec.description:
        lines += [spec.description.strip(), ""]
    if full_count is not None and full_count > len(data):
        lines += [f"**Reduced campaign: {len(data)} of the campaign file's {full_count} runs** (the same run "
                  "ids as the full campaign's; the full command flies the rest and keeps these).", ""]
    lines += [f"Runs: {len(data)} planned — " + ", ".join(f"{n} {s}" for s, n in sorted(status.items())) + ".",
              f"Grouped by: {', '.join(spec.group_by) or '(one group)'}. "
              f"Intervals: {CONFIDENCE:.0%} bootstrap over whole runs ({BOOTSTRAP_RESAMPLES} resamples, "
              "seed 0); — where a figure has no samples. Errors are horizontal; the estimate error is "
              "the autopilot's (runs with an autopilot only), the accepted-fix error is over the fixes "
              "perception accepted. Recall: false fixes rejected / false fixes; precision: rejected fixes "
              "that were false / rejected fixes.", ""]
    names = [m[0] for m in METRICS]
    lines += ["| group | runs ok / planned | failed | " + " | ".join(names) + " |",
              "|---|---|---|" + "---|" * len(names)]
    for g in groups:
        cells = [_fmt(*g[name], fmt) for name, _s, fmt in METRICS]
        lines.append(f"| {g['group']} | {g['ok']} / {g['runs']} | {g['failed']} | " + " | ".join(cells) + " |")
    lines += ["", "![error CDFs per method](error_cdf.png)", "", "![success rate per group](success_rate.png)", ""]
    failed = [d for d in data if d.row.get("run_status") in ("failed", "timeout")]
    if failed:
        lines += ["## Failed runs", ""]
        for d in failed:
            tail = (d.row.get("run_log_tail") or "").strip().splitlines()[-3:]
            lines.append(f"- `{d.row['run_id']}` ({d.row.get('run_status')}, exit status "
                         f"{d.row.get('run_exit_status')}, {d.row.get('run_attempts')} attempts): "
                         + " / ".join(f"`{t.strip()}`" for t in tail))
        lines.append("")
    walls = [d.row["run_wall_s"] for d in data if d.row.get("run_status") == "ok" and d.row.get("run_wall_s")]
    if walls:
        lines += [f"Flight wall time: median {np.median(walls):.0f} s, total {np.sum(walls) / 3600:.2f} flight-hours "
                  f"on {len({d.row.get('run_host') for d in data if d.row.get('run_host')})} host(s).", ""]
    lines += ["One row per run in `results.parquet` / `results.csv`; each run's folder is `runs/<id>/`.",
              f"Generated by `{command}`.", ""]
    return "\n".join(lines)


def write_outputs(out: Path, spec: CampaignSpec, runs: list[PlannedRun], report_dir: str | None = None,
                  command: str | None = None, full_count: int | None = None) -> None:
    """Tables first (they must survive anything), then the report and its plots."""
    data = collect(out, runs)
    write_tables(out, [d.row for d in data])
    groups = group_table(data, spec.group_by)
    try:
        _plot(out, data, groups)
    except Exception:   # a plot must never lose the table or the report
        log.exception("could not draw the campaign plots")
    cmd = command or f"scenenav campaign {spec.path.name} --out {out.name}"
    md = report_markdown(spec, data, groups, cmd, full_count)
    write_atomic(out / "report.md", md)
    if report_dir:
        dest = Path(report_dir)
        dest.mkdir(parents=True, exist_ok=True)
        for name in PLOTS:
            if (out / name).is_file():
                shutil.copy(out / name, dest / name)
        (dest / "report.md").write_text(md, encoding="utf-8")
