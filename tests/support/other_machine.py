"""Another machine for the tests that reach a run over the network (a node, a ground station).

``OtherMachine`` is a Linux network namespace joined to this one by a veth pair: its own interfaces
and its own loopback (it cannot reach this machine's 127.0.0.1), one /30 link to this machine, as a
companion computer or a laptop on a LAN. Without the rights to create one (not root, or no ``ip``)
it falls back to this machine reached through its first non-loopback address: weaker (the kernel
would also route loopback), but a run listening on 127.0.0.1 only is still out of reach.
``describe()`` says which one a test got.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import uuid
from pathlib import Path

from support import REPO_ROOT


class OtherMachine:
    """``host_addr``: this machine as the other one reaches it; ``node_addr``: the other machine's
    address as this one reaches it. ``start(cmd, log)`` runs a command there."""

    def __init__(self) -> None:
        self.netns: str | None = None
        tag = uuid.uuid4().hex[:6]
        octet = random.randrange(0, 64) * 4
        self.host_addr, self.node_addr = f"10.231.{octet}.1", f"10.231.{octet}.2"
        name, host_if, node_if = f"sn{tag}", f"sna{tag}", f"snb{tag}"
        steps = [["ip", "netns", "add", name],
                 ["ip", "link", "add", host_if, "type", "veth", "peer", "name", node_if],
                 ["ip", "link", "set", node_if, "netns", name],
                 ["ip", "addr", "add", f"{self.host_addr}/30", "dev", host_if],
                 ["ip", "link", "set", host_if, "up"],
                 ["ip", "netns", "exec", name, "ip", "addr", "add", f"{self.node_addr}/30", "dev", node_if],
                 ["ip", "netns", "exec", name, "ip", "link", "set", node_if, "up"],
                 ["ip", "netns", "exec", name, "ip", "link", "set", "lo", "up"]]
        if shutil.which("ip") and os.geteuid() == 0:
            try:
                for step in steps:
                    subprocess.run(step, check=True, capture_output=True, timeout=10)
                self.netns = name
                return
            except (subprocess.SubprocessError, OSError):
                subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=10)
                subprocess.run(["ip", "link", "del", host_if], capture_output=True, timeout=10)
        from scenenav.app.launcher import interface_addresses
        found = interface_addresses()
        assert found, "neither a network namespace nor a non-loopback address to reach the run by"
        self.host_addr = self.node_addr = found[0]

    def describe(self) -> str:
        return (f"network namespace {self.netns} ({self.node_addr}, this machine {self.host_addr})"
                if self.netns else f"this machine through {self.host_addr}")

    def start(self, cmd: list[str], log: Path) -> subprocess.Popen:
        if self.netns:
            cmd = ["ip", "netns", "exec", self.netns, *cmd]
        with log.open("wb") as f:
            return subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    cwd=REPO_ROOT)

    def close(self) -> None:
        if self.netns:      # deleting the namespace deletes its veth end, and so the pair
            subprocess.run(["ip", "netns", "del", self.netns], capture_output=True, timeout=10)
