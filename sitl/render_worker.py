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

Images come back through shared memory: a ring of ``IMAGE_SLOTS`` image-sized slots mapped before
the fork; the simulator hands a free slot with each request, the worker writes the image there and
answers with a few bytes (frame, slot, shape). Through the pipe itself a 120 kB image does not fit
its 64 kB buffer: the worker stalled in ``send`` until the simulator collected the frame
``latency_s`` later, and the transfer then cost the simulator's loop about 0.4 ms a frame in
wake-ups between the two processes (``scenenav bench sim``, 2026-12-04). A request with no free
slot (more frames in flight than slots) gets its image through the pipe as before.
"""

from __future__ import annotations

import logging
import mmap
import multiprocessing as mp
import os
import signal
from collections import OrderedDict

import numpy as np

from scenenav.core.parent_death import set_parent_death_signal
from sitl.config import CameraConfig

log = logging.getLogger(__name__)

#: the worker's first message: kernels loaded and the camera built, requests are rendered at once
READY = "ready"
#: image slots in the shared ring (frames in flight at once; beyond that, images go through the pipe)
IMAGE_SLOTS = 8


def die_with_parent(parent_pid: int, sig: int = signal.SIGKILL) -> None:
    """In a forked child: get ``sig`` when the parent dies (Linux ``prctl(PR_SET_PDEATHSIG)``), and
    exit at once if the parent already died before the call (the race prctl's man page names)."""
    set_parent_death_signal(sig)   # not Linux: the closed pipe still ends the child
    if os.getppid() != parent_pid:
        os._exit(0)


def _optics_rng(seed: np.random.SeedSequence | None) -> np.random.Generator | None:
    return np.random.default_rng(seed) if seed is not None else None


def _slot_view(ring: mmap.mmap, slot: int, slot_bytes: int) -> np.ndarray:
    """The bytes of one image slot of the shared ring, as a flat uint8 array (no copy)."""
    return np.frombuffer(ring, dtype=np.uint8, count=slot_bytes, offset=slot * slot_bytes)


def _serve(conn, parent_conn, parent_pid: int, orthophoto: np.ndarray, m_per_px: float,
           cfg: CameraConfig, heights_m: np.ndarray | None, facade_rgb: np.ndarray | None,
           optics_seed: np.random.SeedSequence | None, ring: mmap.mmap, slot_bytes: int) -> None:
    from sitl.camera import GroundCamera, warm_up
    die_with_parent(parent_pid)
    parent_conn.close()   # else this copy keeps the pipe open after the simulator died: no EOF
    warm_up()             # kernels loaded while the simulator starts, not at its first frame
    camera = GroundCamera(-1, orthophoto, m_per_px, cfg, heights_m=heights_m, facade_rgb=facade_rgb,
                          optics_rng=_optics_rng(optics_seed))
    conn.send(READY)
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return
            if msg is None:
                return
            seq, slot, capture_s, pos, q, vel, rates = msg
            image = np.ascontiguousarray(camera.render_capture(capture_s, np.array(pos), np.array(q),
                                                               np.array(vel), np.array(rates)))
            if slot >= 0 and image.dtype == np.uint8 and image.nbytes <= slot_bytes:
                _slot_view(ring, slot, slot_bytes)[:image.nbytes] = image.reshape(-1)
                conn.send((seq, slot, image.shape))
            else:
                conn.send((seq, -1, image))
    finally:
        camera.close()


def _floats(values) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(values, dtype=float).reshape(-1))


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
        self._ring: mmap.mmap | None = None
        self._slot_bytes = cfg.width_px * cfg.height_px * 3
        self._free_slots = list(range(IMAGE_SLOTS))
        self._ready = not cfg.render_in_worker
        if cfg.render_in_worker:
            ctx = mp.get_context("fork")   # the child inherits the orthophoto without a copy
            self._conn, child = ctx.Pipe()
            # anonymous and shared (MAP_SHARED): the forked worker writes, this process reads
            self._ring = mmap.mmap(-1, IMAGE_SLOTS * self._slot_bytes)
            self._proc = ctx.Process(target=_serve,
                                     args=(child, self._conn, os.getpid(), orthophoto, m_per_px, cfg,
                                           heights_m, facade_rgb, optics_seed, self._ring,
                                           self._slot_bytes),
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
        if self._camera is not None:
            self._done[seq] = self._camera.render_capture(
                capture_s, np.asarray(position_enu_m, dtype=float).copy(),
                np.asarray(q_wxyz, dtype=float).copy(), np.asarray(velocity_enu_m_s, dtype=float).copy(),
                np.asarray(body_rates_flu_rad_s, dtype=float).copy())
            return
        slot = self._free_slots.pop() if self._free_slots else -1
        # plain floats pickle in a few microseconds; numpy arrays take several times that
        self._conn.send((seq, slot, float(capture_s), _floats(position_enu_m), _floats(q_wxyz),
                         _floats(velocity_enu_m_s), _floats(body_rates_flu_rad_s)))
        self._in_flight.append(seq)

    def wait_ready(self, timeout_s: float) -> bool:
        """Block until the worker has loaded its kernels and built its camera (at most ``timeout_s``),
        so that the first frame of a run is not a start-up of about 0.3 s inside the lockstep loop
        (``scenenav bench sim``, 2026-12-05). True when ready (always in-process)."""
        if self._ready:
            return True
        try:
            if not self._conn.poll(timeout_s):
                return False
            self._take(self._conn.recv())
        except (EOFError, OSError) as exc:
            raise RuntimeError("the camera render process died (see the simulator log)") from exc
        return self._ready

    def _take(self, msg) -> None:
        if msg == READY:
            self._ready = True
            return
        got_seq, slot, image = msg
        self._in_flight.remove(got_seq)
        if slot >= 0:
            assert self._ring is not None
            shape = tuple(image)
            n = int(np.prod(shape))
            image = _slot_view(self._ring, slot, self._slot_bytes)[:n].reshape(shape).copy()
            self._free_slots.append(slot)
        self._done[got_seq] = image

    def result(self, seq: int) -> np.ndarray:
        while seq not in self._done:
            if not self._in_flight:
                raise KeyError(f"camera frame {seq} was never requested")
            try:
                msg = self._conn.recv()
            except (EOFError, OSError) as exc:
                raise RuntimeError("the camera render process died (see the simulator log)") from exc
            self._take(msg)
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
        if self._ring is not None:
            self._ring.close()
            self._ring = None
        if self._camera is not None:
            self._camera.close()
            self._camera = None
