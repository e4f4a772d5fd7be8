"""The navigation decision of the paper (section 5.4) and the false-match detection methods.

A fix is rejected when the probability of class 1 (bad matching area) is greater than 0.5, "no matter
what the overall CNN result is"; otherwise it is accepted. A probability of exactly 0.5 is accepted
(the paper rejects only when P(bad) > 0.5).

Classifier outputs come in two shapes and both are understood by :func:`split_classifier_output`:
``(N,)`` = P(bad) per image, or ``(N, K)`` = softmax over the paper's classes with column 0 = class 1
(bad area) and columns 1.. = the good-area classes (4-, 3-, 2-arm intersections).
"""

from __future__ import annotations

import math
from enum import Enum

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


def decide_from_p_true(p_true: float, threshold: float = P_BAD_THRESHOLD) -> Decision:
    """Same rule expressed on the assistant-map value p_true = 1 - P(bad)."""
    if not math.isfinite(p_true):
        raise ValueError(f"p_true = {p_true!r}: expected a probability in [0, 1]")
    return decide_from_p_bad(1.0 - p_true, threshold)


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
