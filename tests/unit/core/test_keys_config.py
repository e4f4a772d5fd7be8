"""Key expressions, scenario config loading and one-line config errors."""

import pytest
from support import REPO_ROOT

from scenenav.app.scenario import FlightMode, load_scenario
from scenenav.core.config import ConfigError, apply_overrides
from scenenav.core.contracts import LockstepRole
from scenenav.core.errors import UserError
from scenenav.core.keys import Keys, type_for_key


def test_keys_are_namespaced_and_typed():
    a, b = Keys("run-a"), Keys("run-b")
    assert a.imu != b.imu and a.imu.startswith("scenenav/run-a/")
    assert a.truth_pose.startswith("scenenav/run-a/truth/")
    assert type_for_key(a, a.vision_fix("p1")) == "VisionFix"
    assert type_for_key(a, a.camera) == "CameraFrame"
    assert type_for_key(a, a.lockstep_member(LockstepRole.CAMERA, "p1")) is None
    assert type_for_key(a, b.imu) is None
    with pytest.raises(ValueError):
        Keys("bad/ns")
    with pytest.raises(ValueError):
        a.vision_fix("x*")


def test_defaults_load():
    cfg = load_scenario(None)
    assert cfg.flight.mode == FlightMode.SCRIPTED
    assert cfg.sim.camera.width_px == 200 and cfg.sim.camera.fov_deg == 60.0


def test_yaml_and_overrides(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("name: t\nduration_s: 12\nflight:\n  speed_m_s: 8\n")
    cfg = load_scenario(p, ("perception.method=statistical", "clock.tick_rate_hz=50"))
    assert cfg.name == "t" and cfg.duration_s == 12 and cfg.flight.speed_m_s == 8
    assert cfg.perception.method == "statistical" and cfg.clock.tick_rate_hz == 50


@pytest.mark.parametrize("text,needle", [
    ("bogus_key: 1\n", "unknown key 'bogus_key'"),
    ("flight:\n  altitude_m: -5\n", "flight.altitude_m"),
    ("duration_s: abc\n", "duration_s"),
    ("perception:\n  method: magic\n", "perception.method"),
    ("clock:\n  mode: warp\n", "clock.mode"),
    ("flight:\n  nope: 1\n", "unknown key 'flight.nope'"),
    ("- a\n- b\n", "mapping"),
    ("a: [\n", "not valid YAML"),
    ("duration_s: .inf\n", "positive, finite"),
    ("duration_s: 10\nduration_s: 20\n", "key 'duration_s' appears twice (lines 1 and 2)"),
])
def test_bad_scenarios_give_one_line_errors(tmp_path, text, needle):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(UserError) as exc:
        load_scenario(p)
    msg = str(exc.value)
    assert needle in msg and "\n" not in msg
    assert str(p) in msg


def test_missing_file():
    with pytest.raises(UserError, match="no such file"):
        load_scenario("/nonexistent/x.yaml")


def test_override_syntax():
    with pytest.raises(ConfigError):
        apply_overrides({}, ["novalue"])
    assert apply_overrides({"a": {"b": 1}}, ["a.b=2", "c=x"]) == {"a": {"b": 2}, "c": "x"}
    for bad in ("name=@x", "duration_s=[1,2", "a={b", 'a="open'):
        with pytest.raises(ConfigError, match="not valid YAML") as exc:
            apply_overrides({}, [bad])
        assert "\n" not in str(exc.value)


def test_numbers_with_an_exponent_are_numbers(tmp_path):
    # YAML 1.1 (PyYAML) reads 1e-4 as a string; ArduPilot parameters are often written so
    assert apply_overrides({}, ["a=1e-4", "b=2E5", "c=-3e+2", "d=1e", "e=x1e5"]) == \
        {"a": 1e-4, "b": 2e5, "c": -300.0, "d": "1e", "e": "x1e5"}
    p = tmp_path / "s.yaml"
    p.write_text("name: t\nduration_s: 1e2\nautopilot:\n  params: {EK3_GBIAS_P_NSE: 1e-4}\n")
    cfg = load_scenario(p)
    assert cfg.duration_s == 100.0


def test_every_shipped_scenario_loads():
    """Each file in scenarios/ is a valid scenario (what `scenenav run FILE` checks first)."""

    from scenenav.app.scenario import load_scenario
    files = sorted((REPO_ROOT / "scenarios").glob("*.yaml"))
    assert {f.stem for f in files} >= {"demo", "logging_flight", "scripted_loop", "gps_denied", "guided_route",
                                      "perception_swap", "paper_experiment"}
    for f in files:
        cfg = load_scenario(f)
        assert cfg.name == f.stem, f


def test_autopilot_params_mapping_round_trips():
    from scenenav.app.scenario import ScenarioConfig, load_scenario
    from scenenav.core.config import to_dict
    cfg = load_scenario(None, ("autopilot.params={LAND_SPEED: 100, WPNAV_SPEED_DN: 300}",))
    assert cfg.autopilot.params == {"LAND_SPEED": 100.0, "WPNAV_SPEED_DN": 300.0}
    from scenenav.core.config import load_config
    again = load_config(ScenarioConfig, to_dict(cfg))
    assert again.autopilot.params == cfg.autopilot.params
