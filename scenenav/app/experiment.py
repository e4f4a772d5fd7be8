"""``scenenav experiment table2``: the paper's experiment (section 6.3, Table 2), reproduced.

The same path at 100 m and 10 m/s is flown four times in lockstep (so every flight sees the
identical camera frames): online CNN (which builds an assistant map as it flies), the assistant
map built during that first flight, the statistical indicator, and no exclusion. Each flight is a
full ``scenenav run`` (simulator, autopilot, perception node, recorder) in its own run folder.

By default the autopilot flies each flight as a mission, as in the paper: it takes off at the
route's first waypoint, climbs to the flight altitude, flies the route and lands, navigating on GPS
(the logging flights of the paper had GPS), so the perception method never steers the vehicle and
the four flights are the same flight: the command checks that their truth.csv files are
byte-identical (``identical_frames`` in table2.json). Only the fixes captured within
``SURVEY_BAND_M`` of the flight altitude are scored (not the climb and the landing).
``scripted=True`` (``--scripted``) flies the kinematic path instead (no autopilot; the old table).
``realism`` selects the realism profile (docs/realism.md) of every flight; the results page keeps
one table per profile and flight kind, side by side (``update_results_page``).

Definitions (printed in table2.md):
* a fix's error is against the vehicle's true position at the capture, after undoing the reference
  misregistration the world states (scenenav/app/evaluation.py); each row's JSON also splits the
  accepted fixes' errors by the mean building height in the footprint (``errors_by_height_accepted``);
* a fix is *false* when it is valid and its horizontal error exceeds the threshold (default 5 m);
* ``rms_error_m``: RMS horizontal error over the fixes the method accepted;
* ``detected_false_pct``: fixes the method flagged false / fixes that really are false, x 100
  (the paper's "detected false matchings/overall"; over-flagging can exceed 100 %);
* ``precision`` / ``recall`` of the rejection: share of rejected fixes that really are false /
  share of really-false fixes that were rejected;
* ``fix_time_ms_median``: the perception node's per-fix time (align + NCC + CNN + lookup).

Decision rule of the cnn and assistant-map rows (column ``rule``): ``combined`` by default, i.e.
``perception.weights`` is the combined decision model of the scenario (``decision_model_for``: the
``perception.decision_model`` a realism profile or ``--set`` gives, else the shipped
``perception/weights/decision_combined.json``: the logistic P(false fix) from the area's P(bad),
the NCC quality and the track evidence; docs/perception.md). The paper's rule
(P(bad) > 0.5) is flown with ``decision_rule="paper"`` or ``--set perception.weights=<a CNN .pt>``
(overrides come last). With the combined rule, two more flights repeat the cnn and assistant-map
rows under the paper's rule (``paper_rows``; run folders ``run-*-paper``) for comparison. The rule
each flight really used is read back from its ``perception_diag_perception.csv``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import shutil
from pathlib import Path

import numpy as np

from scenenav.core.errors import UserError

log = logging.getLogger(__name__)

PAPER = {  # Table 2 of the seed paper: RMS m, time ms, detected %
    "cnn": (1.2, 140.0, 98.7), "assistant-map": (1.15, 41.0, 98.7),
    "statistical": (1.5, 41.0, 112.0), "none": (3.1, 40.0, None),
}
METHODS = ("cnn", "assistant-map", "statistical", "none")
DECISION_RULES = ("combined", "paper")
#: Autopilot flights: fixes captured within this of the flight altitude are scored (the survey
#: leg), not those of the climb and the landing.
SURVEY_BAND_M = 10.0
#: Autopilot flights: simulated-time budget beyond the route at cruise speed (take-off, climb,
#: turns, descent and landing); the run ends when the vehicle has landed.
MISSION_MARGIN_S = 300.0
#: Autopilot flights descend briskly (3 m/s to 10 m, then 1 m/s; the landing is not scored).
FAST_LANDING_PARAMS = "{LAND_SPEED_HIGH: 300, LAND_SPEED: 100}"


def route_length_m(route) -> float:
    return float(sum(math.dist(a, b) for a, b in zip(route[:-1], route[1:], strict=True)))


def at_survey_altitude(fx: dict, altitude_m: float, band_m: float = SURVEY_BAND_M) -> dict:
    """The fix table's rows captured within ``band_m`` of ``altitude_m`` (true height)."""
    keep = np.abs(np.asarray(fx["truth_z_m"], dtype=float) - altitude_m) <= band_m
    return {k: (np.asarray(v)[keep] if np.ndim(v) == 1 and len(v) == len(keep) else v)
            for k, v in fx.items()}


