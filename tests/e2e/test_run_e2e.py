"""End-to-end runs of `scenenav run`: run folder contract, determinism, Ctrl-C, realtime pacing."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SHORT = ["--set", "duration_s=6", "--set", "perception.method=statistical", "--quiet"]


def scenenav(*args, **kw):
    return subprocess.run([sys.executable, "-m", "scenenav.app.cli", *args], capture_output=True,
                          text=True, timeout=kw.pop("timeout", 300), **kw)


def rows(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:   # a zombie of ours is not alive
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("runs")
    outs = []
    for name in ("a", "b"):
        out = base / name
        r = scenenav("run", "--out", str(out), *SHORT)
        assert r.returncode == 0, r.stderr[-2000:]
        outs.append((out, r))
    return outs


def test_run_folder_contract(two_runs):
    out, r = two_runs[0]
    assert "summary:" in r.stdout
    for name in ("summary.json", "truth.csv", "fixes.csv", "estimates.csv", "events.csv",
                 "trajectory.png", "bus.mcap", "scenario.yaml", "run.json", "logs/sim.log",
                 "logs/perception.log", "logs/recorder.log"):
        assert (out / name).exists(), name
    s = json.loads((out / "summary.json").read_text())
    for key in ("rms_error_m", "max_error_m", "fixes_total", "fixes_accepted", "false_fixes",
                "false_fixes_rejected", "true_fixes_rejected", "fix_time_ms_median",
                "mission_completed", "mission_succeeded", "gps_used", "sim_time_s", "wall_time_s"):
        assert key in s, key
    assert 5.9 <= s["sim_time_s"] <= 6.1
    assert 50 <= s["fixes_total"] <= 62          # 10 Hz camera for 6 s, minus the camera latency
    assert s["fix_rms_error_accepted_m"] < 3.0   # scripted flight over the city: good matches
    truth = rows(out / "truth.csv")
    assert len(truth) > 100 and abs(float(truth[0]["z_m"]) - 100.0) < 0.01


def test_mcap_readable(two_runs):
    from mcap.reader import make_reader
    out, _ = two_runs[0]
    topics = set()
    with (out / "bus.mcap").open("rb") as f:
        for _schema, channel, _msg in make_reader(f).iter_messages():
            # bus keys without their scenenav/<namespace>/ prefix; the view's viz/... as they are
            t = channel.topic
            topics.add(t if t.startswith("viz/") else t.split("/", 2)[-1])
    assert {"clock", "sensors/imu", "viz/camera", "truth/pose", "viz/truth/pose", "viz/map/reference"} <= topics
    assert any(t.startswith("perception/fix/") for t in topics)


def test_lockstep_runs_are_deterministic(two_runs):
    (a, _), (b, _) = two_runs
    assert (a / "truth.csv").read_text() == (b / "truth.csv").read_text()
    fa, fb = rows(a / "fixes.csv"), rows(b / "fixes.csv")
    assert len(fa) == len(fb) and len(fa) > 0
    for ra, rb in zip(fa, fb, strict=False):   # wall-clock timings differ; everything else must not
        assert {k: v for k, v in ra.items() if not k.startswith("time_")} == \
               {k: v for k, v in rb.items() if not k.startswith("time_")}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_interrupt_stops_everything_and_keeps_the_folder(tmp_path, sig):
    out = tmp_path / "int"
    # started with SIGINT ignored, like a background job of a non-interactive shell
    proc = subprocess.Popen([sys.executable, "-m", "scenenav.app.cli", "run", "--out", str(out),
                             "--set", "duration_s=600", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    truth = out / "truth.csv"
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120:
        if truth.exists() and truth.stat().st_size > 2000:
            break
        time.sleep(0.2)
    else:
        proc.kill()
        pytest.fail("the run never started flying")
    pids = json.loads((out / "logs" / "pids.json").read_text())
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=90)
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err
    for name, pid in pids.items():
        assert not _alive(pid), f"{name} (pid {pid}) survived Ctrl-C"
    s = json.loads((out / "summary.json").read_text())
    assert s["end_reason"] == "interrupted" and s["sim_time_s"] > 0
    assert len(rows(out / "truth.csv")) > 5
    from mcap.reader import make_reader
    with (out / "bus.mcap").open("rb") as f:
        assert sum(1 for _ in make_reader(f).iter_messages()) > 10


def test_realtime_mode_is_paced(tmp_path):
    out = tmp_path / "rt"
    r = scenenav("run", "--out", str(out), "--set", "duration_s=3", "--set", "clock.mode=realtime",
                 "--set", "clock.speed_factor=2", "--set", "perception.enabled=false", "--quiet")
    assert r.returncode == 0, r.stderr[-2000:]
    stats = json.loads((out / "sim_stats.json").read_text())
    # paced to 2x the wall clock: 3 simulated seconds cannot take less than 1.5 wall seconds
    assert stats["wall_time_s"] >= 1.5 * 0.95
    assert stats["sim_time_s"] >= 2.9


def test_children_die_with_a_killed_launcher(tmp_path):
    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "scenenav.app.cli", "run", "--out", str(out),
                             "--set", "duration_s=600", "--set", "perception.enabled=false", "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pids_file = out / "logs" / "pids.json"
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120 and not (pids_file.exists() and len(json.loads(pids_file.read_text())) >= 2):
        time.sleep(0.2)
    pids = json.loads(pids_file.read_text())
    proc.kill()                      # SIGKILL: the launcher cannot clean up
    proc.wait(30)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30 and any(_alive(p) for p in pids.values()):
        time.sleep(0.2)
    assert not [n for n, p in pids.items() if _alive(p)]
