"""A ``scenenav run`` started in the background for fault injection (tests/faults).

``FaultRun`` starts the launcher in its own session, waits for simulated time to pass (from the run
folder's truth.csv), finds the processes of the run (the launcher's process group and the group each
child leads, so grandchildren such as the camera render worker are included) and checks that none
survive the run.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path


def run_group_pids(pgids: set[int]) -> set[int]:
    """Live (non-zombie) processes whose process group is one of ``pgids`` (read from /proc)."""
    out = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        state, pgrp = fields[0], int(fields[2])
        if pgrp in pgids and state != "Z":
            out.add(int(entry))
    return out


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def last_sim_time(run_dir: Path) -> float | None:
    try:
        lines = (run_dir / "truth.csv").read_bytes().splitlines()
        return float(lines[-1].split(b",")[0]) if len(lines) > 1 else None
    except (OSError, ValueError, IndexError):
        return None


class FaultRun:
    def __init__(self, run_dir: Path, *args: str, scenario: str | None = None) -> None:
        self.run_dir = Path(run_dir)
        cmd = [sys.executable, "-m", "scenenav.app.cli", "run"]
        if scenario:
            cmd.append(scenario)
        cmd += ["--out", str(self.run_dir), "--quiet", *args]
        # files, not pipes: a launcher that logs a lot must never block on a full pipe
        self._out = self.run_dir.with_name(self.run_dir.name + ".stdout")
        self._err = self.run_dir.with_name(self.run_dir.name + ".stderr")
        with self._out.open("w") as out, self._err.open("w") as err:
            self.proc = subprocess.Popen(cmd, stdout=out, stderr=err, stdin=subprocess.DEVNULL,
                                         start_new_session=True)
        self.stdout = self.stderr = ""

    def pids(self) -> dict[str, int]:
        try:
            return json.loads((self.run_dir / "logs" / "pids.json").read_text())
        except (OSError, ValueError):
            return {}

    def wait_sim_time(self, t_s: float, timeout_s: float = 240.0) -> float:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            t = last_sim_time(self.run_dir)
            if t is not None and t >= t_s:
                return t
            if self.proc.poll() is not None:
                raise AssertionError(f"run ended before t={t_s} s: {self._err.read_text()[-3000:]}")
            time.sleep(0.2)
        raise AssertionError(f"simulated time did not reach {t_s} s in {timeout_s} s")

    def group_pids(self) -> set[int]:
        """Every live process of the run now (launcher group and each child's group)."""
        return run_group_pids({self.proc.pid, *self.pids().values()})

    def kill_node(self, name: str, sig: int = signal.SIGKILL) -> int:
        pid = self.pids()[name]
        os.kill(pid, sig)
        return pid

    def finish(self, timeout_s: float = 300.0) -> int:
        self.proc.wait(timeout_s)
        self.stdout, self.stderr = self._out.read_text(), self._err.read_text()
        return self.proc.returncode

    def kill(self) -> None:
        """Test clean-up: nothing of the run may stay behind, even when an assertion failed."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
        for pgid in {self.proc.pid, *self.pids().values()}:
            try:
                os.killpg(pgid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass

    def summary(self) -> dict:
        return json.loads((self.run_dir / "summary.json").read_text())


def wait_gone(pids: set[int], timeout_s: float = 10.0) -> set[int]:
    """The pids of ``pids`` still alive after up to ``timeout_s`` (an exiting process needs a moment)."""
    deadline = time.monotonic() + timeout_s
    left = {p for p in pids if alive(p)}
    while left and time.monotonic() < deadline:
        time.sleep(0.1)
        left = {p for p in left if alive(p)}
    return left


def describe(pids: set[int]) -> str:
    """Command lines of ``pids`` (for assertion messages)."""
    out = []
    for pid in sorted(pids):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[:200]
        except OSError:
            cmd = "?"
        out.append(f"{pid}: {cmd}")
    return "; ".join(out)
