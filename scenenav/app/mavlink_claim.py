"""MAVLink system ids of live runs: two runs sending to the same UDP output never both say system 1.

A run that sends MAVLink to a UDP output (``autopilot.mavlink_udp_out``, where ground stations
listen) claims the pair (output, ``SYSID_THISMAV``) for its lifetime with an exclusive ``flock`` on
a small file in a per-user folder. The lock belongs to the launcher process, so it is released
however the launcher ends (even by SIGKILL): there is never a stale claim to clean up. When the id
is already claimed by another live run, the launcher takes the next free id (1..255) if the user
did not choose one, and refuses with one line naming the other run if they did (the
``autopilot.params`` or the parameter file sets ``SYSID_THISMAV``).
"""

from __future__ import annotations

import fcntl
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

from scenenav.core.errors import UserError

#: MAVLink system ids a vehicle may use (MAVLink common: 0 is broadcast).
_SYSIDS = range(1, 256)
#: ArduCopter's default SYSID_THISMAV.
DEFAULT_SYSID = 1


def claims_dir() -> Path:
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    d = Path(base) / f"scenenav-{os.getuid()}" / "mavlink-sysid"
    d.mkdir(parents=True, exist_ok=True)
    return d


@dataclass
class SysidClaim:
    """A held claim; ``release()`` (or the process ending) frees it."""

    udp_out: str
    system_id: int
    fd: int

    def release(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def _lock_path(udp_out: str, sysid: int) -> Path:
    safe = re.sub(r"[^0-9A-Za-z.]+", "_", udp_out)
    return claims_dir() / f"{safe}.sysid{sysid}.lock"


def _try_claim(udp_out: str, sysid: int, owner: str) -> SysidClaim | None:
    fd = os.open(_lock_path(udp_out, sysid), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    os.ftruncate(fd, 0)
    os.write(fd, owner.encode())
    return SysidClaim(udp_out, sysid, fd)


def _owner(udp_out: str, sysid: int) -> str:
    try:
        return _lock_path(udp_out, sysid).read_text().strip() or "another run"
    except OSError:
        return "another run"


def claim_sysid(udp_out: str, wanted: int, chosen_by_user: bool, owner: str) -> SysidClaim:
    """Claim ``wanted`` on ``udp_out`` (HOST:PORT), or the next free id when the user did not
    choose it; UserError when they did and it is taken, or when every id is taken."""
    claim = _try_claim(udp_out, wanted, owner)
    if claim is not None:
        return claim
    if chosen_by_user:
        raise UserError(f"autopilot SYSID_THISMAV = {wanted}: already used by the live run "
                        f"{_owner(udp_out, wanted)} sending MAVLink to UDP {udp_out}; expected "
                        f"another id, or autopilot.mavlink_udp_out=none")
    for sysid in _SYSIDS:
        if sysid != wanted:
            claim = _try_claim(udp_out, sysid, owner)
            if claim is not None:
                return claim
    raise UserError(f"autopilot.mavlink_udp_out = {udp_out}: every MAVLink system id 1..255 is "
                    f"used by a live run; expected a free UDP output or none")
