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


@contextlib.contextmanager
def interrupt_on_stop_signals() -> Iterator[None]:
    """Within the block the first SIGINT or SIGTERM raises KeyboardInterrupt; later ones are only
    logged (a second Ctrl-C must not break the code in ``finally`` that is stopping the children).
    The old handlers return after the block."""
    raised = False

    def handler(signum, _frame) -> None:
        nonlocal raised
        if raised:
            log.warning("signal %d: already stopping", signum)
            return
        raised = True
        raise KeyboardInterrupt(f"signal {signum}")
    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


@contextlib.contextmanager
def stop_signals_deferred() -> Iterator[None]:
    """Within the block SIGINT and SIGTERM wait (blocked in this thread) and are delivered at its
    end: a child started here is recorded before a Ctrl-C can interrupt, so it is always stopped.
    A child inherits the blocked mask through fork and exec: its ``preexec_fn`` calls
    ``unblock_stop_signals``."""
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)


def unblock_stop_signals() -> None:
    """In a child before exec: undo ``stop_signals_deferred``'s mask, so the child can be stopped."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
