"""``scenenav sitl --external perception:ID``: a ground-station session whose perception node is the
user's own (the example node, zenoh + numpy + OpenCV only). The session says it waits for the node,
the clock starts once it joined, and its fixes are the run's."""

from __future__ import annotations

import csv
import subprocess
import sys

import pytest
from support import REPO_ROOT
from support.sitl_session import SitlSession, wait_until

EXAMPLE = REPO_ROOT / "examples" / "perception_node_python" / "node.py"
NODE_ID = "my_matcher"


def _fix_rows(run_dir):
    try:
        with (run_dir / "fixes.csv").open(newline="") as f:
            return list(csv.DictReader(f))
    except OSError:
        return []


def test_sitl_waits_for_the_users_perception_node_and_uses_its_fixes(tmp_path):
    sitl = SitlSession(tmp_path, "--lockstep", "--external", f"perception:{NODE_ID}")
    node = None
    try:
        assert wait_until(lambda: any(f"perception:{NODE_ID}" in ln and "waiting up to" in ln
                                      for ln in sitl.lines) or sitl.proc.poll() is not None, 120), \
            "\n".join(sitl.lines[-30:])
        assert (sitl.run_dir / "run.json").is_file()       # written before the wait is announced
        assert not (sitl.run_dir / "logs" / "perception.log").exists()   # no built-in node
        node = subprocess.Popen([sys.executable, str(EXAMPLE), str(sitl.run_dir)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
        sitl.wait_ready()
        assert wait_until(lambda: len(_fix_rows(sitl.run_dir)) >= 20, 120), "no fixes from the node"
    finally:
        sitl.stop()
        if node is not None:
            try:
                node.wait(30)          # it leaves when the run ends
            except subprocess.TimeoutExpired:
                node.kill()
                pytest.fail("the external node did not leave when the session ended")
    rows = _fix_rows(sitl.run_dir)
    assert {r["node_id"] for r in rows} == {NODE_ID}
    assert min(int(r["frame_seq"]) for r in rows) == 0       # the clock waited for it: frame 0 answered
