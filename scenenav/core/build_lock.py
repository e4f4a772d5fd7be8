"""One builder at a time for a cached artefact (a generated world, a world's assistant map).

Several processes that need the same missing cache entry at once (the runs of a campaign starting
together on a fresh machine, the workers of a test session) would each build it, and all but one
would throw their copy away: the cache writes through a temporary name renamed into place, which
keeps it correct, not cheap. ``exclusive_build`` serialises them on an advisory lock file
(``fcntl.flock``, released by the kernel when its holder exits or is killed): the first builds, the
others wait and then find the entry in the cache. The lock is best effort: where no lock file can be
made (a read-only cache folder) the caller builds without one, as before.
"""

from __future__ import annotations

import fcntl
import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

log = logging.getLogger(__name__)

#: The lock files' folder, under the cache root.
LOCK_SUBDIR = "locks"


@contextmanager
def exclusive_build(cache_root: Path, name: str, on_wait: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold the build lock ``<cache_root>/locks/<name>.lock`` for the ``with`` block; ``on_wait`` is
    called once if another process holds it (before waiting for it)."""
    path = cache_root / LOCK_SUBDIR / f"{name}.lock"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle = path.open("a+b")
    except OSError as exc:
        log.debug("no build lock %s (%s): building without one", path, exc)
        yield
        return
    with handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if on_wait is not None:
                on_wait()
            fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
