"""Decision-rule data from flights: fly the training worlds, read the run folders, fit, evaluate.

The app-layer half of ``scenenav cnn decision-data`` / ``fit-decision`` (the pure fit is
``perception.decision_fit``). Data: full lockstep flights (``scenenav run``, the Table-2 path: the
bowtie fitted to the world, 100 m, 10 m/s, method ``cnn``) over generated TRAINING worlds. Every fix
gives two samples from the same capture, one per method (see ``perception.decision_fit``); the
label "false fix" (valid, error > 5 m) uses the simulator's truth, here only, to fit.
"""

from __future__ import annotations

import json
import logging
import platform
import time
from pathlib import Path

import numpy as np

from perception.decision import (
    COMBINED_FEATURES,
    VARIANCE_WINDOWS,
    CombinedDecisionModel,
    TrackEvidence,
    combined_features,
)
from perception.decision_fit import SOURCES, FlightSamples, cross_validate, make_model, pool_samples, rejection_scores
from perception.statistical import StatisticalDetector
from scenenav.core.errors import UserError
from scenenav.core.formats.atomic_file import write_atomic

log = logging.getLogger(__name__)

#: The perception node whose diagnostics and assistant map a decision-data flight leaves.
NODE_ID = "perception"


# ------------------------------------------------------------------------------ samples
def survey_altitude_m(run_dir: Path) -> float | None:
    """The flight altitude of an autopilot flight folder (its ``scenario.yaml``), None for a
    scripted flight (or a folder without a scenario)."""
    path = Path(run_dir) / "scenario.yaml"
    if not path.is_file():
        return None
    import yaml
    flight = (yaml.safe_load(path.read_text(encoding="utf-8")) or {}).get("flight") or {}
    if flight.get("mode") != "autopilot":
        return None
    return float(flight.get("altitude_m", 100.0))


def flight_samples(run_dir: str | Path, threshold_m: float = 5.0) -> FlightSamples:
    """Features and labels of one ``cnn`` flight folder (see the module docstring).

    An autopilot flight's samples are the fixes captured within ``SURVEY_BAND_M`` of its flight
    altitude (true height), the fixes ``scenenav experiment table2`` scores; the climb and the
    landing are left out. The run, the anchor and the statistical indicators are still fed every
    valid fix in order, as in flight."""
    from perception.assistant_map import AssistantMap
    from scenenav.app.evaluation import fix_table, read_csv
    run_dir = Path(run_dir)
    fx = fix_table(run_dir, threshold_m)
    diag = read_csv(run_dir / f"perception_diag_{NODE_ID}.csv")
    amap_path = run_dir / f"assistant_map_{NODE_ID}.npz"
    if not fx or not diag or not amap_path.is_file():
        raise UserError(f"{run_dir}: not a finished cnn flight with perception diagnostics "
                        f"(fixes.csv, perception_diag_{NODE_ID}.csv, assistant_map_{NODE_ID}.npz)")
    seq_fx = fx["frame_seq"].astype(np.int64)
    seq_d = diag["frame_seq"].astype(np.int64)
    pos = {int(s): i for i, s in enumerate(seq_d)}
    keep = np.array([int(s) in pos for s in seq_fx]) & (fx["valid"] > 0.5)
    idx_fx = np.flatnonzero(keep)
    idx_d = np.array([pos[int(seq_fx[i])] for i in idx_fx], dtype=np.int64)
    amap = AssistantMap.load(amap_path)
    m_per_px = amap.m_per_px
    p_online = fx["p_bad"][idx_fx]
    du, dv = diag["drone_u_px"][idx_d], diag["drone_v_px"][idx_d]
    p_map = np.array([1.0 - amap.lookup(u, v) for u, v in zip(du, dv, strict=False)])
    p_map = np.where(np.isfinite(p_map), p_map, p_online)
    innov = diag["innovation_px"][idx_d] * m_per_px
    # TrackEvidence replayed exactly as the pipeline feeds it: every valid match, in order.
    ev = TrackEvidence()
    run, dr_innov, dr_age, reach = (np.empty(len(idx_d)) for _ in range(4))
    for k, j in enumerate(idx_d):
        run[k], dr_innov[k], dr_age[k], reach[k] = ev.observe(
            float(diag["t_s"][j]), (float(diag["u_px"][j]), float(diag["v_px"][j])),
            bool(diag["quality_ok"][j] > 0.5), str(diag["search"][j]) != "window")
    dr_innov *= m_per_px
    reach *= m_per_px
    peak, psr, spr = (diag[k][idx_d] for k in ("ncc_peak", "ncc_psr", "ncc_second_peak_ratio"))
    # The statistical indicators as the pipeline computes them: every valid fix, in order.
    variances = []
    for w in VARIANCE_WINDOWS:
        det = StatisticalDetector(w)
        variances.append(np.array([det.update(x, y, t)[1] for x, y, t in zip(
            fx["x_m"][idx_fx], fx["y_m"][idx_fx], fx["t_s"][idx_fx], strict=False)]))
    features, p_bads = {}, {}
    for src, p_bad in (("cnn", p_online), ("assistant-map", p_map)):
        features[src] = np.array([combined_features(pb, pk, ps, sp, inn, int(rn), di, da, v30, v10, re)
                             for pb, pk, ps, sp, inn, rn, di, da, v30, v10, re
                             in zip(p_bad, peak, psr, spr, innov, run, dr_innov, dr_age, *variances,
                                    reach, strict=False)])
        p_bads[src] = p_bad
    sel = np.ones(len(idx_fx), dtype=bool)
    altitude = survey_altitude_m(run_dir)
    if altitude is not None:
        from scenenav.app.experiment import SURVEY_BAND_M
        sel = np.abs(np.asarray(fx["truth_z_m"], dtype=float)[idx_fx] - altitude) <= SURVEY_BAND_M
    return FlightSamples(world=run_dir.name, y=fx["is_false"][idx_fx][sel].astype(bool),
                         error_m=fx["error_m"][idx_fx][sel], t_s=fx["t_s"][idx_fx][sel],
                         features={k: v[sel] for k, v in features.items()},
                         p_bad={k: v[sel] for k, v in p_bads.items()})


