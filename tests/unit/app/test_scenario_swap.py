"""perception.swap_at_s: the launcher swaps the perception node in flight (make-before-break)."""

import csv
import json
import subprocess
import sys

import pytest
from support import REPO_ROOT

ROOT = REPO_ROOT


# The clock is paced (realtime, 4x): the swap starts a new process at 8 s of simulated time, and it must
# be up before the flight ends. In lockstep the flight's wall time is whatever the machine allows (70 s
# in about 8 s on a quiet machine, less as the simulator gets faster), which a node starting on a loaded
# machine lost: perception-2 came up after the flight had ended and the test failed.
PACED = ["--set", "clock.mode=realtime", "--set", "clock.speed_factor=4"]


def test_scenario_swaps_perception_in_flight(tmp_path):
    out = tmp_path / "swap"
    r = subprocess.run([sys.executable, "-m", "scenenav.app.cli", "run", str(ROOT / "scenarios" / "perception_swap.yaml"),
                        "--out", str(out), "--quiet", "--set", "flight.mode=scripted", *PACED,
                        "--set", "duration_s=70", "--set", "perception.swap_at_s=8",
                        "--set", "perception.method=statistical", "--set", "perception.swap_method=none"],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    with (out / "fixes.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    first = [float(x["t_s"]) for x in rows if x["node_id"] == "perception"]
    second = [float(x["t_s"]) for x in rows if x["node_id"] == "perception-2"]
    assert first and second
    assert min(second) >= 8.0 - 0.2                 # the new node starts at the swap time ...
    assert max(first) < max(second) - 5.0          # ... and the old one stops while the flight goes on
    assert {x["method"] for x in rows if x["node_id"] == "perception-2"} == {"none"}
    events = (out / "events.csv").read_text()
    assert "perception-2" in events
    pids = json.loads((out / "logs" / "pids.json").read_text())
    assert "perception-2" in pids and (out / "logs" / "perception-2.log").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sim_time_s"] == pytest.approx(70.0, abs=0.5)
    assert "failed_nodes" not in summary
