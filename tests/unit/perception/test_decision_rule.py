"""The combined decision rule: features, model file, fitting, dead reckoning, pipeline and node use."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from test_pipeline import ALT, MPP, cnn_fake, fly, render

from perception.config import PerceptionConfig, PerceptionNodeConfig
from perception.decision import (
    COMBINED_FEATURES,
    DEFAULT_DECISION_MODEL,
    CombinedDecisionModel,
    Decision,
    DecisionRule,
    FalseMatchMethod,
    TrackEvidence,
    combined_features,
)
from perception.decision_fit import choose_threshold, fit_logistic, make_model, rejection_scores
from perception.pipeline import PerceptionPipeline, Reason
from scenenav.core.errors import UserError

K = len(COMBINED_FEATURES)


def _model(intercept: float, threshold: float = 0.5, **w) -> CombinedDecisionModel:
    weights = tuple(float(w.get(f, 0.0)) for f in COMBINED_FEATURES)
    return CombinedDecisionModel(intercept=intercept, weights=weights, mean=(0.0,) * K,
                                 std=(1.0,) * K, threshold=threshold)


def test_features_known_and_unknown_parts():
    x = combined_features(0.5, 0.8, math.e, 0.3, 1.0, 9, 3.0, 2.0, 0.999, math.nan, 9.0)
    assert x.shape == (K,)
    f = dict(zip(COMBINED_FEATURES, x, strict=False))
    assert f["bad_logit"] == pytest.approx(0.0)
    assert f["log_psr"] == pytest.approx(1.0)
    assert f["innov"] == pytest.approx(math.log(2.0)) and f["no_track"] == 0.0
    assert f["log_run"] == pytest.approx(math.log(10.0))
    assert f["log_var30"] == pytest.approx(0.0) and f["log_var10"] == 0.0
    assert f["reach"] == pytest.approx(math.log(10.0))
    assert f["dr_innov"] == pytest.approx(math.log(4.0)) and f["dr_age"] == pytest.approx(math.log(3.0))
    assert f["no_dr"] == 0.0
    y = dict(zip(COMBINED_FEATURES, combined_features(1.0, 0.2, 2.0, 0.9, math.nan), strict=False))
    assert y["bad_logit"] == pytest.approx(math.log(0.995 / 0.005))
    assert y["no_track"] == 1.0 and y["innov"] == 0.0 and y["log_run"] == 0.0
    assert y["no_dr"] == 1.0 and y["dr_innov"] == 0.0 and y["reach"] == 0.0


def test_model_probability_threshold_and_file_round_trip(tmp_path):
    m = _model(-1.0, threshold=0.3, peak=-4.0, no_track=3.0)
    good = combined_features(0.1, 0.9, 10.0, 0.2, 0.2, 20)
    bad = combined_features(0.9, 0.2, 2.0, 0.95, math.nan)
    assert m.decide(good)[0] is Decision.ACCEPT
    d, p = m.decide(bad)
    assert d is Decision.REJECT and p == pytest.approx(1 / (1 + math.exp(-(-1.0 - 0.8 + 3.0))))
    path = tmp_path / "m.json"
    m.save(path)
    m2 = CombinedDecisionModel.load(path)
    assert m2 == m and m2.model_id == m.model_id
    assert float(m2.p_false(bad)) == pytest.approx(float(m.p_false(bad)))
    d = json.loads(path.read_text())
    d["weights"] = d["weights"][:-1]
    path.write_text(json.dumps(d))
    with pytest.raises(UserError, match="weights"):
        CombinedDecisionModel.load(path)
    with pytest.raises(UserError, match="cannot read"):
        CombinedDecisionModel.load(tmp_path / "missing.json")


def test_standardised_parametrisation_matches_raw_logit():
    rng = np.random.default_rng(0)
    m = CombinedDecisionModel(intercept=0.3, weights=tuple(rng.normal(size=K)),
                              mean=tuple(rng.normal(size=K)), std=tuple(rng.uniform(0.5, 2, K)))
    x = rng.normal(size=(5, K))
    z = (x - np.array(m.mean)) / np.array(m.std)
    assert np.allclose(m.logit(x), 0.3 + z @ np.array(m.weights))


def test_fit_logistic_separates_and_threshold_reaches_recall():
    rng = np.random.default_rng(1)
    n = 4000
    x = rng.normal(size=(n, K))
    logit = -1.0 + 3.0 * x[:, 1] - 2.0 * x[:, 4]
    y = rng.uniform(size=n) < 1 / (1 + np.exp(-logit))
    b0, w, mean, std = fit_logistic(x, y, l2=1.0)
    raw = np.asarray(w) / std
    assert raw[1] == pytest.approx(3.0, rel=0.2) and raw[4] == pytest.approx(-2.0, rel=0.2)
    assert abs(raw[0]) < 0.3
    m = make_model(x, y, 1.0)
    p = m.p_false(x)
    t = choose_threshold(p, y, 0.99)
    assert rejection_scores(y, p > t)["recall"] >= 0.99
    assert t <= 0.5


def test_track_evidence_runs_and_dead_reckoned_anchor():
    ev = TrackEvidence(min_run=3)
    assert ev.predict(1.0) is None
    # Two good matches: a run of 2, not established yet.
    assert ev.observe(0.0, (10.0, 20.0), True, True)[0] == 0
    assert ev.observe(0.1, (11.0, 20.0), True, False)[0] == 1
    assert ev.predict(0.2) is None
    run, dist, age, reach = ev.observe(0.2, (12.0, 20.0), True, False)  # established: anchor
    assert run == 2 and math.isnan(dist) and math.isnan(reach)
    (u, v), age = ev.predict(1.2)
    assert (u, v) == pytest.approx((22.0, 20.0)) and age == pytest.approx(1.0)
    # A low-quality match breaks the run but the anchor stays and measures it.
    run, dist, age, reach = ev.observe(0.3, (40.0, 20.0), False, False)
    assert run == 3 and dist == pytest.approx(27.0) and age == pytest.approx(0.1)
    # 28 px from the anchor position, reachable: 1.2 x 10 px/s x 0.1 s = 1.2 px -> 26.8 px beyond
    assert reach == pytest.approx(28.0 - 1.2)
    assert ev.observe(1.2, (21.0, 20.0), False, False)[3] < 0.0          # within reach
    assert ev.count == 0
    # A re-acquisition starts a new run; the anchor only moves once that run is established.
    ev.observe(0.4, (100.0, 0.0), True, True)
    ev.observe(0.5, (101.0, 0.0), True, False)
    assert ev.predict(0.5)[0] == pytest.approx((15.0, 20.0))
    ev.observe(0.6, (102.0, 0.0), True, False)
    assert ev.predict(0.6)[0] == pytest.approx((102.0, 0.0))
    ev.reset()
    assert ev.predict(0.6) is None and ev.count == 0


def _established_run(ev, velocity=None):
    """Three good matches moving 10 px/s east from (10, 20): an anchor at (12, 20) at t = 0.2 s."""
    for i in range(3):
        ev.observe(0.1 * i, (10.0 + i, 20.0), True, i == 0, velocity)


def test_track_evidence_dead_reckons_with_the_given_velocity():
    """A hold after the run: with the estimated velocity (0 px/s) the anchor stays with the vehicle
    and a match where the vehicle is measures 0 px; at the run's constant velocity it measured 18."""
    held = TrackEvidence(min_run=3)
    _established_run(held, (10.0, 0.0))
    old = TrackEvidence(min_run=3)
    _established_run(old)
    for t in (0.5, 1.0, 2.0):
        _, dist_held, age, _ = held.observe(t, (12.0, 20.0), False, False, (0.0, 0.0))
        _, dist_old, age_old, _ = old.observe(t, (12.0, 20.0), False, False)
        assert dist_held == pytest.approx(0.0, abs=1e-9)
        assert dist_old == pytest.approx(10.0 * (t - 0.2))
        assert age == pytest.approx(t - 0.2) == age_old


