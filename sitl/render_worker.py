"""Camera rendering pipelined with the simulation loop.

``CameraPipeline.request(seq, position, q)`` hands a capture pose to the renderer and returns at
once; ``CameraPipeline.result(seq)`` returns that frame's image, blocking only if it is not ready.
The simulator requests at the capture tick and collects ``latency_s`` later, so the rendering
(``sitl.camera``, a few ms a frame) overlaps the physics and the bus on the second core. The image depends
only on the capture pose, so lockstep runs stay deterministic.

With ``render_in_worker`` the renderer lives in a forked child process; otherwise it renders in-process at request time. The child never outlives the simulator,
even one killed by SIGKILL: it closes its inherited copy of the simulator's end of the pipe (so the
simulator's death closes the pipe and the child sees EOF), and it asks the kernel for SIGKILL when
its parent dies (``PR_SET_PDEATHSIG``, which ``fork()`` does not inherit from the simulator).
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing as mp
import os
import signal
from collections import OrderedDict

import numpy as np

from sitl.config import CameraConfig

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1   # linux/prctl.h


def die_with_parent(parent_pid: int, sig: int = signal.SIGKILL) -> None:
    """In a forked child: get ``sig`` when the parent dies (Linux ``prctl(PR_SET_PDEATHSIG)``), and
    exit at once if the parent already died before the call (the race prctl's man page names)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(sig))
    except (OSError, AttributeError):
        pass   # not Linux: the closed pipe still ends the child
    if os.getppid() != parent_pid:
        os._exit(0)


def _optics_rng(seed: np.random.SeedSequence | None) -> np.random.Generator | None:
    return np.random.default_rng(seed) if seed is not None else None


def _serve(conn, parent_conn, parent_pid: int, orthophoto: np.ndarray, m_per_px: float,
           cfg: CameraConfig, heights_m: np.ndarray | None, facade_rgb: np.ndarray | None,
           optics_seed: np.random.SeedSequence | None) -> None:
    from sitl.camera import GroundCamera, warm_up
    die_with_parent(parent_pid)
    parent_conn.close()   # else this copy keeps the pipe open after the simulator died: no EOF
    warm_up()             # kernels loaded while the simulator starts, not at its first frame
    camera = GroundCamera(-1, orthophoto, m_per_px, cfg, heights_m=heights_m, facade_rgb=facade_rgb,
                          optics_rng=_optics_rng(optics_seed))
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return
            if msg is None:
                return
            seq, capture_s, pos, q, vel, rates = msg
            conn.send((seq, camera.render_capture(capture_s, pos, q, vel, rates)))
    finally:
        camera.close()


class CameraPipeline:
    """Renders capture poses with ``sitl.camera.GroundCamera`` (of the orthophoto and, when given and
    ``cfg.relief``, the DSM ``heights_m`` and facade colours), in a worker or in-process.
    ``optics_seed``: the seed of the camera and mount realism's random stream (``sitl.camera_model``;
    the core's ``optics_seed``); None renders the ideal pinhole image."""

    def __init__(self, orthophoto: np.ndarray, m_per_px: float, cfg: CameraConfig,
                 heights_m: np.ndarray | None = None, facade_rgb: np.ndarray | None = None,
                 optics_seed: np.random.SeedSequence | None = None):
        self.cfg = cfg
        self._done: OrderedDict[int, np.ndarray] = OrderedDict()
        self._in_flight: list[int] = []
        self._proc = None
        self._camera = None
        if cfg.render_in_worker:
            ctx = mp.get_context("fork")   # the child inherits the orthophoto without a copy
            self._conn, child = ctx.Pipe()
            self._proc = ctx.Process(target=_serve,
                                     args=(child, self._conn, os.getpid(), orthophoto, m_per_px, cfg,
                                           heights_m, facade_rgb, optics_seed),
                                     name="camera-render", daemon=True)
            self._proc.start()
            child.close()
        else:
            from sitl.camera import GroundCamera
            self._camera = GroundCamera(-1, orthophoto, m_per_px, cfg, heights_m=heights_m,
                                        facade_rgb=facade_rgb, optics_rng=_optics_rng(optics_seed))

    def request(self, seq: int, position_enu_m, q_wxyz, *, capture_s: float = 0.0,
                velocity_enu_m_s=(0.0, 0.0, 0.0), body_rates_flu_rad_s=(0.0, 0.0, 0.0)) -> None:
        """Render the capture ``seq`` at this truth pose (``capture_s``, velocity and body rates: for
        the jitter, gimbal lag and motion blur of ``sitl.camera_model``)."""
        pos = np.asarray(position_enu_m, dtype=float).copy()
        q = np.asarray(q_wxyz, dtype=float).copy()
        vel = np.asarray(velocity_enu_m_s, dtype=float).copy()
        rates = np.asarray(body_rates_flu_rad_s, dtype=float).copy()
        if self._camera is not None:
            self._done[seq] = self._camera.render_capture(capture_s, pos, q, vel, rates)
            return
        self._conn.send((seq, float(capture_s), pos, q, vel, rates))
        self._in_flight.append(seq)

    def result(self, seq: int) -> np.ndarray:
        while seq not in self._done:
            if not self._in_flight:
                raise KeyError(f"camera frame {seq} was never requested")
            try:
                got_seq, image = self._conn.recv()
            except (EOFError, OSError) as exc:
                raise RuntimeError("the camera render process died (see the simulator log)") from exc
            self._in_flight.remove(got_seq)
            self._done[got_seq] = image
        return self._done.pop(seq)

    def close(self) -> None:
        if self._proc is not None:
            try:
                self._conn.send(None)
            except (OSError, BrokenPipeError):
                pass
            self._proc.join(5)
            if self._proc.is_alive():
                self._proc.terminate()
            self._conn.close()
            self._proc = None
        if self._camera is not None:
            self._camera.close()
            self._camera = None
