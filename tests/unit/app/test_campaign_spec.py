"""Campaign files -> planned runs: cross product, random draws, repeats, stable ids (no flights)."""

from __future__ import annotations

import pytest
import yaml
from support import REPO_ROOT

from scenenav.app.campaign_spec import expand, load_campaign
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