# ------------------------------------------------------------------------------ flights
def fly_cnn(world_dir: str | Path, run_dir: str | Path, weights: str = "", seed: int = 0,
            progress: bool = False, realism: str | None = None, scripted: bool = True,
            overrides: tuple[str, ...] = ()) -> dict:
    """One Table-2 flight with method cnn over ``world_dir``: the flight ``scenenav experiment
    table2`` flies (``experiment.table2_scenario``: the autopilot mission on GPS, or the scripted
    kinematic path with ``scripted``) on profile ``realism``, ``overrides`` last (as ``--set``)."""
    from scenenav.app.experiment import table2_scenario
    from scenenav.app.launcher import run
    sets, _cfg, _world = table2_scenario(world_dir, seed, realism, scripted, tuple(overrides))
    sets += ["perception.method=cnn", "name=decision-data-cnn"]
    if weights:
        sets.append(f"perception.weights={Path(weights).resolve()}")
    return run(None, str(run_dir), tuple(sets) + tuple(overrides), progress=progress)


def check_training_seeds(world_seeds: tuple[int, ...]) -> None:
    """Refuse the default world and every held-out seed (``RESERVED_SEEDS``, any seed >= 9000)."""
    reserved = sorted(s for s in set(world_seeds) if s in RESERVED_SEEDS or s >= HELD_OUT_FROM)
    if reserved:
        raise UserError(f"world seed(s) {reserved} reserved for held-out evaluation (0 and every seed "
                        f">= {HELD_OUT_FROM}); choose other training seeds")


def collect(out: str | Path, world_seeds: tuple[int, ...], size_px: tuple[int, int] = (900, 1000),
            weights: str = "", progress: bool = False, command: str = "",
            realism: str | None = None, scripted: bool = True,
            overrides: tuple[str, ...] = ()) -> list[Path]:
    """Generate each training world and fly it once with the online CNN (skips finished ones), as
    ``fly_cnn`` flies it. Writes ``manifest.json`` (command, seeds, size, weights, realism, flight
    kind, overrides) beside ``worlds/`` and ``flights/``. A folder holds one kind of flight: a
    manifest of another realism, flight kind or overrides is refused."""
    from worlds.generator import CityConfig, generate_world
    check_training_seeds(world_seeds)
    from scenenav.app.scenario import load_scenario
    # bad --realism or --set: one line before any world is generated
    load_scenario(None, ((f"realism={realism}",) if realism is not None else ()) + tuple(overrides))
    out = Path(out)
    flight = {"realism": realism or "ideal", "flight": "scripted" if scripted else "autopilot",
              "overrides": list(overrides)}
    man_path = out / "manifest.json"
    if man_path.is_file():
        old = json.loads(man_path.read_text(encoding="utf-8"))
        was = {"realism": old.get("realism", "ideal"), "flight": old.get("flight", "scripted"),
               "overrides": old.get("overrides", [])}
        if was != flight:
            raise UserError(f"{out}: holds {was['realism']}/{was['flight']} flights with overrides "
                            f"{was['overrides']}; asked for {flight['realism']}/{flight['flight']} with "
                            f"{flight['overrides']} (choose another --out)")
    (out / "worlds").mkdir(parents=True, exist_ok=True)
    runs = []
    for seed in world_seeds:
        wdir = out / "worlds" / f"w{seed}"
        if not (wdir / "manifest.json").is_file():
            world = generate_world(CityConfig(seed=seed, width_px=size_px[0], height_px=size_px[1]),
                                   name=f"w{seed}")
            world.save(wdir)
        rdir = out / "flights" / f"w{seed}"
        if not (rdir / "summary.json").is_file():
            if rdir.exists():
                raise UserError(f"{rdir}: an unfinished flight; delete it and run again")
            log.info("decision data: flying world %d (%s, %s)", seed, flight["realism"], flight["flight"])
            fly_cnn(wdir, rdir, weights, progress=progress, realism=realism, scripted=scripted,
                    overrides=overrides)
        runs.append(rdir)
        write_atomic(man_path, json.dumps({   # after every flight: a stopped collection keeps its record
            "command": command, "world_seeds": list(world_seeds), "world_size_px": list(size_px),
            "weights": str(Path(weights).resolve()) if weights else "perception/weights/default.pt",
            **flight, "flights": [str(r) for r in runs]}, indent=2) + "\n")
    return runs


