"""perception.decision_rule in a scenario selects the rule the perception node flies."""

import csv
import subprocess
import sys

import pytest
from support import REPO_ROOT

ROOT = REPO_ROOT


@pytest.mark.parametrize("rule", ["paper", "combined"])
def test_scenario_key_selects_the_decision_rule(tmp_path, rule):
    out = tmp_path / rule
    r = subprocess.run([sys.executable, "-m", "scenenav.app.cli", "run", "--out", str(out), "--quiet",
                        "--set", "duration_s=6", "--set", "perception.method=cnn",
                        "--set", f"perception.decision_rule={rule}"],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    with (out / "perception_diag_perception.csv").open(newline="") as f:
        rows = [x for x in csv.DictReader(f) if x["valid"] == "1"]
    assert len(rows) > 20
    assert {x["rule"] for x in rows} == {rule}


def test_combined_rule_refuses_a_cnn_weights_file(tmp_path):
    r = subprocess.run([sys.executable, "-m", "scenenav.app.cli", "run", "--out", str(tmp_path / "x"),
                        "--set", "perception.decision_rule=combined",
                        "--set", "perception.weights=perception/weights/default.pt"],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "decision_model" in r.stderr
