"""Campaign files -> planned runs: cross product, random draws, repeats, stable ids (no flights)."""

from __future__ import annotations

import copy
import hashlib
import json
import os
import subprocess
import sys

import pytest
import yaml
from support import REPO_ROOT

import scenenav.app.scenario
from scenenav.app.campaign_spec import (
    canonical_scenario_text,
    default_scenario,
    derived_seed,
    expand,
    load_campaign,
    plan_json,
    run_id_of,
)
from scenenav.core.errors import UserError


def _campaign(tmp_path, **keys):
    (tmp_path / "base.yaml").write_text(yaml.safe_dump({"name": "b", "seed": 5, "duration_s": 20}))
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"base": "base.yaml", **keys}, sort_keys=False))
    return load_campaign(path)


def test_grid_is_the_cross_product_in_file_order_with_set_applied(tmp_path):
    runs = expand(_campaign(tmp_path, set={"duration_s": 30},
                            grid={"perception.method": ["none", "statistical"], "seed": [1, 2, 3]}))
    assert [dict(r.point) for r in runs] == [{"perception.method": m, "seed": s}
                                             for m in ("none", "statistical") for s in (1, 2, 3)]
    assert all(r.scenario["duration_s"] == 30.0 for r in runs)
    assert [(r.scenario["perception"]["method"], r.scenario["seed"]) for r in runs] == \
        [(dict(r.point)["perception.method"], dict(r.point)["seed"]) for r in runs]


def test_ids_are_stable_and_depend_only_on_the_resolved_scenario(tmp_path):
    a = expand(_campaign(tmp_path, grid={"seed": [1, 2]}))
    b = expand(_campaign(tmp_path, grid={"seed": [2, 1]}))
    assert {r.run_id for r in a} == {r.run_id for r in b} and len({r.run_id for r in a}) == 2
    c = expand(_campaign(tmp_path, set={"duration_s": 20.0}, grid={"seed": [1, 2]}))   # base says 20 already
    assert {r.run_id for r in c} == {r.run_id for r in a}


def _with_new_keys(d: dict) -> dict:
    """``d`` as a later scenenav would resolve it: a new top-level key, a new key in a section and a new
    section, each at its default."""
    d = copy.deepcopy(d)
    d["new_top_key_s"] = 2.5
    d["sim"]["wind"]["new_turbulence_scale"] = [1.0, 1.0]
    d["new_section"] = {"enabled": False, "gain": 0.3, "inner": {"mode": "off"}}
    return d


def test_a_new_key_at_its_default_keeps_every_id_and_derived_seed(tmp_path):
    runs = expand(_campaign(tmp_path, grid={"sim.wind.gust_std_m_s": [0.0, 1.5]}, repeat=2,
                            set={"autopilot.params": {"EK3_WIND_P_NSE": 0.7}}))
    defaults, new_defaults = default_scenario(), _with_new_keys(default_scenario())
    for r in runs:
        assert run_id_of(_with_new_keys(r.scenario), new_defaults) == run_id_of(r.scenario, defaults) == r.run_id
        for rep in (0, 1, 7):
            assert derived_seed(_with_new_keys(r.scenario), rep, new_defaults) == derived_seed(r.scenario, rep, defaults)


def test_a_new_key_in_the_schema_keeps_the_planned_ids_and_seeds(tmp_path, monkeypatch):
    """End to end: every resolved scenario and the defaults gain the keys, as on a later scenenav."""
    spec = _campaign(tmp_path, grid={"perception.method": ["none", "statistical"]}, repeat=3)
    before = [(r.run_id, r.overrides) for r in expand(spec)]
    to_dict = scenenav.app.scenario.scenario_to_dict
    monkeypatch.setattr(scenenav.app.scenario, "scenario_to_dict", lambda cfg: _with_new_keys(to_dict(cfg)))
    assert "new_section" in default_scenario()
    after = expand(spec)
    assert [(r.run_id, r.overrides) for r in after] == before and "new_section" in after[0].scenario


def test_the_canonical_text_names_only_what_differs_from_the_defaults():
    defaults = default_scenario()
    assert canonical_scenario_text(defaults) == "{}"
    assert run_id_of(defaults) == hashlib.sha256(b"{}").hexdigest()[:12]   # the same on every version
    s = copy.deepcopy(defaults)
    s["seed"], s["sim"]["wind"]["gust_std_m_s"] = 5, 0.7
    assert json.loads(canonical_scenario_text(s)) == {"seed": 5, "sim": {"wind": {"gust_std_m_s": 0.7}}}


