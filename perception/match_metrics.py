"""Typed per-fix measurements: the NCC match quality metrics and the per-stage timings.

``MatchMetrics`` is what the matcher says about one correlation peak (docs/perception.md, "Quality
gate"); it travels into ``contracts.VisionFix`` as ``ncc_peak``, ``ncc_psr`` and
``ncc_second_peak_ratio``. ``StageTimes`` is the wall-clock time spent per pipeline stage (the
``time_*_ms`` columns of ``fixes.csv``; never part of the behaviour).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class MatchMetrics:
    """Quality of one NCC peak (NaN when no match was computed).

    ``peak``: the correlation value at the peak (-1..1). ``psr``: peak-to-sidelobe ratio, (peak -
    side-lobe mean) / side-lobe std. ``second_peak_ratio``: the highest other local maximum over the
    peak (0..1; 1 = ambiguous).
    """

    peak: float
    psr: float
    second_peak_ratio: float

    @classmethod
    def unknown(cls) -> MatchMetrics:
        """All NaN: no match computed."""
        return cls(math.nan, math.nan, math.nan)


@dataclass
class StageTimes:
    """Wall-clock milliseconds per stage of one fix (accumulated while the fix is computed).

    ``align``: rotate and scale the capture; ``ncc``: crop + correlation + peak refinement;
    ``cnn``: the classifier; ``lookup``: assistant-map lookup/write or the statistical detector;
    ``total``: the whole ``PerceptionPipeline.process`` call.
    """

    align_ms: float = 0.0
    ncc_ms: float = 0.0
    cnn_ms: float = 0.0
    lookup_ms: float = 0.0
    total_ms: float = 0.0


@dataclass(frozen=True)
class SearchTimes:
    """Wall-clock milliseconds of one ``SceneMatcher.match``: window crop, correlation, refinement."""

    crop_ms: float = 0.0
    ncc_ms: float = 0.0
    refine_ms: float = 0.0
