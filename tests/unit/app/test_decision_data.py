"""The decision-rule data path of the app layer: flight folders -> samples -> fitted model."""

from __future__ import annotations

import math

import numpy as np

from perception.decision import COMBINED_FEATURES, CombinedDecisionModel
from scenenav.app.decision_data import evaluate_flights, fit_decision, flight_dirs_under, flight_samples

K = len(COMBINED_FEATURES)


def _fake_flight(path, seed: int, n: int = 120):
    """A flight folder as the perception node and recorder write it: a straight track whose
    second half is a false lock (low peak, global search, 300 m off)."""
    from perception.assistant_map import AssistantMap
    rng = np.random.default_rng(seed)
    path.mkdir(parents=True)
    t = np.arange(n) * 0.1
    tx, ty = -50.0 + 10.0 * t, np.zeros(n)
    bad = np.arange(n) >= n // 2
    x = np.where(bad, tx + 300.0, tx + rng.normal(0, 0.2, n))
    y = ty + rng.normal(0, 0.2, n)
    mpp = 0.5
    u, v = x / mpp + 200.0, 100.0 - y / mpp
    peak = np.where(bad, rng.uniform(0.15, 0.35, n), rng.uniform(0.6, 0.9, n))
    lines = ["t_s,frame_seq,valid,accepted,x_m,y_m,p_bad"]
    lines += [f"{a:.3f},{i},1,1,{b:.3f},{c:.3f},{0.9 if k else 0.1}"
              for i, (a, b, c, k) in enumerate(zip(t, x, y, bad, strict=False))]
    (path / "fixes.csv").write_text("\n".join(lines) + "\n")
    (path / "truth.csv").write_text("t_s,x_m,y_m\n" + "\n".join(
        f"{a:.3f},{b:.3f},{c:.3f}" for a, b, c in zip(t, tx, ty, strict=False)) + "\n")
    cols = ("t_s,frame_seq,u_px,v_px,quality_ok,search,drone_u_px,drone_v_px,innovation_px,"
            "ncc_peak,ncc_psr,ncc_second_peak_ratio")
    rows = [f"{a:.3f},{i},{uu:.3f},{vv:.3f},{0 if k else 1},{'global' if k else 'window'},"
            f"{uu:.3f},{vv:.3f},{'nan' if k or i < 2 else 0.4},{pk:.3f},{3.0 if k else 9.0},"
            f"{0.95 if k else 0.3}"
            for i, (a, uu, vv, k, pk) in enumerate(zip(t, u, v, bad, peak, strict=False))]
    (path / "perception_diag_perception.csv").write_text(cols + "\n" + "\n".join(rows) + "\n")
    amap = AssistantMap(400, 200, mpp)
    amap.probability[:] = 0.5
    amap.save(path / "assistant_map_perception.npz")


def test_fit_decision_on_flight_folders(tmp_path):
    for k in range(3):
        _fake_flight(tmp_path / "flights" / f"w{k}", k)
        (tmp_path / "flights" / f"w{k}" / "summary.json").write_text("{}")
    dirs = flight_dirs_under(tmp_path)
    assert [d.name for d in dirs] == ["w0", "w1", "w2"]
    s = flight_samples(dirs[0])
    assert s.y.sum() == 60 and s.features["cnn"].shape == (120, K)
    assert s.features["assistant-map"].shape == (120, K)
    f = dict(zip(COMBINED_FEATURES, s.features["cnn"][100], strict=False))
    assert f["no_track"] == 1.0 and f["dr_innov"] > math.log(100.0)   # far from the anchor
    out = tmp_path / "model.json"
    model = fit_decision(dirs, out, "", data_manifest={"command": "test"})
    loaded = CombinedDecisionModel.load(out)
    assert loaded.model_id == model.model_id and loaded.meta["data"] == {"command": "test"}
    assert loaded.meta["training_worlds"] == ["w0", "w1", "w2"]
    res = evaluate_flights(loaded, dirs[:1])["w0"]["assistant-map"]["combined"]
    assert res["recall"] == 1.0 and res["precision"] == 1.0
    # deterministic
    assert fit_decision(dirs, tmp_path / "again.json", "").model_id == model.model_id


