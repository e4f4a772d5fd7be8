"""The camera render worker never outlives the process that forked it, even one killed by SIGKILL
and with no launcher around to clean up its process group (sitl/render_worker.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

from support.fault_run import alive, wait_gone

SCRIPT = textwrap.dedent("""
    import sys, time
    import numpy as np
    from sitl.config import CameraConfig
    from sitl.render_worker import CameraPipeline
    cam = CameraPipeline(np.full((64, 64, 3), 128, np.uint8), 1.0, CameraConfig(render_in_worker=True))
    cam.request(0, (0.0, 0.0, 50.0), (1.0, 0.0, 0.0, 0.0))
    assert cam.result(0).shape[2] == 3
    print(cam._proc.pid, flush=True)
    time.sleep(600)
""")


def test_render_worker_exits_when_its_parent_is_killed():
    parent = subprocess.Popen([sys.executable, "-c", SCRIPT], stdout=subprocess.PIPE, text=True,
                              start_new_session=True)
    try:
        worker = int(parent.stdout.readline())
        assert alive(worker)
        parent.send_signal(signal.SIGKILL)
        parent.wait(30)
        assert wait_gone({worker}, timeout_s=20) == set(), "the render worker outlived its parent"
    finally:
        try:
            os.killpg(parent.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