def test_track_evidence_follows_a_turn_step_by_step():
    """North at 5 px/s for 1 s after the run, then west at 5 px/s for 1 s: the anchor follows the
    velocities given, integrated from one match to the next."""
    ev = TrackEvidence(min_run=3)
    _established_run(ev, (10.0, 0.0))
    pos = [12.0, 20.0]
    t = 0.2
    for step in range(20):
        vel = (0.0, -5.0) if step < 10 else (-5.0, 0.0)
        t += 0.1
        pos = [pos[0] + vel[0] * 0.1, pos[1] + vel[1] * 0.1]
        _, dist, _, _ = ev.observe(t, tuple(pos), False, False, vel)
        assert dist == pytest.approx(0.0, abs=1e-6)
    assert pos == pytest.approx([7.0, 15.0])


def test_track_evidence_without_velocity_keeps_the_run_velocity():
    """A frame without an estimate (None) after velocities were given moves the anchor at the run's
    own velocity over that step; a new established run puts the anchor on its newest match."""
    ev = TrackEvidence(min_run=3)
    _established_run(ev, (10.0, 0.0))
    _, dist, _, _ = ev.observe(0.3, (12.0, 20.0), False, False, (0.0, 0.0))
    assert dist == pytest.approx(0.0, abs=1e-9)
    _, dist, _, _ = ev.observe(0.5, (12.0, 20.0), False, False, None)     # 10 px/s x 0.2 s
    assert dist == pytest.approx(2.0)
    for i, t in enumerate((0.6, 0.7, 0.8)):
        ev.observe(t, (50.0 + i, 0.0), True, i == 0, (10.0, 0.0))
    _, dist, _, _ = ev.observe(0.9, (53.0, 0.0), False, False, (10.0, 0.0))
    assert dist == pytest.approx(0.0, abs=1e-9)


