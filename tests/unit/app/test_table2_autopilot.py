"""Table 2 under the autopilot: the flight settings, the survey-altitude scoring, the results page
that keeps one column per realism profile."""

from __future__ import annotations

import json

import numpy as np

from scenenav.app.experiment import (
    MISSION_MARGIN_S,
    at_survey_altitude,
    flight_settings,
    route_length_m,
    update_results_page,
)
from scenenav.app.scenario import FlightMode, load_scenario

ROUTE = ((-100.0, -100.0), (100.0, -100.0), (-100.0, 100.0))


def test_autopilot_flight_settings_fly_the_route_as_a_mission_on_gps():
    cfg = load_scenario(None, tuple(flight_settings(ROUTE, 100.0, 10.0, scripted=False)))
    assert cfg.flight.mode is FlightMode.AUTOPILOT
    assert cfg.flight.route_enu_m == ROUTE and cfg.flight.start_enu_m == ROUTE[0]
    assert cfg.sim.gps.enabled and not cfg.guidance.enabled
    assert cfg.duration_s >= route_length_m(ROUTE) / 10.0 + MISSION_MARGIN_S - 1.0


def test_scripted_flight_settings_keep_the_old_kinematic_flight():
    cfg = load_scenario(None, tuple(flight_settings(ROUTE, 100.0, 10.0, scripted=True)))
    assert cfg.flight.mode is FlightMode.SCRIPTED and cfg.flight.route_enu_m == ROUTE


def test_profile_settings_stay_under_the_flight_settings():
    sets = ("realism=realistic", *flight_settings(ROUTE, 100.0, 10.0, scripted=True))
    cfg = load_scenario(None, sets)
    assert cfg.flight.mode is FlightMode.SCRIPTED             # --scripted wins over the profile
    assert cfg.sim.wind.mean_velocity_enu_m_s == (5.0, 0.0, 0.0)


def test_only_fixes_at_the_survey_altitude_are_scored():
    fx = {"t_s": np.arange(5.0), "truth_z_m": np.array([20.0, 95.0, 100.0, 109.0, 60.0]),
          "error_m": np.array([50.0, 1.0, 2.0, 3.0, 40.0])}
    kept = at_survey_altitude(fx, 100.0, 10.0)
    assert list(kept["t_s"]) == [1.0, 2.0, 3.0] and list(kept["error_m"]) == [1.0, 2.0, 3.0]


def _result(realism: str, rms: float) -> dict:
    row = {"rms_error_m": rms, "fix_time_ms_median": 2.0, "detected_false_pct": 100.0,
           "precision": 0.9, "recall": 1.0, "fixes_total": 10, "false_fixes": 2,
           "false_fixes_accepted": 0}
    return {"world": "default", "threshold_m": 5.0, "realism": realism, "flight": "autopilot",
            "decision_rule": "combined", "identical_frames": True,
            "rows": [{"method": m, "rule": "combined" if m in ("cnn", "assistant-map") else "—", **row}
                     for m in ("cnn", "assistant-map", "statistical", "none")]}


def test_results_page_keeps_one_column_per_profile(tmp_path):
    page = tmp_path / "docs" / "results.md"
    out = tmp_path / "run"
    out.mkdir()
    update_results_page(page, _result("ideal", 0.31), out, "scenenav experiment table2 --realism ideal")
    update_results_page(page, _result("realistic", 1.77), out, "scenenav experiment table2 --realism realistic")
    text = page.read_text()
    assert "| method | ideal-autopilot | realistic-autopilot | paper |" in text
    assert "| cnn | 0.31 / 100.0 / 0 | 1.77 / 100.0 / 0 |" in text
    assert "--realism realistic" in text
    # a new run of one profile replaces its own column only
    update_results_page(page, _result("realistic", 1.50), out, "scenenav experiment table2 --realism realistic")
    text = page.read_text()
    assert "| cnn | 0.31 / 100.0 / 0 | 1.50 / 100.0 / 0 |" in text
    stored = json.loads((page.parent / "table2-realistic-autopilot.json").read_text())
    assert stored["rows"][0]["rms_error_m"] == 1.50


def test_each_profile_flies_its_own_combined_rule_model():
    """paper and realistic select the model fitted on realistic flights (a file that loads and
    names the CNN it was fitted with); ideal keeps the shipped one; --set still wins."""
    from perception.decision import DEFAULT_DECISION_MODEL, REALISTIC_DECISION_MODEL, CombinedDecisionModel
    from scenenav.app.experiment import decision_model_for
    realistic = load_scenario(None, ("realism=realistic",))
    assert decision_model_for(realistic) == REALISTIC_DECISION_MODEL != DEFAULT_DECISION_MODEL
    model = CombinedDecisionModel.load(REALISTIC_DECISION_MODEL)
    assert model.cnn_weights_path().name == "matchability.pt" and model.cnn_weights_path().is_file()
    assert model.meta["data"]["realism"] == "realistic" and model.meta["data"]["flight"] == "autopilot"
    assert decision_model_for(load_scenario(None, ("realism=paper",))) == REALISTIC_DECISION_MODEL
    assert decision_model_for(load_scenario(None, ("realism=ideal",))) == DEFAULT_DECISION_MODEL
    mine = load_scenario(None, ("realism=realistic", f"perception.decision_model={DEFAULT_DECISION_MODEL}"))
    assert decision_model_for(mine) == DEFAULT_DECISION_MODEL
