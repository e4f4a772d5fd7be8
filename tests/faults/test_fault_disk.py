"""Disk space (docs/faults.md): a run refuses to start without ``recorder.min_free_disk_mb`` free,
a disk full at start leaves nothing behind (no 0-byte scenario.yaml: the same --out works next
time), and a disk that fills mid-run ends the run cleanly: one line naming the disk, every file
readable, a summary that says why, no process left.

The full-disk cases run the flight on a small tmpfs, so they need root (mount); else skipped.
"""

from __future__ import annotations

import csv
import subprocess
import sys

import pytest
from support.fault_run import FaultRun, wait_gone


def scenenav_run(out, *args: str, timeout: float = 300):
    return subprocess.run([sys.executable, "-m", "scenenav.app.cli", "run", "scenarios/logging_flight.yaml",
                           "--out", str(out), "--quiet", "--set", "perception.method=statistical",
                           *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def small_disk(tmp_path):
    """A 20 MB tmpfs (root only); unmounted afterwards."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=20m", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _fill(path):
    """Fill the file system of ``path`` completely (ENOSPC)."""
    with (path / "filler").open("wb") as f:
        try:
            while True:
                f.write(b"\0" * (1 << 20))
                f.flush()
        except OSError:
            pass
    with (path / "filler2").open("wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError:
            pass


def test_refused_below_the_free_margin(tmp_path):
    out = tmp_path / "run"
    r = scenenav_run(out, "--set", "recorder.min_free_disk_mb=100000000")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "MB free on /" in lines[0] and "recorder.min_free_disk_mb" in lines[0]
    assert not out.exists()


def test_disk_full_at_start_leaves_nothing_and_a_rerun_works(small_disk):
    _fill(small_disk)
    out = small_disk / "run"
    r = scenenav_run(out, "--set", "recorder.min_free_disk_mb=0", "--set", "duration_s=2")
    assert r.returncode == 2, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "no space left" in lines[0] and f"on {small_disk}" in lines[0], r.stderr
    assert not out.exists(), "a half-written run folder was left behind"
    (small_disk / "filler").unlink()
    r = scenenav_run(out, "--set", "recorder.min_free_disk_mb=0", "--set", "duration_s=2",
                     "--set", "recorder.camera_every_n=0")
    assert r.returncode == 0, r.stderr[-2000:]
    assert (out / "summary.json").is_file()


def test_disk_filling_mid_run_ends_it_cleanly(small_disk):
    from scenenav.app.recorder import count_mcap_messages
    run = FaultRun(small_disk / "run", "--set", "perception.method=statistical",
                   "--set", "duration_s=120", "--set", "recorder.camera_every_n=1",
                   "--set", "recorder.min_free_disk_mb=10", scenario="scenarios/logging_flight.yaml")
    try:
        run.wait_sim_time(0.5)
        pids = run.group_pids()
        code = run.finish(timeout_s=400)
    finally:
        run.kill()
    assert code == 1, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    disk_lines = [ln for ln in run.stderr.splitlines() if "disk full" in ln]
    assert len(disk_lines) == 1 and f"MB free on {small_disk}" in disk_lines[0], run.stderr[-3000:]
    assert wait_gone(pids) == set()
    out = run.run_dir
    s = run.summary()
    assert s["end_reason"].startswith("disk full") and s["aborted"] is True
    assert s["sim_time_s"] < 120
    assert count_mcap_messages(out / "bus.mcap") > 100
    for name in ("truth.csv", "fixes.csv", "events.csv"):
        with (out / name).open(newline="") as f:
            rows = list(csv.reader(f))
        assert len(rows) > 1 and all(len(row) == len(rows[0]) for row in rows), name
    assert (out / "trajectory.png").is_file()
    assert not (out / ".disk_reserve").exists()