def file_sha256(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def flight_settings(route, altitude_m: float, speed_m_s: float, scripted: bool) -> list[str]:
    """The ``--set`` items that make every table2 flight the same flight."""
    sets = ["flight.route_enu_m=" + json.dumps([list(p) for p in route])]
    if scripted:
        return ["flight.mode=scripted", *sets, "duration_s=100000"]   # ends when the route is done
    duration = route_length_m(route) / speed_m_s + MISSION_MARGIN_S
    return ["flight.mode=autopilot", *sets, f"flight.start_enu_m={json.dumps(list(route[0]))}",
            f"flight.altitude_m={altitude_m}", f"flight.speed_m_s={speed_m_s}",
            "sim.gps.enabled=true", "guidance.enabled=false", "autopilot.mission_end=land",
            f"autopilot.params={FAST_LANDING_PARAMS}", f"duration_s={duration:.0f}"]


def table2_scenario(world_dir: str | Path | None, seed: int = 0, realism: str | None = None,
                    scripted: bool = False, overrides: tuple[str, ...] = (),
                    extra: tuple[str, ...] = ()):
    """The flight every table2 flight flies: ``(sets, cfg, world)``.

    ``sets`` are the ``--set`` items (seed, realism, world, route and flight kind:
    ``flight_settings``, then ``extra``) without ``overrides``; ``cfg`` is the scenario they give
    with ``overrides`` laid over them (as ``--set`` would); ``world`` the loaded world. The route is
    the one ``route_for`` fits to the world on the profile and overrides. One helper for every
    caller that flies "the Table-2 flight" (``run_table2``, ``scenenav cnn decision-data``,
    ``realism_ablation``)."""
    from scenenav.app.nodes import load_world_for
    from scenenav.app.realism import parse_realism
    from scenenav.app.scenario import load_scenario, route_for
    base = [f"seed={seed}", *extra]
    if realism is not None:
        parse_realism(realism, "--realism")
        base.append(f"realism={realism}")
    if world_dir:
        base.append(f"world={Path(world_dir).resolve()}")
    cfg0 = load_scenario(None, tuple(base) + ("flight.mode=scripted",) + tuple(overrides))
    world = load_world_for(cfg0)
    route = route_for(cfg0, world)
    base += flight_settings(route, cfg0.flight.altitude_m, cfg0.flight.speed_m_s, scripted)
    return base, load_scenario(None, tuple(base) + tuple(overrides)), world


def decision_model_for(cfg) -> Path:
    """The combined-rule model a scenario flies: its ``perception.decision_model`` (set by a realism
    profile, the scenario or ``--set``), else the shipped ``decision_combined.json``."""
    from perception.decision import decision_model_path
    return decision_model_path(cfg.perception.decision_model)


def flown_rule(run_dir: Path) -> str:
    """The decision rule a flight's perception node used (its diagnostics), '—' when none."""
    from scenenav.app.evaluation import read_csv
    diag = read_csv(Path(run_dir) / "perception_diag_perception.csv")
    rules = diag.get("rule") if diag else None
    if rules is None or len(rules) == 0:
        return "—"
    return "+".join(sorted({str(r) for r in rules}))


def rejection_metrics(fx: dict) -> dict:
    valid = fx["valid"] > 0.5
    false = fx["is_false"].astype(bool) & valid
    rejected = valid & (fx["accepted"] < 0.5)
    acc = valid & ~rejected
    n_false = int(false.sum())
    n_rej = int(rejected.sum())
    err = fx["error_m"]
    return {
        "rms_error_m": float(np.sqrt(np.mean(err[acc] ** 2))) if acc.any() else None,
        "rms_error_all_m": float(np.sqrt(np.mean(err[valid] ** 2))) if valid.any() else None,
        "fix_time_ms_median": float(np.nanmedian(fx["time_total_ms"])) if len(valid) else None,
        "detected_false_pct": (100.0 * n_rej / n_false) if n_false else None,
        "precision": (float((false & rejected).sum()) / n_rej) if n_rej else None,
        "recall": (float((false & rejected).sum()) / n_false) if n_false else None,
        "fixes_total": int(valid.sum()),
        "fixes_accepted": int(acc.sum()),
        "false_fixes": n_false,
        "false_fixes_accepted": int((false & acc).sum()),
    }


def run_table2(world_dir: str | None, out: str, seed: int = 0, threshold_m: float = 5.0,
               overrides: tuple[str, ...] = (), progress: bool = True,
               results_page: str | None = None, decision_rule: str = "combined",
               paper_rows: bool = True, realism: str | None = None, scripted: bool = False) -> dict:
    from scenenav.app.evaluation import fix_height_splits, fix_table
    from scenenav.app.launcher import run
    from scenenav.app.realism import parse_realism
    if decision_rule not in DECISION_RULES:
        raise UserError(f"decision rule {decision_rule!r}: expected one of {', '.join(DECISION_RULES)}")
    if realism is not None:
        parse_realism(realism, "--realism")
    out_dir = Path(out)
    if out_dir.exists() and any(out_dir.iterdir()):
        raise UserError(f"{out_dir}: output folder exists and is not empty (choose a new --out)")
    base, cfg0, world = table2_scenario(   # cfg0: what every flight flies
        world_dir, seed, realism, scripted, tuple(overrides),
        extra=(f"evaluation.false_fix_threshold_m={threshold_m}",))
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    flights = [(m, decision_rule) for m in METHODS]
    if decision_rule == "combined" and paper_rows:
        # The paper's rule on the same frames, for comparison (its own CNN flight and map).
        flights += [("cnn", "paper"), ("assistant-map", "paper")]
    for method, rule in flights:
        suffix = "-paper" if rule == "paper" and decision_rule != "paper" else ""
        sets = list(base) + [f"perception.method={method}", f"name=table2-{method}{suffix}"]
        if rule == "combined" and method in ("cnn", "assistant-map"):
            sets.append(f"perception.weights={decision_model_for(cfg0)}")
        sets += list(overrides)
        map_path = out_dir / f"assistant_map{suffix}.npz"
        if method == "assistant-map":
            if not map_path.is_file():
                raise UserError("the online-CNN flight left no assistant map to reuse")
            sets.append(f"perception.assistant_map={map_path.resolve()}")
        run_dir = out_dir / f"run-{method}{suffix}"
        log.info("table2: flying with method %s (%s)", method, rule)
        summary = run(None, str(run_dir), tuple(sets), progress=progress)
        if method == "cnn":
            built = run_dir / "assistant_map_perception.npz"
            if built.is_file():
                shutil.copy(built, map_path)
        fx = fix_table(run_dir, threshold_m, world.manifest.reference)
        if fx and not scripted:
            fx = at_survey_altitude(fx, cfg0.flight.altitude_m)
        if not fx or len(fx["t_s"]) == 0:
            raise UserError(f"{run_dir}: the flight produced no fixes (see {run_dir / 'logs'})")
        splits = fix_height_splits(fx, world, cfg0.sim.camera.fov_deg, threshold_m)
        row = {"method": method, "rule": flown_rule(run_dir) if method in ("cnn", "assistant-map")
               else "—", **rejection_metrics(fx), "run_dir": str(run_dir),
               "real_time_factor": summary.get("real_time_factor"),
               "truth_sha256": file_sha256(run_dir / "truth.csv"),
               "errors_by_height_accepted": splits[1].to_dict() if splits else None}
        rows.append(row)
    digests = {r["truth_sha256"] for r in rows}
    identical = len(digests) == 1 and None not in digests
    if not identical:
        log.warning("table2: the flights' truth.csv differ: the methods did not see identical frames")
    result = {"world": world.manifest.name, "threshold_m": threshold_m, "seed": seed,
              "decision_rule": decision_rule, "realism": cfg0.realism.value,
              "flight": "scripted" if scripted else "autopilot", "identical_frames": identical,
              "survey_band_m": None if scripted else SURVEY_BAND_M,
              "rows": rows, "paper": {m: {"rms_error_m": p[0], "fix_time_ms": p[1],
                                          "detected_false_pct": p[2]} for m, p in PAPER.items()}}
    (out_dir / "table2.json").write_text(json.dumps(result, indent=2))
    md = table2_markdown(result)
    (out_dir / "table2.md").write_text(md)
    try:
        plot_figures(out_dir, rows[:len(METHODS)], threshold_m, world.manifest.reference)
    except Exception:  # plots never lose the table
        log.exception("could not draw the figures")
    if results_page:
        command = (f"scenenav experiment table2 --out {out} --results-page {results_page}"
                   + (f" --realism {realism}" if realism else "") + (" --scripted" if scripted else "")
                   + "".join(f" --set {o}" for o in overrides))
        update_results_page(Path(results_page), result, out_dir, command)
    print(md)
    return result


def profile_key(result: dict) -> str:
    """The results page's name for a table: its realism profile and flight kind."""
    return f"{result.get('realism', 'ideal')}-{result.get('flight', 'scripted')}"


#: Column order of the results page (others follow, sorted).
PAGE_ORDER = ("ideal-scripted", "ideal-autopilot", "paper-autopilot", "realistic-autopilot")


def update_results_page(page: Path, result: dict, out_dir: Path, command: str) -> None:
    """Store ``result`` beside ``page`` (``table2-<profile>-<flight>.json`` and its figures) and
    rewrite the page from every table stored there: the profiles side by side, then each table."""
    page.parent.mkdir(parents=True, exist_ok=True)
    key = profile_key(result)
    for fig in ("figure7.png", "figure8.png"):
        if (out_dir / fig).is_file():
            shutil.copy(out_dir / fig, page.parent / f"table2-{key}-{fig}")
    (page.parent / f"table2-{key}.json").write_text(json.dumps({**result, "command": command}, indent=2))
    tables = {}
    for path in sorted(page.parent.glob("table2-*.json")):
        data = json.loads(path.read_text())
        tables[profile_key(data)] = data
    page.write_text(results_page_markdown(tables))


def results_page_markdown(tables: dict[str, dict]) -> str:
    keys = [k for k in PAGE_ORDER if k in tables] + sorted(k for k in tables if k not in PAGE_ORDER)
    lines = ["# Table 2 reproduced, per realism profile", "",
             "Each column is one `scenenav experiment table2` run (four flights, one per method, in "
             "lockstep) on the realism profile and flight kind of its heading (docs/realism.md): "
             "`scripted` = the kinematic path without the autopilot, `autopilot` = the mission flown "
             "by the autopilot on GPS, scored over the fixes at the survey altitude. Regenerated by "
             "the command under each table; a run updates its own column.", "",
             "RMS error over accepted fixes (m) / detected false (%) / false fixes accepted:", "",
             "| method | " + " | ".join(keys) + " | paper |",
             "|---|" + "---|" * (len(keys) + 1)]
    for method in METHODS:
        cells = []
        for k in keys:
            # the first row of a method is its main flight (the paper-rule repeats come after)
            row = next((r for r in tables[k]["rows"] if r["method"] == method), None)
            cells.append("—" if row is None else f"{_f(row['rms_error_m'])} / "
                         f"{_f(row['detected_false_pct'], '{:.1f}')} / {row['false_fixes_accepted']}")
        p = PAPER[method]
        lines.append(f"| {method} | " + " | ".join(cells) + f" | {p[0]} / {_f(p[2], '{:g}')} / — |")
    lines += ["", "| | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys),
              "| world | " + " | ".join(f"`{tables[k]['world']}`" for k in keys) + " |",
              "| identical frames in the four flights | "
              + " | ".join(_yes(tables[k].get("identical_frames")) for k in keys) + " |", ""]
    for k in keys:
        t = tables[k]
        md = table2_markdown(t).replace("# Table 2 reproduced", f"## {k}", 1)
        md = md.replace("Figures: figure7.png (paths), figure8.png (statistical variance).",
                        f"Figures: ![Figure 7](table2-{k}-figure7.png) ![Figure 8](table2-{k}-figure8.png)")
        lines += [md, f"Command: `{t.get('command', 'scenenav experiment table2')}`", ""]
    return "\n".join(lines)


def _yes(value) -> str:
    return "—" if value is None else ("yes" if value else "no")


def _f(v, fmt="{:.2f}") -> str:
    return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def table2_markdown(result: dict) -> str:
    lines = [f"# Table 2 reproduced — world `{result['world']}`", "",
             f"False fix: valid fix with horizontal error > {result['threshold_m']:g} m. "
             "RMS over accepted fixes. detected = flagged false / really false x 100.", "",
             "rule: the decision rule the flight used (paper = P(bad) > 0.5; combined = logistic "
             "P(false fix) from P(bad), NCC quality and tracker innovation, docs/perception.md, "
             "where its held-out-world results are).", "",
             "| method | rule | RMS error (m) | fix time median (ms) | detected false (%) | precision | recall "
             "| fixes | false fixes | false accepted | paper RMS (m) | paper time (ms) | paper detected (%) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        p = PAPER[r["method"]]
        lines.append(f"| {r['method']} | {r.get('rule', '—')} | {_f(r['rms_error_m'])} | {_f(r['fix_time_ms_median'], '{:.1f}')} "
                     f"| {_f(r['detected_false_pct'], '{:.1f}')} | {_f(r['precision'], '{:.3f}')} "
                     f"| {_f(r['recall'], '{:.3f}')} | {r['fixes_total']} | {r['false_fixes']} "
                     f"| {r['false_fixes_accepted']} | {p[0]} | {p[1]:g} | {_f(p[2], '{:g}')} |")
    lines += ["", "Generated by `scenenav experiment table2`; each row is a full lockstep flight "
              "(run folders beside this file). Figures: figure7.png (paths), figure8.png "
              "(statistical variance)."]
    return "\n".join(lines) + "\n"


def plot_figures(out_dir: Path, rows: list[dict], threshold_m: float, reference=None) -> None:
    """Figures 7 and 8 of the flights in ``rows``; errors after undoing ``reference``'s
    misregistration (None: the one each run's world states)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from perception.statistical import StatisticalDetector
    from scenenav.app.evaluation import fix_table
    fig, axes = plt.subplots(2, 4, figsize=(18, 8))
    for i, r in enumerate(rows):
        fx = fix_table(Path(r["run_dir"]), threshold_m, reference)
        acc = (fx["valid"] > 0.5) & (fx["accepted"] > 0.5)
        ax = axes[0, i]
        ax.plot(fx["truth_x_m"], fx["truth_y_m"], "k-", lw=1, label="ref")
        ax.plot(fx["x_m"][acc], fx["y_m"][acc], "g.", ms=3, label="scene matching (accepted)")
        rej = (fx["valid"] > 0.5) & ~acc
        ax.plot(fx["x_m"][rej], fx["y_m"][rej], "rx", ms=3, label="rejected")
        ax.set_title(r["method"])
        ax.set_aspect("equal")
        ax.legend(fontsize=6)
        ax2 = axes[1, i]
        ax2.plot(fx["t_s"], fx["truth_x_m"], "k-", lw=1, label="ref x")
        ax2.plot(fx["t_s"], fx["truth_y_m"], "k--", lw=1, label="ref y")
        ax2.plot(fx["t_s"][acc], fx["x_m"][acc], "b.", ms=2, label="x")
        ax2.plot(fx["t_s"][acc], fx["y_m"][acc], "m.", ms=2, label="y")
        ax2.set_xlabel("t (s)")
        ax2.legend(fontsize=6)
    fig.suptitle("Figure 7: calculated path (accepted fixes) and reference path, per method")
    fig.tight_layout()
    fig.savefig(out_dir / "figure7.png", dpi=80)
    plt.close(fig)
    stat = next(r for r in rows if r["method"] == "statistical")
    fx = fix_table(Path(stat["run_dir"]), threshold_m, reference)
    ok = (fx["valid"] > 0.5) & np.isfinite(fx["x_m"]) & np.isfinite(fx["y_m"])
    fx = {k: (np.asarray(v)[ok] if np.ndim(v) == 1 and len(v) == len(ok) else v) for k, v in fx.items()}
    det = StatisticalDetector()
    var = [det.update(x, y, t)[1] for x, y, t in zip(fx["x_m"], fx["y_m"], fx["t_s"], strict=False)]
    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(fx["t_s"], var, "b-", lw=1, label="variance (m²)")
    ax.axhline(det.threshold, color="r", ls="--", label=f"threshold {det.threshold}")
    false_t = fx["t_s"][fx["is_false"].astype(bool)]
    ax.plot(false_t, np.full(len(false_t), det.threshold), "k|", ms=12, label="really false fixes")
    ax.set_yscale("log")
    ax.set_xlabel("t (s)")
    ax.legend()
    ax.set_title("Figure 8: statistical indicator")
    fig.tight_layout()
    fig.savefig(out_dir / "figure8.png", dpi=80)
    plt.close(fig)
