"""A node written outside the project joins a run: ``scenenav run --external perception:ID`` waits
for it before the clock starts, run.json tells it everything it needs, the autopilot flies on its
fixes; ``scenenav node check`` passes the example node and fails each broken variant on the right
rule; a node that never comes ends the run with a one-line message.

The example node (examples/perception_node_python/node.py) imports only zenoh, numpy and OpenCV.
Four runs, two at a time: ``node check`` of the example node in a GPS-denied lockstep flight
of 16 simulated seconds, 4 s and 8 s check runs of two variants of it that break chosen rules
(tests/support/broken_perception_node.py), and one run that waits 2 s for a node that never comes.
"""

from __future__ import annotations

import csv
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from support import REPO_ROOT
from support.external_flight import EXAMPLE_NODE, external_flight

EXAMPLE = EXAMPLE_NODE
BROKEN = REPO_ROOT / "tests" / "support" / "broken_perception_node.py"
NODE_ID = "my_matcher"
RUN_TIMEOUT_S = 400
SCENARIO = external_flight("external_node", 24)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "scenenav.app.cli", *args]


#: The broken variants fly the default scripted flight, world seen flat, camera at 5 Hz.
CHECK_SETS = ("--set", "sim.camera.relief=false", "--set", "sim.camera.rate_hz=5")


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """Four runs, two at a time: ``node check`` of the example node in the GPS-denied flight, of two
    broken variants of it (short scripted flights), and a run waiting 2 s for a node that never comes."""
    tmp = tmp_path_factory.mktemp("external")
    scenario = tmp / "external.yaml"
    scenario.write_text(yaml.safe_dump(SCENARIO))
    commands = {
        "example": _cli("node", "check", "perception", "--json", "--node-id", NODE_ID, "--scenario",
                        str(scenario), "--duration-s", str(SCENARIO["duration_s"]), "--out",
                        str(tmp / "example"), "--", sys.executable, str(EXAMPLE), "{run_dir}"),
        "bent": _cli("node", "check", "perception", "--json", "--duration-s", "16", "--ack-timeout-s", "2",
                     *CHECK_SETS, "--out", str(tmp / "bent"), "--", sys.executable, str(BROKEN),
                     "--break", "ack,timestamp,covariance", "{run_dir}"),
        "fragile": _cli("node", "check", "perception", "--json", "--duration-s", "4", *CHECK_SETS,
                        "--out", str(tmp / "fragile"), "--", sys.executable, str(BROKEN), "--break",
                        "malformed", "{run_dir}"),
        "nobody": _cli("run", "--out", str(tmp / "nobody"), "--quiet", "--external", "perception:nobody",
                       "--set", "duration_s=1", "--set", "external.join_timeout_s=2",
                       "--set", "autopilot.mavlink_udp_out=none"),
    }
    out = {}
    # two at a time: four lockstep runs at once (each five processes) starve the real-time flights
    # another pytest worker may be flying beside this module
    for pair in (("example", "nobody"), ("bent", "fragile")):
        procs = {name: subprocess.Popen(commands[name], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, cwd=REPO_ROOT, stdin=subprocess.DEVNULL) for name in pair}
        for name, proc in procs.items():
            stdout, stderr = proc.communicate(timeout=RUN_TIMEOUT_S)
            out[name] = (proc.returncode, stdout, stderr, tmp / name)
    return out


def _failed(report: dict) -> set[str]:
    return {r["rule"] for r in report["rules"] if not r["passed"]}


def test_node_check_passes_the_example_node(flights):
    code, stdout, stderr, _ = flights["example"]
    report = json.loads(stdout)              # --json: stdout is the one document
    assert code == 0 and report["passed"], (stderr[-2000:], report)
    assert report["frames"] >= 50 and report["fixes"] == report["frames"] == report["acks"]
    from scenenav.app.node_check import RULES
    assert [r["rule"] for r in report["rules"]] == list(RULES)


