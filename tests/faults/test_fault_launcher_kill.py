"""SIGKILL of the launcher (docs/faults.md): the nodes die with it (PDEATHSIG, the render worker with
the simulator), and ``scenenav summarize RUN_DIR`` rebuilds the summary and the plot from what was
recorded, marking what is missing."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

from support.fault_run import FaultRun, describe, wait_gone


def summarize(run_dir):
    return subprocess.run([sys.executable, "-m", "scenenav.app.cli", "summarize", str(run_dir)],
                          capture_output=True, text=True, timeout=300)


def test_launcher_killed_then_summarize_rebuilds(tmp_path):
    from scenenav.app.recorder import count_mcap_messages
    run = FaultRun(tmp_path / "run", "--set", "duration_s=60", "--set", "perception.method=statistical",
                   scenario="scenarios/logging_flight.yaml")
    try:
        run.wait_sim_time(4.0)
        pids = run.group_pids()
        assert len(pids) >= 5        # launcher, sim (+ render worker), recorder, perception
        run.proc.send_signal(signal.SIGKILL)
        run.proc.wait(30)
        left = wait_gone(pids, timeout_s=60)
        logs = {n: (run.run_dir / "logs" / f"{n}.log").read_text()[-1500:] for n, pid in run.pids().items()
                if pid in left}
        assert left == set(), f"nodes outlived the launcher: {describe(left)} {logs}"
    finally:
        run.kill()
    out = run.run_dir
    assert not (out / "summary.json").exists() and not (out / "trajectory.png").exists()
    r = summarize(out)
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["rebuilt"] is True and (out / "trajectory.png").is_file()
    assert 4.0 <= s["sim_time_s"] < 60.0
    assert s["fixes_total"] > 30
    # the whole chunks before the tear are recovered (the first holds the reference and assistant
    # maps of the live-view channels, a few MB: on a short run that may be all 2/3 of the file keeps)
    assert count_mcap_messages(out / "bus.mcap") >= 10
    assert not (out / ".disk_reserve").exists()

    # a folder with less in it: no simulator stats, a torn bus.mcap
    (out / "sim_stats.json").unlink()
    (out / "summary.json").unlink()
    data = (out / "bus.mcap").read_bytes()
    (out / "bus.mcap").write_bytes(data[: len(data) * 2 // 3])
    r = summarize(out)
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads((out / "summary.json").read_text())
    assert any(m.startswith("sim_stats.json") for m in s["missing"])
    assert s["end_reason"].startswith("unknown")
    assert any("bus.mcap had no footer" in n for n in s["notes"])
    # the whole chunks before the tear are recovered (the first holds the reference and assistant
    # maps of the live-view channels, a few MB: on a short run that may be all 2/3 of the file keeps)
    assert count_mcap_messages(out / "bus.mcap") >= 1
    assert "missing" in r.stdout


def test_summarize_a_folder_that_is_not_a_run(tmp_path):
    r = summarize(tmp_path)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()]
    assert r.stderr.startswith("error: ") and "scenario.yaml" in r.stderr
