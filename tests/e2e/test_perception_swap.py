"""Swapping the perception node while the vehicle flies: nothing restarts, the logs follow the
live node, the gap in fixes is logged."""

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

#: real-time SITL flights: `make test` runs them after the parallel part, apart from it
pytestmark = pytest.mark.realtime


def _wait_for(pred, timeout_s, what):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if pred():
            return
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


def _fix_nodes(run: Path) -> list[str]:
    p = run / "fixes.csv"
    if not p.exists():
        return []
    with p.open(newline="") as f:
        return [r["node_id"] for r in csv.DictReader(f)]


def test_swap_perception_node_in_flight(tmp_path):
    run = tmp_path / "swap"
    # paced at 2x: the second node is a process started by hand while the vehicle flies; a lockstep
    # flight's wall time is whatever the machine allows (30 s in a few seconds on a quiet machine), and
    # a node starting on a loaded machine came up after the flight had ended; 60 simulated s leave a
    # loaded machine time to start the second node and stop the first
    launcher = subprocess.Popen(
        [sys.executable, "-m", "scenenav.app.cli", "run", "--out", str(run), "--set", "duration_s=60",
         "--set", "perception.method=none", "--set", "clock.mode=realtime", "--set", "clock.speed_factor=2",
         "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    p2 = None
    try:
        _wait_for(lambda: len(_fix_nodes(run)) >= 20, 120, "fixes from the first node")
        meta = json.loads((run / "run.json").read_text())
        pids = json.loads((run / "logs" / "pids.json").read_text())
        p2_log = (run / "logs" / "perception-2.log").open("w")
        p2 = subprocess.Popen(
            [sys.executable, "-m", "scenenav.app.cli", "node", "perception", "--namespace", meta["namespace"],
             "--hub-port", str(meta["hub_port"]), "--run-dir", str(run), "--node-id", "perception-2",
             "--method", "statistical"], stdout=p2_log, stderr=subprocess.STDOUT)
        _wait_for(lambda: "perception-2" in _fix_nodes(run), 120, "fixes from the new node")
        # stop the original node: the run goes on with the new one
        subprocess.run(["kill", "-INT", str(pids["perception"])], check=True)
        n_before = len(_fix_nodes(run))
        _wait_for(lambda: len(_fix_nodes(run)) > n_before + 20, 120, "fixes after the swap")
        out, err = launcher.communicate(timeout=300)
        assert launcher.returncode == 0, err[-3000:]
    finally:
        if launcher.poll() is None:
            launcher.send_signal(signal.SIGINT)
            launcher.wait(60)
        if p2 is not None:
            p2.send_signal(signal.SIGINT)
            p2.wait(30)
    nodes = _fix_nodes(run)
    assert nodes[0] == "perception" and nodes[-1] == "perception-2"
    # the simulator never restarted: one continuous clock, the whole duration flown
    summary = json.loads((run / "summary.json").read_text())
    assert abs(summary["sim_time_s"] - 60.0) < 0.2
    assert (run / "logs" / "sim.log").read_text().count("simulation finished") == 1
    with (run / "events.csv").open(newline="") as f:
        events = [r["text"] for r in csv.DictReader(f)]
    changes = [e for e in events if e.startswith("fix source changed: perception -> perception-2")]
    assert len(changes) == 1 and "gap in fixes" in changes[0]
    assert any(e == "node down: perception/perception" for e in events)
    assert any(e == "node up: perception/perception-2" for e in events)
    # per-node results: two rows, each with its own method and figures; the headline names both
    rows = {r["node_id"]: r for r in summary["perception_nodes"]}
    assert list(rows) == ["perception", "perception-2"]
    assert rows["perception"]["method"] == "none" and rows["perception-2"]["method"] == "statistical"
    assert summary["perception_method"] == "none -> statistical"
    assert summary["fix_metrics_nodes"] == ["perception", "perception-2"]
    assert sum(r["fixes_total"] for r in rows.values()) == summary["fixes_total"]
    assert rows["perception"]["first_fix_s"] < rows["perception-2"]["first_fix_s"]
    assert rows["perception"]["last_fix_s"] < rows["perception-2"]["last_fix_s"]
    recorded = json.loads((run / "recorder_stats.json").read_text())["perception_nodes"]
    assert {n: r["fixes"] for n, r in recorded.items()} == {n: r["fixes_total"] for n, r in rows.items()}
    assert "pooled over 2 perception nodes" in out
    assert "perception node perception-2 (statistical)" in out
