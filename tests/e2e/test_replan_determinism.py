"""Lockstep runs give byte-identical truth twice, also when the guidance node replans.

Two flights of ``scenarios/guided_route.yaml`` cut to 35 simulated seconds, side by side, with
``guidance.replan_drift_m`` 3 m so that the GPS-denied estimate drifts off the route a few times and
the node replans (2 replans by 35 s: at 30 and 32 s, 2026-12-06). Until session 23 the node left lockstep
once its mission ran, so a replan's upload landed at a wall-clock-dependent simulated time and two
such flights diverged after the first replan; now it stays a member, holds the tick a replan is
decided at until the new mission is uploaded, and reads the estimate of that tick."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from support import REPO_ROOT

from scenenav.core.bus import free_port

SCENARIO = REPO_ROOT / "scenarios" / "guided_route.yaml"
pytestmark = pytest.mark.timeout(900)


def test_a_replanning_flight_is_reproducible(tmp_path):
    procs, outs = [], []
    for name in ("a", "b"):
        out = tmp_path / name
        sets = ["duration_s=35", "guidance.replan_drift_m=3", f"autopilot.mavlink_tcp_port={free_port()}",
                "autopilot.mavlink_udp_out=none"]
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "scenenav.app.cli", "run", str(SCENARIO), "--out", str(out), "--quiet",
             *[a for s in sets for a in ("--set", s)]],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO_ROOT, stdin=subprocess.DEVNULL))
        outs.append(out)
    for proc in procs:
        _, stderr = proc.communicate(timeout=800)
        assert proc.returncode == 0, stderr[-3000:]
    a, b = outs
    replans = json.loads((a / "guidance_stats.json").read_text())["replans"]
    assert replans >= 2, "the flight must replan for this test to mean anything"
    assert json.loads((b / "guidance_stats.json").read_text())["replans"] == replans
    for name in ("truth.csv", "estimates.csv"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    for n in range(1, replans + 1):
        ra = json.loads((a / f"route-{n}.json").read_text())
        rb = json.loads((b / f"route-{n}.json").read_text())
        assert ra["sim_time_s"] == rb["sim_time_s"] and ra["waypoints"] == rb["waypoints"], n
