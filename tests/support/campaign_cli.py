"""Helpers for the campaign tests: write a campaign file, start ``scenenav campaign`` in its own
process group (as a terminal would: Ctrl-C goes to the whole group), find the processes of a run."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
SCRIPTED = REPO / "scenarios" / "scripted_loop.yaml"


def write_campaign(path: Path, **keys) -> Path:
    path.write_text(yaml.safe_dump(keys, sort_keys=False))
    return path


def start_campaign(campaign: Path, out: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "scenenav.app.cli", "campaign", str(campaign), "--out", str(out), "--quiet",
           *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, cwd=str(campaign.parent))


def processes_mentioning(text: str) -> list[tuple[int, int, str]]:
    """(pid, parent pid, command line) of every live process whose command line contains ``text``."""
    out = []
    me = os.getpid()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == me:
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        if text in cmdline:
            state = stat.rsplit(")", 1)[1].split()
            if state[0] != "Z":
                out.append((int(entry.name), int(state[1]), cmdline))
    return out


def flights_running(out: Path) -> list[tuple[int, int, str]]:
    """The ``scenenav run`` launchers of a campaign folder that are alive."""
    return [p for p in processes_mentioning(str(out / "runs")) if " run " in p[2] and "--out" in p[2]]


def wait_for(condition, timeout_s: float, what: str):
    """Poll ``condition`` until it returns something truthy; fail the test after ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(0.5)
    raise AssertionError(f"timed out waiting for {what}")
