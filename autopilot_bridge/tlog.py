"""MAVProxy-compatible telemetry log (``.tlog``) writer.

Format (what MAVProxy writes and ``mavlogdump.py`` / ``mavutil.mavlink_connection(path)``
read): a sequence of records, each an 8-byte big-endian unsigned integer timestamp in
microseconds since the Unix epoch followed by one complete raw MAVLink frame (header,
payload, CRC and signature if any). Frames of both directions go into the same file in the
order they were sent or received.
"""

from __future__ import annotations

import logging
import struct
import time
from pathlib import Path
from typing import BinaryIO, Callable

logger = logging.getLogger(__name__)

_TIMESTAMP = struct.Struct(">Q")


class TlogWriter:
    """Appends frames to a .tlog file. Write errors are logged once and disable the log."""

    def __init__(self, path: str | Path, wallclock_s: Callable[[], float] = time.time) -> None:
        self.path = Path(path)
        self._wallclock_s = wallclock_s
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh: BinaryIO | None = open(self.path, "ab")  # noqa: SIM115 (closed in close())
        self.records = 0

    def write(self, frame: bytes, time_us: int | None = None) -> None:
        """Append one raw MAVLink frame stamped with ``time_us`` (default: now)."""
        if self._fh is None:
            return
        if time_us is None:
            time_us = int(self._wallclock_s() * 1e6)
        try:
            self._fh.write(_TIMESTAMP.pack(max(0, time_us)) + bytes(frame))
            self.records += 1
        except OSError:
            logger.exception("tlog %s: write failed; logging stopped", self.path)
            self._close_quietly()

    def flush(self) -> None:
        if self._fh is not None:
            try:
                self._fh.flush()
            except OSError:
                logger.exception("tlog %s: flush failed; logging stopped", self.path)
                self._close_quietly()

    def close(self) -> None:
        self.flush()
        self._close_quietly()

    def _close_quietly(self) -> None:
        fh, self._fh = self._fh, None
        if fh is not None:
            try:
                fh.close()
            except OSError:
                logger.warning("tlog %s: close failed", self.path)
