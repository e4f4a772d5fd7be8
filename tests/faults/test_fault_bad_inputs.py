"""Bad input files are refused by the launcher before any node starts: one line, exit 2, no run
folder (docs/faults.md). Each case is a real ``scenenav run`` with one broken file."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest


def scenenav_run(out, *args: str):
    return subprocess.run([sys.executable, "-m", "scenenav.app.cli", "run", *args, "--out", str(out),
                           "--quiet", "--set", "duration_s=5"],
                          capture_output=True, text=True, timeout=300)


def _corrupt_npz(path):
    path.write_bytes(b"PK\x03\x04 this is not a zip archive" + bytes(range(256)))
    return path


def _small_map(path):
    np.savez(path, probability=np.full((40, 30), 0.5, dtype=np.float32))
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    (d / "weights.pt").write_bytes(b"\x80\x02 not a torch file")
    (d / "model.json").write_text('{"format_version": 1, "rule": "combined", "weights": [1, 2')
    (d / "params.json").write_text('{"WPNAV_SPEED": "fast"}')
    (d / "params_bad_json.json").write_text("{WPNAV_SPEED: 500")
    return {"corrupt_npz": _corrupt_npz(d / "corrupt.npz"), "small_npz": _small_map(d / "small.npz"),
            "weights": d / "weights.pt", "model": d / "model.json", "params": d / "params.json",
            "params_bad_json": d / "params_bad_json.json"}


CASES = {
    "perception map corrupt": (["--set", "perception.method=assistant-map",
                                "--set", "perception.assistant_map={corrupt_npz}"],
                               "perception.assistant_map"),
    "perception map of another size": (["--set", "perception.method=cnn",
                                        "--set", "perception.assistant_map={small_npz}"],
                                       "perception.assistant_map"),
    "guidance map corrupt": (["scenarios/gps_denied.yaml", "--set", "guidance.assistant_map={corrupt_npz}"],
                             "guidance.assistant_map"),
    "guidance map of another size": (["scenarios/gps_denied.yaml",
                                      "--set", "guidance.assistant_map={small_npz}"],
                                     "guidance.assistant_map"),
    "weights missing": (["--set", "perception.method=cnn", "--set", "perception.weights=/nonexistent/w.pt"],
                        "perception.weights"),
    "weights corrupt": (["--set", "perception.method=cnn", "--set", "perception.weights={weights}"],
                        "perception.weights"),
    "decision model corrupt": (["--set", "perception.method=cnn", "--set", "perception.decision_rule=combined",
                                "--set", "perception.decision_model={model}"], "perception.decision_model"),
    "decision model missing": (["--set", "perception.method=statistical",
                                "--set", "perception.decision_rule=combined",
                                "--set", "perception.decision_model=/nonexistent/m.json"],
                               "perception.decision_model"),
    "route off the world": (["--set", "flight.route_enu_m=[[0,0],[90000,0]]"], "flight.route_enu_m[1]"),
    "guidance goal off the world": (["scenarios/gps_denied.yaml", "--set", "guidance.goals_enu_m=[[0,70000]]",
                                     "--set", "guidance.assistant_map={small_npz}"],
                                    "guidance.assistant_map"),
    "parameter value not a number": (["--set", "flight.mode=autopilot", "--set", "autopilot.params_file={params}",
                                      "--set", "autopilot.mavlink_udp_out=none"], "autopilot.params_file"),
    "parameter file not JSON": (["--set", "flight.mode=autopilot",
                                 "--set", "autopilot.params_file={params_bad_json}",
                                 "--set", "autopilot.mavlink_udp_out=none"], "autopilot.params_file"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_is_one_line_exit_2_before_start(case, files, tmp_path):
    args, key = CASES[case]
    args = [a.format(**files) for a in args]
    out = tmp_path / "run"
    r = scenenav_run(out, *args)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr[-2000:]
    assert key in lines[0]
    assert not out.exists(), "a run folder was created: a process may have started"


def test_goal_off_the_world_with_a_good_map(tmp_path):
    """The guidance goals are checked once the map is good."""
    from worlds.default import load_default_world
    w = load_default_world()
    path = tmp_path / "map.npz"
    np.savez(path, probability=np.full((w.height_px, w.width_px), 0.9, dtype=np.float32))
    out = tmp_path / "run"
    r = scenenav_run(out, "scenarios/gps_denied.yaml", "--set", f"guidance.assistant_map={path}",
                     "--set", "guidance.goals_enu_m=[[0,70000]]")
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.strip().splitlines() == [r.stderr.strip()]
    assert "guidance.goals_enu_m[0]" in r.stderr and not out.exists()


def test_good_params_file_passes_the_check(tmp_path):
    from scenenav.app.preflight import validate_inputs
    from scenenav.app.scenario import load_scenario
    from worlds.default import load_default_world
    p = tmp_path / "ok.json"
    p.write_text(json.dumps({"WPNAV_SPEED": 500}))
    cfg = load_scenario(None, ("flight.mode=autopilot", f"autopilot.params_file={p}"))
    validate_inputs(cfg, load_default_world())      # no exception
