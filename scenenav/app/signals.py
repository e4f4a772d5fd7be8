"""Stopping on Ctrl-C and SIGTERM: the one place the project installs signal handlers.

* Nodes (``scenenav node ...``) turn SIGINT/SIGTERM into a ``threading.Event`` and shut down cleanly.
* The launcher and ``scenenav sitl`` turn them into ``KeyboardInterrupt`` (so the code that stops the
  children runs in ``finally``), even when started with SIGINT ignored, as background jobs of
  non-interactive shells are; the previous handlers come back when the block ends.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Iterator

log = logging.getLogger(__name__)

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

#: Wall seconds a node may take to stop after SIGINT/SIGTERM before it exits regardless: when the
#: launcher itself was killed (PDEATHSIG), nobody else would escalate, and a node stuck closing
#: (a bus whose router is gone, a wedged worker) must still not outlive its run.
STOP_DEADLINE_S = 30.0


def _exit_late() -> None:
    log.error("did not stop within %.0f s of the stop signal: exiting now", STOP_DEADLINE_S)
    logging.shutdown()
    os._exit(3)


def stop_event() -> threading.Event:
    """An event that SIGINT or SIGTERM sets (for node processes); the process exits anyway
    ``STOP_DEADLINE_S`` after the first stop signal."""
    ev = threading.Event()

    def handler(signum, _frame) -> None:
        log.info("signal %d: stopping", signum)
        if not ev.is_set():
            timer = threading.Timer(STOP_DEADLINE_S, _exit_late)
            timer.daemon = True
            timer.start()
        ev.set()
    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
    return ev


def _raise_interrupt(signum, _frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def interrupt_on_stop_signals() -> Iterator[None]:
    """Within the block SIGINT and SIGTERM raise KeyboardInterrupt; the old handlers return after."""
    previous = {sig: signal.signal(sig, _raise_interrupt) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
