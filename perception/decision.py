"""The navigation decision of the paper (section 5.4) and the false-match detection methods.

A fix is rejected when the probability of class 1 (bad matching area) is greater than 0.5, "no matter
what the overall CNN result is"; otherwise it is accepted. A probability of exactly 0.5 is accepted
(the paper rejects only when P(bad) > 0.5).

Classifier outputs come in two shapes and both are understood by :func:`split_classifier_output`:
``(N,)`` = P(bad) per image, or ``(N, K)`` = softmax over the paper's classes with column 0 = class 1
(bad area) and columns 1.. = the good-area classes (4-, 3-, 2-arm intersections).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np

#: Paper 5.4: reject when P(class 1 = bad area) > 0.5.
P_BAD_THRESHOLD = 0.5
#: Column of the bad-area class in a (N, K) softmax output (the paper's class 1).
BAD_CLASS_COLUMN = 0
#: Number of classes in the paper's CNN (bad, 4-arm, 3-arm, 2-arm).
N_PAPER_CLASSES = 4


class Decision(str, Enum):
    """Accept or reject a scene-matching fix."""

    ACCEPT = "accept"
    REJECT = "reject"


class FalseMatchMethod(str, Enum):
    """How false matches are detected (values are the bus/CLI spellings)."""

    CNN = "cnn"
    ASSISTANT_MAP = "assistant-map"
    STATISTICAL = "statistical"
    NONE = "none"


def decide_from_p_bad(p_bad: float, threshold: float = P_BAD_THRESHOLD) -> Decision:
    """REJECT when ``p_bad > threshold`` (paper 5.4), ACCEPT otherwise. NaN raises ValueError."""
    if not math.isfinite(p_bad):
        raise ValueError(f"p_bad = {p_bad!r}: expected a probability in [0, 1]")
    return Decision.REJECT if p_bad > threshold else Decision.ACCEPT


def split_classifier_output(output: np.ndarray, n_images: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Classifier output -> (P(bad) as float64 (N,), class probabilities (N, K) or None).

    Accepts ``(N,)`` P(bad) or ``(N, K)`` class probabilities (column 0 = bad). Values are clipped
    to [0, 1]; a wrong shape or non-finite values raise ValueError (a classifier bug, not bad input).
    """
    out = np.asarray(output, dtype=np.float64)
    if out.ndim == 1 and out.shape[0] == n_images:
        p_bad, classes = out, None
    elif out.ndim == 2 and out.shape[0] == n_images and out.shape[1] >= 1:
        p_bad, classes = out[:, BAD_CLASS_COLUMN], out
    else:
        raise ValueError(f"classifier returned shape {out.shape}: expected ({n_images},) P(bad) "
                         f"or ({n_images}, K) class probabilities")
    if not np.all(np.isfinite(out)):
        raise ValueError("classifier returned non-finite probabilities")
    p_bad = np.clip(p_bad, 0.0, 1.0)
    return p_bad, (np.clip(classes, 0.0, 1.0) if classes is not None else None)


# ------------------------------------------------------------------------------ combined rule
class DecisionRule(str, Enum):
    """How the cnn / assistant-map methods turn their evidence into a verdict.

    ``paper``: the paper's rule (5.4), REJECT when P(bad) > p_bad_threshold, whatever the match.
    ``combined``: a logistic model of P(false fix) from the area's P(bad) (map value or online
    CNN) *and* the fix's own evidence (NCC peak, PSR, second-peak ratio, innovation against the
    tracker's constant-velocity prediction); coefficients fitted on flights over training worlds
    (``scenenav cnn fit-decision``) and stored in a decision-model file. See docs/perception.md.
    """

    PAPER = "paper"
    COMBINED = "combined"


#: Features of the combined rule, in coefficient order (all known at flight time, no truth):
#: ``bad_logit``  logit of the area's P(bad), P clipped to [P_CLIP, 1 - P_CLIP];
#: ``peak``       NCC peak; ``log_psr`` ln(max(PSR, 1)); ``spr`` second-peak ratio;
#: ``innov``      ln(1 + innovation / 1 m) when the tracker predicted from a known velocity, else 0;
#: ``no_track``   1 when there was no such prediction (global search, re-acquisition, one fix);
#: ``log_run``    ln(1 + length of the unbroken run of quality-ok matches this one continues)
#:                (:class:`TrackEvidence`);
#: ``dr_innov``   ln(1 + distance / 1 m) between the fix and the dead-reckoned anchor of the last
#:                established run (:class:`TrackEvidence`), 0 without one;
#: ``dr_age``     ln(1 + seconds since that anchor), 0 without one;
#: ``no_dr``      1 when no run has been established yet;
#: ``log_var30``  ln(1e-3 + the paper's statistical indicator: detrended variance (m^2) of the last
#:                30 fixes, this one included; perception.statistical), 0 before 3 fixes;
#: ``log_var10``  the same over the last 10 fixes (reacts faster);
#: ``reach``      ln(1 + metres by which the fix lies beyond where the drone can be: farther from the
#:                anchor's position than REACH_FACTOR x anchor speed x anchor age), 0 without anchor.
COMBINED_FEATURES = ("bad_logit", "peak", "log_psr", "spr", "innov", "no_track", "log_run",
                     "dr_innov", "dr_age", "no_dr", "log_var30", "log_var10", "reach")
