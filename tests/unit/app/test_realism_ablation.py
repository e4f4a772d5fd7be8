"""The ablation harness's scoring (scenenav/app/realism_ablation.py) on hand-made frame records;
the flight itself is exercised by the documented runs, not here (minutes of simulation)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from scenenav.app.realism_ablation import FrameRecord, _History, estimate_errors, score
from scenenav.core.formats.world_manifest import ReferenceInfo

WORLD = SimpleNamespace(manifest=SimpleNamespace(reference=ReferenceInfo()))


def _rec(z: float, fix_err: float, accepted: bool = True, valid: bool = True) -> FrameRecord:
    r = FrameRecord(0.0, (10.0, 20.0, z), (0.0, 0.0), (0.0, 0.0), 0.0, 0.0, 0.0, z)
    r.fixes["node"] = (valid, accepted, 10.0 + fix_err, 20.0)
    r.estimate_xy_m = (10.0, 20.0 + fix_err / 2)
    return r


def test_score_counts_false_fixes_at_survey_altitude_only():
    recs = [_rec(100.0, 1.0), _rec(100.0, 3.0, accepted=False), _rec(100.0, 50.0),
            _rec(100.0, 9.0, accepted=False), _rec(100.0, 0.0, valid=False),
            _rec(40.0, 500.0)]                      # the climb: not scored
    s = score(recs, WORLD, 100.0)["node"]
    assert s["frames"] == 5 and s["fixes"] == 4 and s["false"] == 2
    assert s["false_share"] == pytest.approx(0.5)
    assert s["rms_all_m"] == pytest.approx(math.sqrt((1 + 9 + 2500 + 81) / 4))
    assert s["rms_accepted_m"] == pytest.approx(math.sqrt((1 + 2500) / 2))
    assert s["false_accepted"] == 1 and s["recall"] == pytest.approx(0.5) and s["precision"] == pytest.approx(0.5)
    assert s["median_m"] == pytest.approx(6.0)


def test_estimate_errors_over_the_survey():
    e = estimate_errors([_rec(100.0, 2.0), _rec(100.0, 6.0), _rec(30.0, 100.0)], 100.0)
    assert e["rms_m"] == pytest.approx(math.sqrt((1 + 9) / 2)) and e["max_m"] == pytest.approx(3.0)


def test_history_gives_the_newest_sample_at_or_before():
    h = _History()
    assert h.at(5) is None
    h.add(10, "a")
    h.add(20, "b")
    assert (h.at(5), h.at(10), h.at(19), h.at(25)) == ("a", "a", "a", "b")
