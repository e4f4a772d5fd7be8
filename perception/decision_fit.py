"""The fit of the combined decision rule: logistic regression, threshold choice, cross-validation.

Pure numpy; the flights and the run folders are read by the app layer
(``scenenav/app/decision_data.py``: ``scenenav cnn decision-data`` / ``fit-decision``).

Data: full lockstep flights (``scenenav run``, the Table-2 path: the bowtie fitted to the world,
100 m, 10 m/s, method ``cnn``) over generated TRAINING worlds. Every fix gives two samples from
the same capture, one per method, because the match does not depend on the verdict:

* ``cnn``: the online CNN's P(bad) of that capture;
* ``assistant-map``: 1 - the value the flight's assistant map (saved at the end of the flight,
  exactly what the assistant-map row of Table 2 flies with) holds at the fix's drone pixel, or the
  online P(bad) where the map has no value (what the pipeline does then).

Each sample: :func:`perception.decision.combined_features` and the label "false fix" (valid, error
> 5 m against the simulator's truth). The truth is used only here, to fit; never in flight.

Fit: L2-regularised logistic regression (IRLS on standardised features). The rejection threshold is
chosen by leave-one-world-out cross-validation on the training worlds only: the largest threshold at
which the pooled out-of-world recall reaches ``target_recall``. Held-out worlds and the default
world are never read by the fit.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from perception.decision import CombinedDecisionModel

log = logging.getLogger(__name__)

#: The two methods whose samples are pooled: the online CNN, and the flight's assistant map.
SOURCES = ("cnn", "assistant-map")


@dataclass(frozen=True)
class FlightSamples:
    """The samples of one flight: per valid fix the label and, per source (``SOURCES``), the
    combined-rule features and the area P(bad) they were computed from."""

    world: str
    y: np.ndarray                       # bool: a false fix (error above the threshold)
    error_m: np.ndarray                 # fix error against the simulator's truth
    t_s: np.ndarray
    features: dict[str, np.ndarray]     # source -> (N, len(COMBINED_FEATURES))
    p_bad: dict[str, np.ndarray]        # source -> (N,)


# ------------------------------------------------------------------------------ logistic fit
def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1.0, iters: int = 100
                 ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """L2-regularised logistic regression by IRLS on standardised features.

    Returns (intercept, weights, mean, std) in the standardised parametrisation of
    :class:`CombinedDecisionModel`. ``l2`` is the penalty on the weights (not the intercept),
    in units of samples.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    mean = x.mean(axis=0)
    std = x.std(axis=0)
    std = np.where(std > 1e-9, std, 1.0)
    z = np.hstack([np.ones((len(x), 1)), (x - mean) / std])
    beta = np.zeros(z.shape[1])
    pen = np.full(z.shape[1], l2)
    pen[0] = 0.0
    for _ in range(iters):
        eta = np.clip(z @ beta, -30.0, 30.0)
        p = 1.0 / (1.0 + np.exp(-eta))
        w = np.maximum(p * (1.0 - p), 1e-9)
        grad = z.T @ (p - y) + pen * beta
        hess = (z * w[:, None]).T @ z + np.diag(pen)
        step = np.linalg.solve(hess, grad)
        beta -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return float(beta[0]), beta[1:], mean, std


def make_model(x: np.ndarray, y: np.ndarray, l2: float, threshold: float = 0.5,
               **kw) -> CombinedDecisionModel:
    b0, w, mean, std = fit_logistic(x, y, l2)
    return CombinedDecisionModel(intercept=b0, weights=tuple(float(v) for v in w),
                                 mean=tuple(float(v) for v in mean),
                                 std=tuple(float(v) for v in std), threshold=threshold, **kw)


def rejection_scores(y: np.ndarray, reject: np.ndarray, error_m: np.ndarray | None = None) -> dict:
    """Precision / recall of a rejection and the RMS error of what is accepted."""
    y = np.asarray(y, bool)
    reject = np.asarray(reject, bool)
    n_rej, n_false = int(reject.sum()), int(y.sum())
    tp = int((reject & y).sum())
    out = {"fixes": int(len(y)), "false": n_false, "rejected": n_rej,
           "precision": tp / n_rej if n_rej else None, "recall": tp / n_false if n_false else None,
           "false_accepted": n_false - tp, "true_rejected": n_rej - tp}
    if error_m is not None:
        acc = ~reject
        out["rms_accepted_m"] = float(np.sqrt(np.mean(error_m[acc] ** 2))) if acc.any() else None
    return out


def pool_samples(samples: list[FlightSamples], sources: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Features and labels of ``samples`` (one per flight), every source stacked."""
    xs, ys = [], []
    for s in samples:
        for src in sources:
            xs.append(s.features[src])
            ys.append(s.y)
    return np.vstack(xs), np.concatenate(ys)


def choose_threshold(p: np.ndarray, y: np.ndarray, target_recall: float) -> float:
    """The largest threshold (P(false) > t rejects) whose recall on (p, y) is >= target_recall."""
    pf = np.sort(p[y])
    if len(pf) == 0:
        return 0.5
    k = int(math.floor((1.0 - target_recall) * len(pf)))   # false fixes we may miss
    t = float(pf[k]) - 1e-9 if k < len(pf) else 0.5
    return float(min(0.5, max(1e-4, t)))


def cross_validate(samples: list[FlightSamples], l2: float, target_recall: float,
                   sources: tuple[str, ...] = SOURCES) -> dict:
    """Leave-one-world-out: out-of-world P(false) for every sample, the chosen threshold, scores."""
    oof = []
    for i, held in enumerate(samples):
        train = [s for j, s in enumerate(samples) if j != i]
        x, y = pool_samples(train, sources)
        m = make_model(x, y, l2)
        oof.append({src: m.p_false(held.features[src]) for src in SOURCES})
    p_all = np.concatenate([o[src] for o in oof for src in sources])
    y_all = np.concatenate([s.y for s in samples for _ in sources])
    thr = choose_threshold(p_all, y_all, target_recall)
    per = {}
    for src in SOURCES:
        p = np.concatenate([o[src] for o in oof])
        y = np.concatenate([s.y for s in samples])
        e = np.concatenate([s.error_m for s in samples])
        per[src] = {"t=0.5": rejection_scores(y, p > 0.5, e),
                    "t=chosen": rejection_scores(y, p > thr, e)}
        per[src]["per_world"] = {s.world: rejection_scores(s.y, o[src] > thr, s.error_m)
                                 for s, o in zip(samples, oof, strict=False)}
    return {"threshold": thr, "scores": per}