# ------------------------------------------------------------------ decision-data flight options
def test_held_out_and_default_world_seeds_are_refused():
    import pytest

    from scenenav.app.decision_data import check_training_seeds
    from scenenav.core.errors import UserError
    check_training_seeds((101, 110, 8999))
    for seeds in ((0,), (101, 9001), (9102,), (9050,), (12345,)):
        with pytest.raises(UserError, match="reserved for held-out"):
            check_training_seeds(seeds)


def _captured_flight(monkeypatch, **kwargs) -> tuple[str, ...]:
    """The ``--set`` items ``fly_cnn`` hands to the launcher (no flight is flown)."""
    import scenenav.app.launcher as launcher
    from scenenav.app import decision_data
    seen = {}
    monkeypatch.setattr(launcher, "run", lambda scenario, run_dir, sets, progress=False:
                        seen.setdefault("sets", sets) and {})
    decision_data.fly_cnn(None, "unused", **kwargs)
    return seen["sets"]


def test_decision_data_flies_the_table2_flight(monkeypatch):
    """The autopilot mission on the profile, exactly the sets table2 flies (plus method cnn), and
    the overrides last; --scripted keeps the old kinematic flight."""
    from scenenav.app.experiment import table2_scenario
    from scenenav.app.scenario import FlightMode, load_scenario
    sets = _captured_flight(monkeypatch, realism="realistic", scripted=False,
                            overrides=("sim.wind.gust_std_m_s=0",))
    table2_sets, _cfg, _world = table2_scenario(None, 0, "realistic", False)
    assert list(sets[:len(table2_sets)]) == table2_sets
    assert sets[-1] == "sim.wind.gust_std_m_s=0" and "perception.method=cnn" in sets
    cfg = load_scenario(None, sets)
    assert cfg.flight.mode is FlightMode.AUTOPILOT and cfg.sim.gps.enabled
    assert cfg.perception.method == "cnn" and cfg.perception.heading_learning   # the profile's
    assert cfg.sim.wind.gust_std_m_s == 0.0                                      # the override's
    old = load_scenario(None, _captured_flight(monkeypatch, scripted=True))
    assert old.flight.mode is FlightMode.SCRIPTED and old.realism.value == "ideal"
    assert old.flight.route_enu_m == cfg.flight.route_enu_m          # the same bowtie


def test_a_data_folder_holds_one_kind_of_flight(tmp_path):
    import json

    import pytest

    from scenenav.app.decision_data import collect
    from scenenav.core.errors import UserError
    (tmp_path / "manifest.json").write_text(json.dumps(
        {"realism": "realistic", "flight": "autopilot", "overrides": []}))
    with pytest.raises(UserError, match="holds realistic/autopilot flights"):
        collect(tmp_path, (101,), realism="paper", scripted=False)
    with pytest.raises(UserError, match="reserved"):
        collect(tmp_path / "new", (9201,), realism="realistic", scripted=False)


def test_autopilot_flight_samples_are_the_survey_fixes(tmp_path):
    """An autopilot flight's samples are the fixes within the survey band of its altitude (what
    table2 scores); a scripted one (or one without scenario.yaml) keeps every valid fix."""
    d = tmp_path / "w0"
    _fake_flight(d, 0)
    all_samples = flight_samples(d)
    n = len(all_samples.y)
    lines = (d / "truth.csv").read_text().splitlines()
    z = [30.0 if i < 20 else 100.0 for i in range(len(lines) - 1)]    # climbing for the first 20
    (d / "truth.csv").write_text("\n".join([lines[0] + ",z_m"] + [f"{ln},{zz}" for ln, zz in
                                                                  zip(lines[1:], z, strict=True)]) + "\n")
    (d / "scenario.yaml").write_text("flight:\n  mode: autopilot\n  altitude_m: 100.0\n")
    survey = flight_samples(d)
    assert len(survey.y) == n - 20 and survey.t_s[0] > all_samples.t_s[19]
    # the run and anchor features are those of the whole sequence, only selected
    assert np.array_equal(survey.features["cnn"], all_samples.features["cnn"][20:])
    (d / "scenario.yaml").write_text("flight:\n  mode: scripted\n  altitude_m: 100.0\n")
    assert len(flight_samples(d).y) == n
