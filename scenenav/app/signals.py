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

from scenenav.core.parent_death import parent_death_signal

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


#: How often a node looks whether its parent (the launcher) is still there (``stop_event``).
PARENT_POLL_S = 0.5


def stop_event(watch_parent: bool | None = None) -> threading.Event:
    """An event that SIGINT or SIGTERM sets (for node processes); the process exits anyway
    ``STOP_DEADLINE_S`` after the first stop signal.

    ``watch_parent`` (default: when a parent-death signal is set, i.e. the launcher started this node
    to die with it; a node a user started by hand may outlive its shell): a daemon thread also sets
    the event (and starts the same deadline) when the process's parent is gone (it was re-parented).
    PDEATHSIG's SIGTERM alone is not enough: Python runs a signal handler only in the main thread
    between bytecodes, so a main thread blocked in native code (a bus call whose peer is gone, a long
    kernel) never starts the deadline, and the node would outlive its run. The watchdog does not
    depend on the main thread."""
    ev = threading.Event()
    # Re-entrant: a second signal can interrupt the handler's own call in the main thread.
    deadline_lock = threading.RLock()
    deadline_armed = threading.Event()

    def stop(why: str) -> None:
        with deadline_lock:
            if not deadline_armed.is_set():
                deadline_armed.set()
                log.info("%s: stopping", why)
                timer = threading.Timer(STOP_DEADLINE_S, _exit_late)
                timer.daemon = True
                timer.start()
        ev.set()

    def handler(signum, _frame) -> None:
        stop(f"signal {signum}")
    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
    if watch_parent is None:
        watch_parent = parent_death_signal() != 0
    if watch_parent:
        parent = os.getppid()

        def watch() -> None:
            while not ev.wait(PARENT_POLL_S):
                if os.getppid() != parent:
                    stop(f"parent process {parent} is gone")
                    return
        threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()
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