#: Reachability margin on the anchor's speed (the drone may speed up a little, in any direction).
REACH_FACTOR = 1.2
#: Windows of the two statistical-indicator features.
VARIANCE_WINDOWS = (30, 10)
P_CLIP = 0.005


def combined_features(p_bad: float, peak: float, psr: float, second_peak_ratio: float,
                      innovation_m: float, run: int = 0, dr_innovation_m: float = math.nan,
                      dr_age_s: float = math.nan, variance30_m2: float = math.nan,
                      variance10_m2: float = math.nan, reach_excess_m: float = math.nan) -> np.ndarray:
    """The feature vector of :data:`COMBINED_FEATURES` (``innovation_m`` NaN = no prediction,
    ``dr_innovation_m`` / ``dr_age_s`` NaN = no established track)."""
    dr = math.isfinite(dr_innovation_m) and math.isfinite(dr_age_s)
    p = min(1.0 - P_CLIP, max(P_CLIP, p_bad if math.isfinite(p_bad) else 0.5))
    tracked = math.isfinite(innovation_m)
    return np.array([
        math.log(p / (1.0 - p)),
        peak if math.isfinite(peak) else 0.0,
        math.log(max(psr, 1.0)) if math.isfinite(psr) else 0.0,
        second_peak_ratio if math.isfinite(second_peak_ratio) else 1.0,
        math.log1p(innovation_m) if tracked else 0.0,
        0.0 if tracked else 1.0,
        math.log1p(max(run, 0)),
        math.log1p(dr_innovation_m) if dr else 0.0,
        math.log1p(max(dr_age_s, 0.0)) if dr else 0.0,
        0.0 if dr else 1.0,
        math.log(1e-3 + variance30_m2) if math.isfinite(variance30_m2) else 0.0,
        math.log(1e-3 + variance10_m2) if math.isfinite(variance10_m2) else 0.0,
        math.log1p(max(reach_excess_m, 0.0)) if math.isfinite(reach_excess_m) else 0.0,
    ])


