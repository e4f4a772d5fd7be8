"""A stand-in for the launcher's ``Launch`` whose ``spawn`` records children instead of starting
processes: the launcher's state machines (the perception swap, the node restarter) are driven over it
with a real run folder whose CSV files the test writes."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path

_pids = itertools.count(100_000)


class FakeProc:
    """A child process that runs until ``send_signal`` (a clean stop) or ``die`` (a failure)."""

    def __init__(self) -> None:
        self.code: int | None = None
        self.pid = next(_pids)

    def poll(self) -> int | None:
        return self.code

    def send_signal(self, _sig) -> None:
        self.code = 0

    def wait(self, _timeout=None) -> int | None:
        return self.code

    def die(self, code: int = -9) -> None:
        self.code = code


@dataclass
class FakeChild:
    name: str
    args: list[str]
    proc: FakeProc = field(default_factory=FakeProc)
    stopping: bool = False


@dataclass
class FakeLaunch:
    run_dir: Path
    children: list[FakeChild] = field(default_factory=list)

    def spawn(self, name: str, args: list[str]) -> FakeChild:
        c = FakeChild(name, list(args))
        self.children.append(c)
        return c

    def running(self, name: str) -> list[FakeChild]:
        return [c for c in self.children if c.name == name and c.proc.poll() is None]
