"""``--json``: stdout carries the one JSON document and nothing else (``scenenav ... --json | jq``).

``json_only_stdout()`` wraps the whole command: it points file descriptor 1 at stderr, so whatever
else would reach stdout (tables, library banners such as pybullet's "build time" line, progress,
output of child processes, which inherit the descriptor) goes to stderr instead. ``emit_json(obj)``
writes the document to the real stdout. NaN and infinities become ``null`` (strict JSON, which
``jq`` and other parsers require).
"""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TextIO

import numpy as np

_real_stdout: TextIO | None = None


@contextmanager
def json_only_stdout() -> Iterator[None]:
    """Inside: fd 1 and ``sys.stdout`` go to stderr; ``emit_json`` writes to the real stdout."""
    global _real_stdout
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    saved_sys_stdout = sys.stdout
    try:
        on_fd1 = saved_sys_stdout.fileno() == 1
    except (AttributeError, OSError, ValueError):
        on_fd1 = False
    # the document goes where stdout went: fd 1, or the object that replaced sys.stdout
    real = os.fdopen(os.dup(saved), "w", encoding="utf-8") if on_fd1 else saved_sys_stdout
    previous, _real_stdout = _real_stdout, real
    sys.stdout = sys.stderr
    try:
        yield
    finally:
        sys.stdout = saved_sys_stdout
        try:
            sys.stdout.flush()
        except (OSError, ValueError):
            pass
        _real_stdout = previous
        if on_fd1:
            real.close()
        os.dup2(saved, 1)
        os.close(saved)


def run_json_aware(args) -> int:
    """``scenenav.core.errors.run_command(args)``; for a command given ``--json`` (``args.json``),
    inside ``json_only_stdout``. Every entry point runs its commands through this."""
    from scenenav.core.errors import run_command
    if getattr(args, "json", False):
        with json_only_stdout():
            return run_command(args)
    return run_command(args)


def strict(obj: Any) -> Any:
    """``obj`` with every non-finite float replaced by None (tuples become lists, numpy scalars
    and arrays plain numbers and lists)."""
    if isinstance(obj, np.generic | np.ndarray):
        obj = obj.tolist()
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): strict(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [strict(v) for v in obj]
    return obj


def emit_json(obj: Any, out: TextIO | None = None) -> None:
    """Write ``obj`` as one strict JSON document (indented) to ``out`` (default: the real stdout)."""
    if out is None:
        out = _real_stdout if _real_stdout is not None else sys.stdout
    out.write(json.dumps(strict(obj), indent=2, allow_nan=False, default=str) + "\n")
    out.flush()