#: Never used for fitting: the default world (seed 0) and the held-out evaluation worlds.
RESERVED_SEEDS = frozenset({0, 9001, 9002, 9003, 9101, 9102, 9103})
#: Every seed from here up is reserved for held-out (blind) checks.
HELD_OUT_FROM = 9000
#: Training worlds of the shipped model (disjoint from the CNN's training worlds 1-12 too).
DEFAULT_TRAIN_SEEDS = tuple(range(101, 111))


def flight_dirs_under(path: str | Path) -> list[Path]:
    """Finished flight folders: ``path`` itself, ``path/flights/*`` or ``path/*`` (sorted)."""
    p = Path(path)
    if (p / "fixes.csv").is_file():
        return [p]
    base = p / "flights" if (p / "flights").is_dir() else p
    dirs = sorted(d for d in base.iterdir() if (d / "summary.json").is_file()) if base.is_dir() else []
    if not dirs:
        raise UserError(f"{p}: no finished flights found")
    return dirs


def fit_decision(flight_dirs: list[Path], out: str | Path, cnn_weights: str, l2: float = 1.0,
                 target_recall: float = 0.987, command: str = "",
                 data_manifest: dict | None = None) -> CombinedDecisionModel:
    """LOWO cross-validation, threshold choice, final fit on all flights; writes the model JSON."""
    t0 = time.perf_counter()
    samples = [flight_samples(d) for d in flight_dirs]
    if len(samples) < 2:
        raise UserError("fit-decision needs flights over at least two training worlds")
    cv = cross_validate(samples, l2, target_recall)
    x, y = pool_samples(samples, SOURCES)
    out = Path(out)
    cnn_rel = ""
    if cnn_weights:
        cw = Path(cnn_weights).resolve()
        try:
            cnn_rel = str(cw.relative_to(out.resolve().parent))
        except ValueError:
            cnn_rel = str(cw)
    meta = {
        "command": command,
        "data": data_manifest or {},
        "training_worlds": [s.world for s in samples],
        "flight_dirs": [str(d) for d in flight_dirs],
        "samples": int(len(y)), "false_samples": int(y.sum()),
        "sources": list(SOURCES), "l2": l2, "target_recall": target_recall,
        "threshold_rule": "largest threshold with pooled leave-one-world-out recall >= target_recall",
        "cross_validation": cv["scores"],
        "wall_time_s": None, "python": platform.python_version(), "numpy": np.__version__,
    }
    model = make_model(x, y, l2, threshold=cv["threshold"], cnn_weights=cnn_rel, meta=meta)
    train_scores = {src: rejection_scores(np.concatenate([s.y for s in samples]),
                                          np.concatenate([model.p_false(s.features[src]) for s in samples])
                                          > model.threshold,
                                          np.concatenate([s.error_m for s in samples]))
                    for src in SOURCES}
    meta["training_fit"] = train_scores
    meta["coefficients_raw"] = {f: float(w) for f, w in zip(COMBINED_FEATURES, model._w, strict=False)}
    meta["intercept_raw"] = float(model._b)
    meta["wall_time_s"] = round(time.perf_counter() - t0, 2)
    model.save(out)
    return model


def evaluate_flights(model: CombinedDecisionModel, flight_dirs: list[Path]) -> dict:
    """Scores of the model (and of the paper rule) on flights it was not fitted on."""
    res = {}
    for d in flight_dirs:
        s = flight_samples(d)
        row = {}
        for src in SOURCES:
            row[src] = {"combined": rejection_scores(s.y, model.p_false(s.features[src]) > model.threshold,
                                                     s.error_m),
                        "paper": rejection_scores(s.y, s.p_bad[src] > 0.5, s.error_m)}
        res[s.world] = row
    return res
