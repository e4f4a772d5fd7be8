"""``base:`` in a scenario YAML: the named scenario merged under it (the demo builds on gps_denied)."""

from __future__ import annotations

from pathlib import Path

import pytest

from scenenav.app.scenario import load_scenario, scenario_yaml
from scenenav.core.errors import UserError

SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"


def test_a_scenario_names_only_what_it_changes(tmp_path):
    (tmp_path / "a.yaml").write_text("name: a\nduration_s: 100\nflight: {mode: autopilot, altitude_m: 80}\n"
                                     "guidance: {enabled: true, goals_enu_m: [[1, 2], [3, 4]]}\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.yaml").write_text("base: ../a.yaml\nname: b\nflight: {altitude_m: 60}\n"
                                             "guidance: {goals_enu_m: [[5, 6]]}\n")
    data = scenario_yaml(tmp_path / "sub" / "b.yaml")
    assert data["flight"] == {"mode": "autopilot", "altitude_m": 60}      # mappings merge
    assert data["guidance"] == {"enabled": True, "goals_enu_m": [[5, 6]]}  # lists replace
    cfg = load_scenario(tmp_path / "sub" / "b.yaml", ("duration_s=50",))
    assert (cfg.name, cfg.duration_s, cfg.flight.altitude_m) == ("b", 50, 60)


def test_the_demo_follows_gps_denied():
    demo, base = load_scenario(SCENARIOS / "demo.yaml"), load_scenario(SCENARIOS / "gps_denied.yaml")
    assert demo.sim == base.sim and demo.perception == base.perception and demo.autopilot == base.autopilot
    assert not demo.sim.gps.enabled and demo.guidance.enabled and demo.flight == base.flight
    assert demo.guidance.clearance_m == base.guidance.clearance_m
    assert len(demo.guidance.goals_enu_m) < len(base.guidance.goals_enu_m)


@pytest.mark.parametrize("text, what", [("base: b.yaml\n", "cycle"), ("base: 3\n", "expected the path"),
                                        ("base: nowhere.yaml\n", "no such file")])
def test_a_bad_base_is_one_line(tmp_path, text, what):
    (tmp_path / "b.yaml").write_text(text)
    with pytest.raises(UserError, match=what):
        scenario_yaml(tmp_path / "b.yaml")
