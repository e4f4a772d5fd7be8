"""Test helpers: child processes whose output lines a thread collects, and MAVProxy driven
through stdin. Shared by the MAVLink client, ground-station and failsafe tests."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

VENV_BIN = Path(sys.executable).parent
MAVPROXY = VENV_BIN / "mavproxy.py"


def wait_until(predicate, timeout_s: float = 60.0, period_s: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period_s)
    return False


class LineProcess:
    """A child process; ``lines`` holds its combined stdout/stderr, one entry per line."""

    def __init__(self, cmd: list[str], *, name: str, timeout_s: float = 60.0,
                 stdin=subprocess.PIPE, **popen) -> None:
        self.name = name
        self.timeout_s = timeout_s
        self.proc = subprocess.Popen(cmd, stdin=stdin, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1, **popen)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def tail(self, n: int = 40) -> str:
        return "\n".join(self.lines[-n:])

    def send(self, line: str) -> int:
        """Write a line to stdin; returns the output mark to search from."""
        mark = len(self.lines)
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return mark

    def expect(self, text: str, start: int = 0, timeout_s: float | None = None) -> int:
        """Index of the first output line from ``start`` on containing ``text``."""
        found: list[int] = []

        def seen() -> bool:
            for i in range(start, len(self.lines)):
                if text in self.lines[i]:
                    found.append(i)
                    return True
            return False

        assert wait_until(seen, self.timeout_s if timeout_s is None else timeout_s), \
            f"{self.name} never printed {text!r}:\n" + self.tail()
        return found[0]

    def join_reader(self) -> None:
        self._reader.join(timeout=5)


class MavproxyProcess(LineProcess):
    """mavproxy.py scripted through stdin, connected to a MAVLink TCP server on loopback."""

    def __init__(self, port: int, workdir: Path, *extra: str, timeout_s: float = 60.0) -> None:
        cmd = [sys.executable, str(MAVPROXY), f"--master=tcp:127.0.0.1:{port}", "--no-state", *extra]
        env = {"HOME": str(workdir), "PATH": str(VENV_BIN) + ":/usr/bin:/bin",
               "PYTHONUNBUFFERED": "1", "TERM": "dumb"}
        super().__init__(cmd, name="MAVProxy", timeout_s=timeout_s, cwd=workdir, env=env)

    def close(self) -> None:
        """``exit`` and end of input make MAVProxy quit; terminate it if it does not."""
        if self.proc.poll() is None:
            try:
                self.send("exit")
                assert self.proc.stdin is not None
                self.proc.stdin.close()
                self.proc.wait(timeout=15)
            except (subprocess.TimeoutExpired, BrokenPipeError, OSError):
                self.proc.terminate()
                try:
                    self.proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(timeout=5)
        self.join_reader()