class TrackEvidence:
    """How established the current match sequence is, from the matches alone (no truth, no verdicts).

    Fed every valid match in order (``observe``). A *run* is an unbroken sequence of quality-ok
    matches: any low-quality match ends it, a quality-ok global search (re-acquisition) starts a
    new one. A run of ``min_run`` matches is *established* (false locks rarely keep matching
    unbroken that long, while a track whose matches are mostly low quality never qualifies);
    each further match of it moves the *anchor*: (t, u, v) and the velocity over its last
    ``min_run`` matches. ``observe`` returns, from the state before the match, the length of the
    run it continues, the distance / age to the anchor dead-reckoned at constant velocity, and the
    reachability excess: how far the match lies beyond REACH_FACTOR x anchor speed x age from the
    anchor's position (negative = reachable; a straight-line extrapolation can be wrong after a
    turn, this bound cannot). Pixels and seconds; the pipeline converts to metres.
    """

    def __init__(self, min_run: int = 10) -> None:
        self.min_run = int(min_run)
        self._run: list[tuple[float, float, float]] = []
        self.count = 0
        self._anchor: tuple[float, float, float, float, float] | None = None
        # [t, u, v]: the anchor dead-reckoned with the velocities given to ``observe`` (None: unused)
        self._dr: list[float] | None = None
        # (anchor, dr) when ``mark_accepted`` was last called: what ``drop_run`` returns to
        self._accepted: tuple[tuple[float, float, float, float, float] | None, list[float] | None] = (None, None)

    def reset(self) -> None:
        self._run = []
        self.count = 0
        self._anchor = None
        self._dr = None
        self._accepted = (None, None)

    def mark_accepted(self) -> None:
        """Remember the anchor as it is now: the newest match was accepted (``drop_run`` returns here)."""
        self._accepted = (self._anchor, None if self._dr is None else list(self._dr))

    def drop_run(self) -> None:
        """End the current run and return the anchor to where it was at the last ``mark_accepted``:
        a run the decision rule kept rejecting (a false lock) must not leave its anchor behind."""
        self._run, self.count = [], 0
        anchor, dr = self._accepted
        self._anchor, self._dr = anchor, None if dr is None else list(dr)

    def predict(self, t_s: float) -> tuple[tuple[float, float], float] | None:
        """The anchor dead-reckoned to ``t_s`` and its age in seconds (None: none yet)."""
        if self._anchor is None:
            return None
        t0, u, v, vu, vv = self._anchor
        dt = max(0.0, t_s - t0)
        return (u + vu * dt, v + vv * dt), dt

    def _dead_reckoned(self, t_s: float, velocity_px_s: tuple[float, float] | None
                       ) -> tuple[tuple[float, float], float] | None:
        """The anchor moved on to ``t_s`` by the given velocity (px/s) since the last call, or by the
        anchor's own velocity when none is given; and the anchor's age."""
        if self._anchor is None:
            return None
        t0, ua, va, vu, vv = self._anchor
        if self._dr is None:
            self._dr = [t0, ua, va]
        dt = t_s - self._dr[0]
        if dt > 0.0:
            du, dv = velocity_px_s if velocity_px_s is not None else (vu, vv)
            self._dr = [t_s, self._dr[1] + du * dt, self._dr[2] + dv * dt]
        return (self._dr[1], self._dr[2]), max(0.0, t_s - t0)

    def observe(self, t_s: float, uv: tuple[float, float], quality_ok: bool,
                reacquired: bool, velocity_px_s: tuple[float, float] | None = None
                ) -> tuple[int, float, float, float]:
        """Add a match; return (run length before it, distance to the dead-reckoned anchor px,
        anchor age s, reachability excess px).

        ``velocity_px_s``: the vehicle's velocity now (map px/s, e.g. the autopilot's estimate;
        ``perception.dr_from_estimate``). Once one is given the anchor is dead-reckoned by these
        velocities, step by step from the last match, instead of at the established run's constant
        velocity: through a turn or a hold it stays with the vehicle. None throughout: as before."""
        run_before = self.count
        if velocity_px_s is not None or self._dr is not None:
            pred = self._dead_reckoned(t_s, velocity_px_s)
        else:
            pred = self.predict(t_s)
        dist, age, excess = math.nan, math.nan, math.nan
        if pred is not None:
            dist = math.hypot(uv[0] - pred[0][0], uv[1] - pred[0][1])
            age = pred[1]
            t0, ua, va, vu, vv = self._anchor
            excess = (math.hypot(uv[0] - ua, uv[1] - va)
                      - REACH_FACTOR * math.hypot(vu, vv) * age)
        if not quality_ok:
            self._run, self.count = [], 0
            return run_before, dist, age, excess
        if reacquired or self.count == 0:
            self._run, self.count = [], 0
        self._run.append((float(t_s), float(uv[0]), float(uv[1])))
        if len(self._run) > self.min_run:
            self._run.pop(0)
        self.count += 1
        if self.count >= self.min_run:
            (ta, ua, va), (tb, ub, vb) = self._run[0], self._run[-1]
            if tb > ta:
                self._anchor = (tb, ub, vb, (ub - ua) / (tb - ta), (vb - va) / (tb - ta))
                if self._dr is not None:
                    self._dr = [tb, ub, vb]
        return run_before, dist, age, excess


#: The shipped combined-rule model (fitted by ``scenenav cnn fit-decision``, see docs/perception.md).
DEFAULT_DECISION_MODEL = Path(__file__).resolve().parent / "weights" / "decision_combined.json"
#: The same rule fitted on ``realistic``-profile autopilot flights (docs/perception.md, "Refit on
#: `realistic`"); the ``paper`` and ``realistic`` realism profiles select it (``perception.decision_model``).
REALISTIC_DECISION_MODEL = DEFAULT_DECISION_MODEL.parent / "decision_combined_realistic.json"
#: Shipped models by name, for scenario files (``perception.decision_model: realistic``).
SHIPPED_DECISION_MODELS = {"ideal": DEFAULT_DECISION_MODEL, "realistic": REALISTIC_DECISION_MODEL}
DECISION_MODEL_FORMAT = 1


def decision_model_path(name_or_path: str) -> Path:
    """``perception.decision_model`` -> the model file: "" the shipped (ideal-fitted) model, a name of
    ``SHIPPED_DECISION_MODELS``, or a path to a ``scenenav cnn fit-decision`` JSON."""
    if not name_or_path:
        return DEFAULT_DECISION_MODEL
    return SHIPPED_DECISION_MODELS.get(name_or_path, Path(name_or_path))


