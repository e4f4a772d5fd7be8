"""scenenav.core.parent_death: the parent-death signal is set and read back (Linux)."""

import signal
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux only")


def test_set_then_read_back_in_a_child():
    code = ("import signal; from scenenav.core.parent_death import parent_death_signal, "
            "set_parent_death_signal as s; before = parent_death_signal(); "
            "ok = s(signal.SIGUSR1); print(before, ok, parent_death_signal())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    before, ok, after = out.stdout.split()
    assert before == "0" and ok == "True" and int(after) == int(signal.SIGUSR1)
