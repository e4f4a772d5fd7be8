"""Bad campaign files: one ``error: ...`` line, exit code 2, before any flight starts."""

from __future__ import annotations

import pytest
from support.campaign_cli import SCRIPTED, start_campaign, write_campaign

BAD = {
    "unknown_key": ({"base": str(SCRIPTED), "grids": {"seed": [1]}}, "unknown key 'grids'"),
    "empty_grid": ({"base": str(SCRIPTED), "grid": {}}, "grid"),
    "empty_axis": ({"base": str(SCRIPTED), "grid": {"seed": []}}, "grid.seed: empty list"),
    "set_not_a_scenario_key": ({"base": str(SCRIPTED), "set": {"perception.methd": "cnn"}},
                               "unknown key 'perception.methd'"),
    "grid_not_a_scenario_key": ({"base": str(SCRIPTED), "grid": {"flight.speed": [5, 10]}},
                                "unknown key 'flight.speed'"),
    "bad_value": ({"base": str(SCRIPTED), "grid": {"flight.speed_m_s": [5, 100]}}, "speed_m_s"),
    "bad_distribution": ({"base": str(SCRIPTED), "random": {"draws": 3, "keys": {"seed": {"gauss": [0, 1]}}}},
                         "unknown distribution 'gauss'"),
    "missing_base": ({"base": "nowhere.yaml"}, "no such scenario file"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_campaign_file_is_one_line_and_exit_2(tmp_path, case):
    content, expected = BAD[case]
    campaign = write_campaign(tmp_path / "bad.yaml", **content)
    out = tmp_path / "out"
    proc = start_campaign(campaign, out)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    assert expected in lines[0] and "bad.yaml" in lines[0]
    assert "Traceback" not in stderr
    assert not out.exists()                              # nothing planned, nothing flown
