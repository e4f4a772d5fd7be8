"""Files written whole or not at all: a reader (a test, a benchmark, the campaign's clean-up, a
node joining the run) never sees a half-written file, and a failed write leaves the old file."""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path


def replace_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Call ``write`` on a temporary file beside ``path`` (a hidden, unique name, so two writers and
    directory watchers never take it for the file), then rename it over ``path``; on any error the
    temporary file is removed and the error raised."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all."""
    def write(tmp: Path) -> None:
        tmp.write_text(text, encoding="utf-8")

    replace_atomic(path, write)
