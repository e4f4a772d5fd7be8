"""Realism profiles: each profile's values, the file and --set win over the profile, bad names fail."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from scenenav.app.realism import PAPER_SETTINGS, PROFILES, REALISTIC_SETTINGS, Realism, apply_realism
from scenenav.app.scenario import FlightMode, ScenarioConfig, load_scenario, scenario_to_dict
from scenenav.core.errors import UserError


def _value(cfg, dotted: str):
    node = cfg
    for part in dotted.split("."):
        node = getattr(node, part)
    return node.value if hasattr(node, "value") and not isinstance(node, (int, float)) else node


def test_ideal_is_todays_defaults_exactly():
    assert scenario_to_dict(load_scenario(None)) == scenario_to_dict(ScenarioConfig())
    assert scenario_to_dict(load_scenario(None, ("realism=ideal",))) == scenario_to_dict(ScenarioConfig())


@pytest.mark.parametrize("realism", [Realism.PAPER, Realism.REALISTIC])
def test_every_profile_setting_reaches_the_scenario(realism):
    cfg = load_scenario(None, (f"realism={realism.value}",))
    assert cfg.realism is realism
    for dotted, value in PROFILES[realism].items():
        got = _value(cfg, dotted)
        want = tuple(value) if isinstance(value, list) else value
        assert got == want, dotted


def test_realistic_is_paper_plus_its_own_settings():
    realistic = PROFILES[Realism.REALISTIC]
    for key in PAPER_SETTINGS:
        assert key in realistic
    for key, value in REALISTIC_SETTINGS.items():
        assert realistic[key] == value
    cfg = load_scenario(None, ("realism=realistic",))
    assert cfg.flight.mode is FlightMode.AUTOPILOT and cfg.perception.reference == "perspective"
    assert cfg.sim.compass.distorted and cfg.sim.wind.mean_velocity_enu_m_s == (5.0, 0.0, 0.0)


def test_set_and_file_keys_win_over_the_profile(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("realism: paper\nflight:\n  mode: scripted\nsim:\n  baro:\n    noise_std_m: 0.9\n")
    cfg = load_scenario(path, ("sim.gps.horizontal_noise_std_m=2.5",))
    assert cfg.flight.mode is FlightMode.SCRIPTED            # the file wins
    assert cfg.sim.baro.noise_std_m == 0.9                   # the file wins
    assert cfg.sim.gps.horizontal_noise_std_m == 2.5         # --set wins
    assert cfg.perception.reference == "perspective"         # the rest comes from the profile
    assert cfg.sim.gps.vertical_noise_std_m == PAPER_SETTINGS["sim.gps.vertical_noise_std_m"]


def test_set_can_choose_the_profile_and_a_resolved_scenario_reloads_the_same(tmp_path):
    import yaml
    cfg = load_scenario(None, ("realism=realistic", "sim.compass.anomaly_mgauss=0"))
    assert cfg.sim.compass.anomaly_mgauss == 0.0
    path = tmp_path / "resolved.yaml"
    path.write_text(yaml.safe_dump(scenario_to_dict(cfg)))
    assert scenario_to_dict(load_scenario(path)) == scenario_to_dict(cfg)


def test_unknown_profile_is_a_one_line_user_error():
    with pytest.raises(UserError, match="realism: 'gritty': expected one of ideal, paper, realistic"):
        apply_realism({"realism": "gritty"})


def test_unknown_profile_on_the_command_line_exits_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "scenenav.app.cli", "run", "--out", str(tmp_path / "x"),
                        "--set", "realism=gritty"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "realism" in lines[0] and "Traceback" not in r.stderr
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())


def test_decision_models_by_name_and_the_gps_denied_pin():
    """``perception.decision_model`` takes a shipped model by name; gps_denied.yaml pins the
    ideal-fitted one under every profile, its realistic twin the realistic refit."""
    from pathlib import Path

    from perception.decision import DEFAULT_DECISION_MODEL, REALISTIC_DECISION_MODEL, decision_model_path
    from scenenav.app.nodes import _perception_weights
    from scenenav.app.scenario import load_scenario
    assert decision_model_path("") == decision_model_path("ideal") == DEFAULT_DECISION_MODEL
    assert decision_model_path("realistic") == REALISTIC_DECISION_MODEL
    assert decision_model_path("my/model.json") == Path("my/model.json")
    root = Path(__file__).resolve().parents[3] / "scenarios"
    for overrides in ((), ("realism=paper",), ("realism=realistic",)):
        cfg = load_scenario(root / "gps_denied.yaml", overrides)
        assert _perception_weights(cfg.perception) == str(DEFAULT_DECISION_MODEL)
    twin = load_scenario(root / "gps_denied_realistic.yaml")     # keeps gps_denied.yaml's model
    assert _perception_weights(twin.perception) == str(DEFAULT_DECISION_MODEL)
    assert twin.realism == "realistic"
    paper = load_scenario(None, ("realism=paper",))
    assert _perception_weights(dataclasses.replace(paper.perception, decision_rule="combined")) \
        == str(REALISTIC_DECISION_MODEL)
