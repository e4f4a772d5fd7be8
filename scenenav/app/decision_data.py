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

log = logging.getLogger(__name__)

#: The perception node whose diagnostics and assistant map a decision-data flight leaves.
NODE_ID = "perception"


# ------------------------------------------------------------------------------ samples
def flight_samples(run_dir: str | Path, threshold_m: float = 5.0) -> FlightSamples:
    """Features and labels of one ``cnn`` flight folder (see the module docstring)."""
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
    return FlightSamples(world=run_dir.name, y=fx["is_false"][idx_fx].astype(bool),
                         error_m=fx["error_m"][idx_fx], t_s=fx["t_s"][idx_fx], features=features,
                         p_bad=p_bads)


# ------------------------------------------------------------------------------ flights
def fly_cnn(world_dir: str | Path, run_dir: str | Path, weights: str = "", seed: int = 0,
            progress: bool = False) -> dict:
    """One Table-2 style flight (bowtie, scripted, method cnn) over ``world_dir``."""
    from scenenav.app.launcher import run
    from scenenav.app.nodes import load_world_for
    from scenenav.app.scenario import load_scenario, route_for
    base = ["flight.mode=scripted", f"seed={seed}", f"world={Path(world_dir).resolve()}"]
    cfg0 = load_scenario(None, tuple(base))
    route = route_for(cfg0, load_world_for(cfg0))
    sets = base + ["flight.route_enu_m=" + json.dumps([list(p) for p in route]),
                   "duration_s=100000", "perception.method=cnn", "name=decision-data-cnn"]
    if weights:
        sets.append(f"perception.weights={Path(weights).resolve()}")
    return run(None, str(run_dir), tuple(sets), progress=progress)


def collect(out: str | Path, world_seeds: tuple[int, ...], size_px: tuple[int, int] = (900, 1000),
            weights: str = "", progress: bool = False, command: str = "") -> list[Path]:
    """Generate each training world and fly it once with the online CNN (skips finished ones).
    Writes ``manifest.json`` (command, seeds, size, weights) beside ``worlds/`` and ``flights/``."""
    from worlds.generator import CityConfig, generate_world
    reserved = sorted(set(world_seeds) & RESERVED_SEEDS)
    if reserved:
        raise UserError(f"world seed(s) {reserved} reserved for held-out evaluation "
                        f"({sorted(RESERVED_SEEDS)}); choose other training seeds")
    out = Path(out)
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
            log.info("decision data: flying world %d", seed)
            fly_cnn(wdir, rdir, weights, progress=progress)
        runs.append(rdir)
    (out / "manifest.json").write_text(json.dumps({
        "command": command, "world_seeds": list(world_seeds), "world_size_px": list(size_px),
        "weights": str(Path(weights).resolve()) if weights else "perception/weights/default.pt",
        "flights": [str(r) for r in runs]}, indent=2) + "\n")
    return runs


#: Never used for fitting: the default world (seed 0) and the held-out evaluation worlds.
RESERVED_SEEDS = frozenset({0, 9001, 9002, 9003, 9101, 9102, 9103})
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