def test_the_autopilot_flies_on_the_external_nodes_fixes(flights):
    _, _, _, out = flights["example"]
    run = out / "run"
    launcher = (out / "launcher.log").read_text()
    assert f"waiting up to 60 s for external node(s) perception:{NODE_ID}" in launcher
    summary = json.loads((run / "summary.json").read_text())
    assert summary["gps_used"] is False and not summary.get("failed_nodes"), summary
    assert not (run / "logs" / "perception.log").exists()      # the built-in node was not started
    with (run / "fixes.csv").open(newline="") as f:
        fixes = list(csv.DictReader(f))
    assert fixes and {row["node_id"] for row in fixes} == {NODE_ID}
    # every frame was answered: the clock waited for the node (the first frame is seq 0)
    sim = json.loads((run / "sim_stats.json").read_text())
    assert len(fixes) == sim["camera_frames"] and sim["ack_timeouts"] == 0
    assert min(int(row["frame_seq"]) for row in fixes) == 0
    # the clock started once the run's nodes (recorder, autopilot, ...) had echoed the node's token
    joined = json.loads((run / "external.json").read_text())
    assert joined["unlinked"] == [] and 0.0 <= joined["links_waited_s"] < 10.0, joined
    sim_log = (run / "logs" / "sim.log").read_text()
    echoed = re.search(r"every node of the run links to the external node\(s\) \((\d+) link", sim_log)
    assert echoed and int(echoed.group(1)) >= 2, sim_log[-2000:]     # the recorder and the autopilot
    stats = json.loads((run / "autopilot_stats.json").read_text())
    assert stats["core"]["vision_fused"] > 10, stats["core"]
    from scenenav.app.evaluation import read_csv
    est = read_csv(run / "estimates.csv")
    assert set(est["position_source"].astype(int)) == {6}
    assert NODE_ID in {str(v) for v in est["vision_node_id"]}
    assert summary["rms_error_m"] is not None and summary["rms_error_m"] < 5.0, summary
    assert summary["max_error_m"] < 15.0, summary
    # its NodeInfo was recorded: run.json appears only once the recorder listens
    from mcap.reader import make_reader
    with (run / "bus.mcap").open("rb") as f:
        topics = {ch.topic for ch in make_reader(f).get_summary().channels.values()}
    assert any(t.endswith(f"/info/{NODE_ID}") for t in topics), sorted(topics)


def test_run_json_tells_an_outside_node_everything(flights):
    run = flights["example"][3] / "run"
    meta = json.loads((run / "run.json").read_text())
    hub = json.loads((run / "hub.json").read_text())
    assert meta["hub_port"] == hub["hub_port"]
    assert meta["bus"] == {"endpoint": f"tcp/127.0.0.1:{hub['hub_port']}", "namespace": meta["namespace"],
                           "key_prefix": f"scenenav/{meta['namespace']}"}
    world = Path(meta["world_dir"])
    assert world.is_absolute() and (world / "manifest.json").is_file()
    assert meta["reference_map"] == str(world / "reference.png")     # perception.reference: orthophoto
    assert meta["reference_kind"] == "orthophoto" and meta["assistant_map"] is None
    cam = meta["camera"]
    f = 0.5 * 200 / math.tan(math.radians(60.0) / 2)
    assert (cam["width_px"], cam["height_px"], cam["fov_deg"], cam["fov_axis"]) == (200, 200, 60.0, "width")
    assert cam["fx_px"] == pytest.approx(f) and cam["fy_px"] == pytest.approx(f)
    assert (cam["cx_px"], cam["cy_px"]) == (99.5, 99.5)
    assert meta["external"] == [f"perception:{NODE_ID}"]
    assert json.loads((run / "external.json").read_text())["joined"] == [f"perception:{NODE_ID}"]


def test_node_check_fails_each_broken_rule(flights):
    code, stdout, stderr, _ = flights["bent"]
    report = json.loads(stdout)
    assert code == 1, stderr[-2000:]
    assert _failed(report) == {"acks", "timestamps", "covariance"}, report
    rules = {r["rule"]: r["detail"] for r in report["rules"]}
    assert "1 of" in rules["acks"] and "never acknowledged" in rules["acks"]
    assert "capture time" in rules["timestamps"] and "not symmetric" in rules["covariance"]


def test_node_check_fails_a_node_that_dies_on_a_malformed_frame(flights):
    code, stdout, stderr, _ = flights["fragile"]
    report = json.loads(stdout)
    assert code == 1, stderr[-2000:]
    failed = _failed(report)
    assert "malformed" in failed and "liveliness" not in failed and "encoding" not in failed, report
    assert "exited" in {r["rule"]: r["detail"] for r in report["rules"]}["malformed"]


def test_a_node_that_never_comes_ends_the_run_with_one_line(flights):
    code, _, stderr, run = flights["nobody"]
    assert code == 1, stderr[-2000:]
    errors = [line for line in stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "external node perception:nobody did not join within 2 s" in errors[0]
    assert "Traceback" not in stderr
    summary = json.loads((run / "summary.json").read_text())
    assert summary["sim_time_s"] == 0 and "perception:nobody" in summary["end_reason"]
    assert json.loads((run / "external.json").read_text())["missing"] == ["perception:nobody"]
