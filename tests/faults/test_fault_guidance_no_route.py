"""A mission the guidance node cannot plan (every goal on a bad matching area) is a failed node: the
run's summary names it, the launcher stops the run at once (the vehicle never armed: nothing would
fly) and ``scenenav run`` exits 1, instead of the run idling on the ground to its duration with
"duration reached" as its only word (seen on fresh world 10034: 600 simulated seconds, 229 s of
wall time, for nothing)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np


def test_no_route_is_a_failed_guidance_node(tmp_path):
    from perception.assistant_map import AssistantMap
    from worlds.default import load_default_world
    world = load_default_world()
    bad = AssistantMap(world.width_px, world.height_px, world.m_per_px, world_name=world.manifest.name,
                       probability=np.zeros((world.height_px, world.width_px), dtype=np.float32))
    map_path = bad.save(tmp_path / "all_bad.npz")
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "scenenav.app.cli", "run", "scenarios/gps_denied.yaml",
                        "--out", str(out), "--quiet", "--set", "duration_s=300",
                        "--set", f"guidance.assistant_map={map_path}"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    failures = summary["node_failures"]
    assert any("guidance" in str(f) and "no route" in str(f) for f in failures), failures
    assert not summary["mission_completed"]
    # stopped as soon as the guidance node had failed (it fails about 1 s in), not at 300 s
    assert summary["end_reason"].startswith("stopped the run before take-off: guidance failed"), summary
    assert summary["sim_time_s"] < 60.0, summary["sim_time_s"]
    assert summary["aborted"] is True
    lines = [ln for ln in r.stderr.splitlines() if "before take-off" in ln]
    assert len(lines) == 1 and "logs/guidance.log" in lines[0], r.stderr[-2000:]
