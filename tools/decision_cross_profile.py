#!/usr/bin/env python3
"""Leave-one-world-out of the combined decision rule across realism profiles.

  tools/decision_cross_profile.py --data NAME=DIR [--data NAME=DIR ...] [--target-recall 0.99]

Each DIR is a ``scenenav cnn decision-data`` folder (flights over the same training worlds, one
profile each). For every training set (each NAME alone, and all pooled) and every world: a model
fitted on the other worlds' flights of that set scores the held-out world's flights of every
profile; the threshold is the set's own (largest with pooled out-of-world recall >= the target, as
``scenenav cnn fit-decision`` chooses it). Prints the pooled precision / recall / false fixes
accepted / RMS of the accepted fixes per (training set, scored profile), then per world.
Assistant-map samples are scored (the cnn samples give the same figures within a fix or two).
docs/perception.md ("Refit on `realistic`") has the table it made. Training worlds only.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from perception.decision_fit import SOURCES, choose_threshold, make_model, pool_samples, rejection_scores
from scenenav.app.decision_data import flight_dirs_under, flight_samples


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", action="append", required=True, metavar="NAME=DIR")
    ap.add_argument("--target-recall", type=float, default=0.99)
    ap.add_argument("--l2", type=float, default=1.0)
    args = ap.parse_args(argv)
    data = {}
    for item in args.data:
        name, _, path = item.partition("=")
        data[name] = {d.name: flight_samples(d) for d in flight_dirs_under(path)}
    worlds = sorted(set.intersection(*(set(v) for v in data.values())))
    sets = {name: [name] for name in data}
    if len(data) > 1:
        sets["pooled"] = list(data)
    src = "assistant-map"
    for tname, members in sets.items():
        oof = {p: {} for p in data}
        for w in worlds:
            x, y = pool_samples([data[m][v] for m in members for v in worlds if v != w], SOURCES)
            model = make_model(x, y, args.l2)
            for p in data:
                oof[p][w] = model.p_false(data[p][w].features[src])
        t = choose_threshold(np.concatenate([oof[m][w] for m in members for w in worlds]),
                             np.concatenate([data[m][w].y for m in members for w in worlds]),
                             args.target_recall)
        for p in data:
            rows = [(w, rejection_scores(data[p][w].y, oof[p][w] > t, data[p][w].error_m)) for w in worlds]
            rows.append(("pooled", rejection_scores(np.concatenate([data[p][w].y for w in worlds]),
                                                    np.concatenate([oof[p][w] for w in worlds]) > t,
                                                    np.concatenate([data[p][w].error_m for w in worlds]))))
            print(f"fitted on {tname} (threshold {t:.4g}), scored on {p} flights:")
            for w, sc in rows:
                print(f"  {w:<7} fixes {sc['fixes']:5d} false {sc['false']:5d} precision {sc['precision']:.3f} "
                      f"recall {sc['recall']:.3f} false accepted {sc['false_accepted']:4d} "
                      f"rms accepted {sc['rms_accepted_m']:.2f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
