"""A node whose launcher died stops even when the stop signal cannot reach its Python handler
(``scenenav.app.signals.stop_event``'s parent watchdog; docs/faults.md, "No orphan, ever")."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

from support.fault_run import alive as _alive

# The grandchild: PDEATHSIG set to a signal it ignores (as if the handler never ran: a main thread
# blocked in native code runs no Python signal handler), then blocked forever in the main thread.
NODE = textwrap.dedent("""
    import ctypes, signal, sys, threading
    signal.signal(signal.SIGUSR1, signal.SIG_IGN)
    ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGUSR1))   # PR_SET_PDEATHSIG
    from scenenav.app import signals
    signals.STOP_DEADLINE_S = 1.0
    signals.PARENT_POLL_S = 0.1
    ev = signals.stop_event()
    print("ready", flush=True)
    threading.Event().wait()          # never returns by itself
""")

# The launcher stand-in: starts the node, says its pid, waits to be killed.
LAUNCHER = textwrap.dedent("""
    import subprocess, sys, time
    p = subprocess.Popen([sys.executable, "-c", sys.argv[1]], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    print(p.pid, flush=True)
    time.sleep(600)
""")


def test_a_node_whose_parent_died_exits_within_the_deadline():
    launcher = subprocess.Popen([sys.executable, "-c", LAUNCHER, NODE], stdout=subprocess.PIPE, text=True)
    node_pid = int(launcher.stdout.readline())
    try:
        assert _alive(node_pid)
        launcher.send_signal(signal.SIGKILL)
        launcher.wait(10)
        deadline = time.monotonic() + 30.0
        while _alive(node_pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(node_pid), "the node outlived its parent"
    finally:
        launcher.kill()
        if _alive(node_pid):
            os.kill(node_pid, signal.SIGKILL)


def test_a_node_started_by_hand_does_not_watch_its_parent():
    # no parent-death signal: the user's shell may go away without stopping the node
    code = ("from scenenav.app import signals\n"
            "import threading\n"
            "signals.stop_event()\n"
            "print(sorted(t.name for t in threading.enumerate()))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "parent-watchdog" not in out.stdout
