"""numba's on-disk kernel cache, kept true when a kernel inlines code from another module.

numba (``@njit(cache=True)``) checks only the source file that defines a kernel before it loads the
kernel from its cache (``__pycache__/<module>.<function>-<line>.py311.nbi/.nbc``). The camera's
kernels in ``worlds/view_renderer.py`` inline the ray walk of ``worlds/raycast.py``: after an edit of
``raycast.py`` alone (a developer's change, or a ``git pull``), the old walk would keep running from
the cache. ``drop_stale_kernels`` removes a module's cached kernels when the sources it inlines changed,
so numba compiles them again; it is called at the module's import, before any kernel runs.
"""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

STAMP_SUFFIX = ".inlined-sources"


def sources_digest(paths: list[Path]) -> str:
    """sha256 over the named source files (names and bytes), in the order given."""
    h = hashlib.sha256()
    for p in paths:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def drop_stale_kernels(module_file: str, inlined: list[str]) -> bool:
    """Remove ``module_file``'s cached numba kernels if the files in ``inlined`` (paths relative to
    the module's folder) changed since the cache was written; True if anything was removed.

    A stamp file beside the cache (``__pycache__/<module>.inlined-sources``) holds the digest. Any
    failure to read or write the cache folder leaves it as it is (numba then does what it always
    does); concurrent processes may both remove and both rewrite: numba compiles what is missing.
    """
    module = Path(module_file)
    cache_dir = module.parent / "__pycache__"
    try:
        digest = sources_digest([module.parent / name for name in inlined])
    except OSError:
        return False
    stamp = cache_dir / f"{module.stem}{STAMP_SUFFIX}"
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    removed = 0
    try:
        for f in cache_dir.glob(f"{module.stem}.*"):
            if f.suffix in (".nbi", ".nbc"):
                f.unlink(missing_ok=True)
                removed += 1
        tmp = cache_dir / f".{stamp.name}.{os.getpid()}"
        tmp.write_text(digest)
        os.replace(tmp, stamp)
    except OSError:
        return removed > 0
    if removed:
        log.info("%s: %d cached kernel files dropped (%s changed)", module.name, removed, ", ".join(inlined))
    return removed > 0