def test_pipeline_paper_rule_is_the_default(world):
    ref, day = world
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.CNN, classify=cnn_fake)
    assert pipe.rule is DecisionRule.PAPER and pipe.decision_model is None
    r, _ = fly(pipe, day, 1)[0]
    assert r.decision_rule is DecisionRule.PAPER and math.isnan(r.p_false)


@pytest.mark.parametrize("method", [FalseMatchMethod.CNN, FalseMatchMethod.ASSISTANT_MAP])
def test_pipeline_combined_rule_uses_match_evidence(world, method):
    ref, day = world
    cfg = dataclasses.replace(PerceptionConfig(), decision_rule=DecisionRule.COMBINED)
    # Rejects what is not tracked (a global search) and trusts a long track, whatever P(bad) says.
    model = _model(-2.0, bad_logit=0.0, no_track=4.0, log_run=-1.0)
    pipe = PerceptionPipeline(ref, MPP, method, cfg, classify=cnn_fake, decision_model=model)
    assert pipe.rule is DecisionRule.COMBINED
    results = fly(pipe, day, 12)
    first = results[0][0]
    assert first.decision_rule is DecisionRule.COMBINED
    assert not first.accepted and first.reason is Reason.LIKELY_FALSE and first.p_false > 0.5
    assert math.isnan(first.innovation_px)
    late = results[-1][0]
    assert late.accepted and late.p_false < 0.5
    assert late.innovation_px < 2.0 and late.run >= 9
    assert late.dr_innovation_px < 2.0 and late.dr_age_s == pytest.approx(0.1, abs=1e-6)
    lake = pipe.process(render(day, 70.0, 200.0, 0.0), 0.0, ALT, 1.3)
    assert lake.valid and lake.p_true == pytest.approx(0.1)


def test_pipeline_combined_rule_loads_the_shipped_model(world):
    ref, _ = world
    cfg = dataclasses.replace(PerceptionConfig(), decision_rule=DecisionRule.COMBINED)
    pipe = PerceptionPipeline(ref, MPP, FalseMatchMethod.ASSISTANT_MAP, cfg, classify=cnn_fake)
    assert pipe.decision_model is not None
    assert pipe.decision_model.source == str(DEFAULT_DECISION_MODEL)
    assert pipe.decision_model.cnn_weights_path().is_file()
    stat = PerceptionPipeline(ref, MPP, FalseMatchMethod.STATISTICAL, cfg)
    assert stat.rule is DecisionRule.PAPER          # the rule only concerns cnn / assistant-map


def test_node_pipeline_rule_follows_the_weights_file(world):
    from types import SimpleNamespace

    from perception.node import make_pipeline
    ref, _ = world
    w = SimpleNamespace(reference=ref, m_per_px=MPP, width_px=ref.shape[1], height_px=ref.shape[0],
                        manifest=SimpleNamespace(name="t"), reference_map=lambda _kind=None: ref)
    settings = PerceptionNodeConfig(method="assistant-map")
    assert make_pipeline(w, settings).rule is DecisionRule.PAPER
    pipe = make_pipeline(w, settings, weights=str(DEFAULT_DECISION_MODEL))
    assert pipe.rule is DecisionRule.COMBINED
    assert pipe.cfg.decision_rule is DecisionRule.COMBINED


def test_table2_markdown_states_the_rule_of_each_row(tmp_path):
    from scenenav.app.experiment import flown_rule, table2_markdown
    run = tmp_path / "run-cnn"
    run.mkdir()
    (run / "perception_diag_perception.csv").write_text("t_s,rule\n0,combined\n0.1,combined\n")
    assert flown_rule(run) == "combined"
    assert flown_rule(tmp_path / "missing") == "—"
    base = {"rms_error_m": 0.3, "fix_time_ms_median": 2.0, "detected_false_pct": 100.0,
            "precision": 0.95, "recall": 0.99, "fixes_total": 10, "false_fixes": 2,
            "false_fixes_accepted": 0}
    md = table2_markdown({"world": "w", "threshold_m": 5.0, "rows": [
        {"method": "assistant-map", "rule": "combined", **base},
        {"method": "assistant-map", "rule": "paper", **base},
        {"method": "none", "rule": "—", **base}]})
    assert "| assistant-map | combined | 0.30 |" in md
    assert "| assistant-map | paper | 0.30 |" in md
    assert "| none | — |" in md
