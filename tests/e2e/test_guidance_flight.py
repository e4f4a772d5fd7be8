"""The guidance node in a lockstep flight (scenarios/guided_route.yaml): it plans around the lake,
uploads the mission over MAVLink, the autopilot flies it GPS-denied, and the flight beats the
straight line between the same points (accepted true fixes, fix error, navigation error)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from support import REPO_ROOT

from guidance.node import cross_track_m
from scenenav.app.evaluation import fix_table, read_csv
from scenenav.core.bus import free_port

ROOT = REPO_ROOT
SCENARIO = ROOT / "scenarios" / "guided_route.yaml"
CRUISE_MIN_Z_M = 90.0
#: The straight flight is cut here: it loses its fixes over the lake, leaves the cruise by ~75 s
#: (vision failsafe) and would land in the lake at ~115 s; what the tests compare is flown by then
#: (2026-12-06: 347 cruise fixes, accepted-true share 0.42, estimate RMS 7.2 m at 90 s, 18.1 m at
#: the landing; the guided flight 2.6 m).
STRAIGHT_S = 90
# Two flights of one to two simulated minutes (plus, on a fresh machine, the world and its
# assistant map being built once): more than the suite's default per-test limit on a loaded machine.
pytestmark = pytest.mark.timeout(1200)


def _start(out: Path, *overrides: str) -> subprocess.Popen:
    # its own MAVLink port, no UDP output: other tests' flights may run beside this one
    overrides = (*overrides, f"autopilot.mavlink_tcp_port={free_port()}",
                 "autopilot.mavlink_udp_out=none")
    sets = [a for o in overrides for a in ("--set", o)]
    return subprocess.Popen([sys.executable, "-m", "scenenav.app.cli", "run", str(SCENARIO), "--out", str(out),
                             "--quiet", *sets], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, stdin=subprocess.DEVNULL)


def _finish(proc: subprocess.Popen, out: Path) -> dict:
    _, stderr = proc.communicate(timeout=900)
    assert proc.returncode == 0, stderr[-3000:]
    return json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    base = tmp_path_factory.mktemp("guided")
    scen = yaml.safe_load(SCENARIO.read_text())
    start = scen["flight"]["start_enu_m"]
    goal = scen["guidance"]["goals_enu_m"][-1]
    # the two flights side by side (lockstep: each waits on its own nodes, so they share the
    # cores without changing what they fly)
    procs = [_start(base / "guided"),
             _start(base / "straight", "guidance.enabled=false", f"duration_s={STRAIGHT_S}",
                    f"flight.route_enu_m=[[{start[0]},{start[1]}],[{goal[0]},{goal[1]}]]")]
    try:
        guided = _finish(procs[0], base / "guided")
        straight = _finish(procs[1], base / "straight")
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    return {"guided": (base / "guided", guided), "straight": (base / "straight", straight),
            "start": np.array(start, float), "goal": np.array(goal, float), "scenario": scen}


def cruise_metrics(run_dir: Path) -> dict:
    """Fixes taken at cruise altitude: share of accepted true ones, RMS error of every valid one."""
    fx = fix_table(run_dir, 5.0)
    truth = read_csv(run_dir / "truth.csv")
    z = np.interp(fx["t_s"], truth["t_s"], truth["z_m"])
    cruise = z > CRUISE_MIN_Z_M
    valid = cruise & (fx["valid"] > 0.5)
    accepted_true = valid & (fx["accepted"] > 0.5) & ~fx["is_false"].astype(bool)
    return {"n": int(cruise.sum()), "accepted_true_share": accepted_true.sum() / max(1, cruise.sum()),
            "rms_valid_m": float(np.sqrt(np.mean(fx["error_m"][valid] ** 2)))}


def test_guidance_node_flies_the_planned_route(flights):
    run_dir, summary = flights["guided"]
    route = json.loads((run_dir / "route.json").read_text())
    xy = np.array([[w["x_m"], w["y_m"]] for w in route["waypoints"]])
    # planned around the lake: the straight line crosses bad area, the route does not
    assert route["straight_line_bad_fraction"][0] > 0.3
    assert route["route_bad_fraction"][0] == 0.0
    assert np.allclose(xy[0], flights["start"]) and np.allclose(xy[-1], flights["goal"])
    assert route["length_m"] > 1.05 * float(np.hypot(*(flights["goal"] - flights["start"])))
    # uploaded over MAVLink and flown by the autopilot: truth follows the route and lands at the goal
    events = (run_dir / "events.csv").read_text()
    assert "mission uploaded" in events and "mission started" in events
    assert summary["mission_completed"] and not summary["gps_used"]
    # landed at the goal: the mission succeeded (within evaluation.goal_tolerance_m)
    assert summary["end_distance_to_goal_m"] <= summary["goal_tolerance_m"] and summary["mission_succeeded"]
    truth = read_csv(run_dir / "truth.csv")
    high = truth["z_m"] > CRUISE_MIN_Z_M
    pts = np.stack([truth["x_m"][high], truth["y_m"][high]], axis=1)
    assert len(pts) > 100
    worst = max(cross_track_m(xy, p) for p in pts[::5])
    assert worst < 15.0, f"truth strayed {worst:.1f} m from the planned route"
    # GPS-denied: the autopilot lands where its estimate puts the goal; the truth is off by the
    # estimate's error then (seen: estimate 1.3 m from the goal, truth 10.5 m, estimate error 11.8 m
    # with a 15.5 m standard deviation), so each is checked against what bounds it
    landed = np.array([truth["x_m"][-1], truth["y_m"][-1]])
    est = read_csv(run_dir / "estimates.csv")
    landed_est = np.array([est["x_m"][-1], est["y_m"][-1]])
    assert np.hypot(*(landed_est - flights["goal"])) < 5.0
    est_error = float(np.hypot(*(landed_est - landed)))
    # ... against the uncertainty the filter had in the air: once landed it fuses the landed
    # position (std 0.3 m, ArduPilot's on-ground behaviour), and whether the last row comes before
    # or after the first such fusion is a matter of one tick
    z = np.interp(est["t_s"], truth["t_s"], truth["z_m"])
    last_air = int(np.nonzero(z > float(truth["z_m"][0]) + 1.0)[0][-1])
    assert est_error < 3.0 * max(float(est["std_x_m"][last_air]), float(est["std_y_m"][last_air]))
    assert np.hypot(*(landed - flights["goal"])) < est_error + 5.0
    assert np.hypot(*(landed - flights["goal"])) < 25.0
    assert summary["route_length_m"] == pytest.approx(route["length_m"])
    assert summary["replans"] == 0
    stats = json.loads((run_dir / "guidance_stats.json").read_text())
    assert stats["start_tries"] >= 1 and stats["replan_failures"] == 0


def test_route_beats_the_straight_line(flights):
    g_dir, g = flights["guided"]
    s_dir, s = flights["straight"]
    gm, sm = cruise_metrics(g_dir), cruise_metrics(s_dir)
    assert gm["n"] > 100 and sm["n"] > 50
    # a higher share of accepted true fixes ...
    assert gm["accepted_true_share"] > sm["accepted_true_share"] + 0.2, (gm, sm)
    # ... (a lower scene-matching error along the path: test_route_halves_the_matching_error) ...
    # ... and, GPS-denied, a lower error of the autopilot's own position estimate
    assert g["rms_error_m"] < s["rms_error_m"], (g["rms_error_m"], s["rms_error_m"])
    assert g["mission_completed"]


# Measured on the 3-D city (seed 5, one pair of flights): RMS of valid fixes along the route 0.79 m
# guided vs 3.22 m straight, accepted-true share 1.00 vs 0.42.
def test_route_halves_the_matching_error(flights):
    gm, sm = cruise_metrics(flights["guided"][0]), cruise_metrics(flights["straight"][0])
    assert gm["rms_valid_m"] < 0.5 * sm["rms_valid_m"], (gm, sm)