@dataclass(frozen=True)
class CombinedDecisionModel:
    """Logistic P(false fix) over :data:`COMBINED_FEATURES`; REJECT when P(false) > ``threshold``.

    ``weights`` are ``(mean, std)``-standardised coefficients: z_i = (x_i - mean_i) / std_i,
    P(false) = sigmoid(intercept + sum w_i z_i). ``cnn_weights`` names the CNN file (relative to the
    model file's folder) whose P(bad) the model was fitted with; ``meta`` holds the fit record
    (training worlds, counts, held-out figures, command).
    """

    intercept: float
    weights: tuple[float, ...]
    mean: tuple[float, ...]
    std: tuple[float, ...]
    threshold: float = 0.5
    features: tuple[str, ...] = COMBINED_FEATURES
    cnn_weights: str = ""
    meta: dict = field(default_factory=dict, compare=False)
    source: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        n = len(self.features)
        if tuple(self.features) != COMBINED_FEATURES:
            raise ValueError(f"decision model features {list(self.features)}: expected "
                             f"{list(COMBINED_FEATURES)}")
        if not (len(self.weights) == len(self.mean) == len(self.std) == n):
            raise ValueError(f"decision model: {n} features need {n} weights, means and stds")
        vals = (self.intercept, self.threshold) + tuple(self.weights) + tuple(self.mean) + tuple(self.std)
        if not all(math.isfinite(v) for v in vals) or min(self.std) <= 0.0:
            raise ValueError("decision model: non-finite coefficient or non-positive std")
        if not 0.0 < self.threshold < 1.0:
            raise ValueError(f"decision model threshold {self.threshold}: expected in (0, 1)")
        object.__setattr__(self, "_w", np.asarray(self.weights, dtype=np.float64)
                           / np.asarray(self.std, dtype=np.float64))
        object.__setattr__(self, "_b", float(self.intercept - np.dot(self._w, self.mean)))

    def logit(self, x: np.ndarray) -> np.ndarray | float:
        """The model's log-odds of a false fix for feature rows ``x`` ((K,) or (N, K))."""
        return np.asarray(x, dtype=np.float64) @ self._w + self._b

    def p_false(self, x: np.ndarray) -> np.ndarray | float:
        z = np.clip(self.logit(x), -50.0, 50.0)
        return 1.0 / (1.0 + np.exp(-z))

    def decide(self, x: np.ndarray) -> tuple[Decision, float]:
        p = float(self.p_false(x))
        return (Decision.REJECT if p > self.threshold else Decision.ACCEPT), p

    @property
    def model_id(self) -> str:
        text = json.dumps([self.intercept, list(self.weights), list(self.mean), list(self.std),
                           self.threshold], sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def to_dict(self) -> dict:
        return {"format_version": DECISION_MODEL_FORMAT, "rule": DecisionRule.COMBINED.value,
                "features": list(self.features), "intercept": self.intercept,
                "weights": list(self.weights), "mean": list(self.mean), "std": list(self.std),
                "threshold": self.threshold, "cnn_weights": self.cnn_weights,
                "model_id": self.model_id, "meta": self.meta}

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path | None = None) -> "CombinedDecisionModel":
        """Read a decision-model JSON (default: the shipped one). Raises UserError on a bad file."""
        from scenenav.core.errors import UserError
        p = Path(path) if path else DEFAULT_DECISION_MODEL
        try:
            d = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            raise UserError(f"decision model {p}: cannot read ({exc})") from None
        try:
            if d.get("format_version") != DECISION_MODEL_FORMAT or d.get("rule") != "combined":
                raise ValueError("not a combined decision model (format_version/rule)")
            return cls(intercept=float(d["intercept"]), weights=tuple(map(float, d["weights"])),
                       mean=tuple(map(float, d["mean"])), std=tuple(map(float, d["std"])),
                       threshold=float(d.get("threshold", 0.5)),
                       features=tuple(d.get("features", COMBINED_FEATURES)),
                       cnn_weights=str(d.get("cnn_weights", "")), meta=dict(d.get("meta", {})),
                       source=str(p))
        except (KeyError, TypeError, ValueError) as exc:
            raise UserError(f"decision model {p}: {exc}") from None

    def cnn_weights_path(self) -> Path | None:
        """The CNN weights file the model was fitted with (None when not recorded)."""
        if not self.cnn_weights:
            return None
        base = Path(self.source).parent if self.source else DEFAULT_DECISION_MODEL.parent
        return (base / self.cnn_weights).resolve()