@pytest.mark.parametrize("change", [
    lambda d: d.update(seed=d["seed"] + 1),                                      # a top-level value
    lambda d: d.update(new_top_key_s=3.0),                                       # a new key set off its default
    lambda d: d["new_section"].update(gain=0.4),                                 # ... in a new section
    lambda d: d["sim"]["wind"].update(gust_std_m_s=d["sim"]["wind"]["gust_std_m_s"] + 0.1),   # nested
    lambda d: d["sim"]["wind"]["mean_velocity_enu_m_s"].__setitem__(1, 2.0),     # one element of a list
    lambda d: d["new_section"]["inner"].update(mode="on"),                       # two levels down
    lambda d: d["autopilot"]["params"].update(EK3_WIND_P_NSE=0.7),               # a free-form mapping
    lambda d: d["flight"].update(mode="autopilot" if d["flight"]["mode"] != "autopilot" else "scripted"),
])
def test_any_value_off_the_defaults_changes_the_id_and_the_seeds(change):
    defaults = _with_new_keys(default_scenario())
    base = copy.deepcopy(defaults)
    base["seed"], base["duration_s"] = 5, 20.0
    changed = copy.deepcopy(base)
    change(changed)
    assert changed != base
    assert run_id_of(changed, defaults) != run_id_of(base, defaults)
    assert derived_seed(changed, 0, defaults) != derived_seed(base, 0, defaults)


def test_a_key_dropped_from_a_mapping_of_the_defaults_changes_the_id():
    defaults = default_scenario()
    defaults["autopilot"]["params"] = {"EK3_WIND_P_NSE": 0.2, "SN_VIS_DR_MAX": 4.0}
    dropped = copy.deepcopy(defaults)
    del dropped["autopilot"]["params"]["SN_VIS_DR_MAX"]
    kept = copy.deepcopy(defaults)
    kept["autopilot"]["params"]["EK3_WIND_P_NSE"] = 0.7
    dropped["autopilot"]["params"]["EK3_WIND_P_NSE"] = 0.7
    assert len({run_id_of(defaults, defaults), run_id_of(dropped, defaults), run_id_of(kept, defaults)}) == 3


def test_the_same_spec_gives_the_same_ids_in_two_invocations(tmp_path):
    """Two processes (different hash seeds) plan the same runs, ids and derived seeds."""
    _campaign(tmp_path, grid={"sim.wind.gust_std_m_s": [0.0, 1.5]}, repeat=2,
              random={"draws": 2, "seed": 3, "keys": {"sim.baro.noise_std_m": {"uniform": [0, 1]}}})
    code = ("import json, sys; from scenenav.app.campaign_spec import expand, load_campaign, plan_json; "
            "s = load_campaign(sys.argv[1]); print(json.dumps(plan_json(s, expand(s), cwd='.')['runs']))")
    plans = [json.loads(subprocess.run([sys.executable, "-c", code, str(tmp_path / "c.yaml")], check=True,
                                       capture_output=True, text=True, timeout=120, cwd=REPO_ROOT,
                                       env={**os.environ, "PYTHONHASHSEED": str(h)}).stdout)
             for h in (1, 2)]
    spec = load_campaign(tmp_path / "c.yaml")
    assert plans[0] == plans[1] == plan_json(spec, expand(spec), cwd=".")["runs"]
    assert len({r["id"] for r in plans[0]}) == 8


def test_bundles_set_several_keys_under_one_label(tmp_path):
    runs = expand(_campaign(tmp_path, grid={"noise": {"low": {"sim.baro.noise_std_m": 0.1},
                                                      "high": {"sim.baro.noise_std_m": 0.9,
                                                               "sim.compass.noise_std_rad": 0.03}}}))
    assert [dict(r.point)["noise"] for r in runs] == ["low", "high"]
    assert runs[1].scenario["sim"]["compass"]["noise_std_rad"] == 0.03
    assert runs[0].scenario["sim"]["baro"]["noise_std_m"] == 0.1


def test_random_draws_are_seeded_and_repeat_derives_distinct_seeds(tmp_path):
    spec = _campaign(tmp_path, random={"draws": 3, "seed": 7,
                                       "keys": {"sim.wind.gust_std_m_s": {"uniform": [0, 2]},
                                                "perception.method": {"choice": ["none", "statistical"]}}},
                     repeat=4)
    runs = expand(spec)
    assert len(runs) == 12 and runs == expand(spec)
    gusts = {dict(r.point)["sim.wind.gust_std_m_s"] for r in runs}
    assert len(gusts) == 3 and all(0 <= g <= 2 for g in gusts)
    assert len({r.scenario["seed"] for r in runs}) == 12
    assert [r.run_id for r in expand(spec, max_repeat=1)] == [r.run_id for r in runs if dict(r.point)["repeat"] == 0]


@pytest.mark.parametrize("keys, message", [
    ({"grid": {"seed": [1, 1]}}, "resolve to the same scenario"),
    ({"repeat": 0}, "repeat = 0"),
    ({"group_by": ["wind"], "grid": {"seed": [1]}}, "not swept"),
    ({"random": {"draws": 2, "keys": {"seed": {"randint": [5, 1]}}}}, "low <= high"),
])
def test_bad_plans_are_one_line_errors(tmp_path, keys, message):
    with pytest.raises(UserError, match=message):
        expand(_campaign(tmp_path, **keys))


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO_ROOT / "campaigns").glob("*.yaml")))
def test_every_shipped_campaign_expands(name):
    """A shipped campaign resolves into distinct runs of valid scenarios (what `scenenav campaign`
    checks before any flight), and its report is where docs/campaigns.md says."""
    runs = expand(load_campaign(REPO_ROOT / "campaigns" / name))
    assert runs and len({r.run_id for r in runs}) == len(runs)
    assert (REPO_ROOT / "docs" / "campaign-reports" / name.removesuffix(".yaml") / "report.md").is_file()
