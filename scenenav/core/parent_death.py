"""The parent-death signal of a process (Linux ``prctl(PR_SET_PDEATHSIG / PR_GET_PDEATHSIG)``).

A child that sets it gets ``sig`` from the kernel when its parent dies, even by SIGKILL: the
launcher's nodes (SIGTERM), the simulator's forked render worker (SIGKILL). ``fork()`` and
``exec()`` of a set-uid program clear it, so each child sets its own. Off Linux both calls do
nothing and report so; callers keep their own fallback (a closed pipe, the launcher's shutdown).
"""

from __future__ import annotations

import ctypes
import signal

_PR_SET_PDEATHSIG = 1   # linux/prctl.h
_PR_GET_PDEATHSIG = 2


def _libc() -> ctypes.CDLL | None:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl   # noqa: B018 - AttributeError where there is no prctl (not Linux)
    except (OSError, AttributeError):
        return None
    return libc


def set_parent_death_signal(sig: int = signal.SIGTERM) -> bool:
    """Ask the kernel for ``sig`` when this process's parent dies; False where that is not possible."""
    libc = _libc()
    return libc is not None and libc.prctl(_PR_SET_PDEATHSIG, int(sig)) == 0


def parent_death_signal() -> int:
    """The signal this process gets when its parent dies; 0 if none is set (or not Linux)."""
    libc = _libc()
    if libc is None:
        return 0
    sig = ctypes.c_int(0)
    if libc.prctl(_PR_GET_PDEATHSIG, ctypes.byref(sig)) != 0:
        return 0
    return int(sig.value)
