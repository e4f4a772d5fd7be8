"""The lockstep protocol, simulator side: who must answer, and waiting for their answers.

Members announce themselves with a Zenoh liveliness token
``scenenav/<ns>/lockstep/member/<role>/<node_id>`` (role ``tick`` or ``camera``) *after* their
subscribers are up, and answer with ``LockstepAck`` on ``lockstep/ack/<node_id>`` after publishing
their outputs (a ``tick`` member that drives the motors answers with its ``MotorCommand`` instead,
which the simulator node feeds in as that member's ack). A member is waited for only for
ticks/frames published after its token was seen; a member whose token disappears (stopped,
crashed, swapped out) is no longer waited for. A member that does not answer within ``timeout_s``
wall seconds is reported and *suspended*: it is not waited for again (so one hung member costs the
run one timeout, not one per tick) until it answers any later sequence number, when it rejoins
(``take_rejoined()`` names it once) and is waited for again. Pure threading, no Zenoh: the node feeds it liveliness changes and acks.

``answer_times()`` reports, per member, how long its answers took: wall seconds from ``published``
of a sequence number to that member's ack of it (round trip plus the member's work), summed over the
answers (``scenenav bench e2e`` shows the mean per member).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from scenenav.core.contracts import LockstepRole

log = logging.getLogger(__name__)


@dataclass
class _Member:
    role: LockstepRole
    joined_after_seq: int          # the member answers only seqs greater than this
    last_ack: int = -1
    suspended: bool = False        # timed out: not waited for until it answers again


class LockstepBarrier:
    """Tracks lockstep members and blocks until every live member acknowledged a sequence number."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._members: dict[str, _Member] = {}
        self._published: dict[LockstepRole, int] = {LockstepRole.TICK: -1, LockstepRole.CAMERA: -1}
        self._published_at: dict[LockstepRole, float] = {}
        self._answer_s: dict[str, float] = {}
        self._answers: dict[str, int] = {}
        self._rejoined: list[str] = []
        self.timeouts = 0

    # called from Zenoh threads ---------------------------------------------------------------
    def member_changed(self, role: LockstepRole, node_id: str, alive: bool) -> None:
        with self._cond:
            if alive:
                if node_id not in self._members:
                    self._members[node_id] = _Member(role, self._published[role])
                    log.info("lockstep member joined: %s (%s)", node_id, role.value)
            elif self._members.pop(node_id, None) is not None:
                log.info("lockstep member left: %s (%s)", node_id, role.value)
            self._cond.notify_all()

    def ack(self, node_id: str, role: LockstepRole, seq: int) -> None:
        with self._cond:
            m = self._members.get(node_id)
            if m is not None and m.role == role and seq > m.last_ack:
                answered_before = m.last_ack
                m.last_ack = seq
                if m.suspended:
                    m.suspended = False
                    self._rejoined.append(node_id)
                    log.info("lockstep member answers again: %s (%s)", node_id, role.value)
                # timed once per published seq: by the first ack that covers it (an ack ahead too)
                if answered_before < self._published[role] <= seq and role in self._published_at:
                    self._answer_s[node_id] = self._answer_s.get(node_id, 0.0) + \
                        time.perf_counter() - self._published_at[role]
                    self._answers[node_id] = self._answers.get(node_id, 0) + 1
                self._cond.notify_all()

    # called from the simulator loop -----------------------------------------------------------
    def published(self, role: LockstepRole, seq: int) -> None:
        """Record that ``seq`` of ``role`` has been published (before waiting for it)."""
        with self._cond:
            self._published[role] = seq
            self._published_at[role] = time.perf_counter()

    def answer_times(self) -> dict[str, tuple[int, float]]:
        """Per member that ever answered: (answers timed, their summed answer time in wall s)."""
        with self._cond:
            return {n: (self._answers[n], self._answer_s[n]) for n in sorted(self._answers)}

    def take_rejoined(self) -> list[str]:
        """Members that answered again after being suspended, since the last call (each once)."""
        with self._cond:
            out, self._rejoined = self._rejoined, []
            return out

    def suspended(self) -> list[str]:
        """Members currently suspended (timed out and not answered since)."""
        with self._cond:
            return sorted(n for n, m in self._members.items() if m.suspended)

    def all_suspended_and_behind(self, role: LockstepRole, limit: int) -> bool:
        """True when ``role`` has members and every one of them is suspended with at least ``limit``
        published sequence numbers after the last it answered (or timed out on): a frozen member,
        whose link would fill if more were sent. A slow member that still answers stays below."""
        with self._cond:
            ms = [m for m in self._members.values() if m.role == role]
            pub = self._published[role]
            return bool(ms) and all(m.suspended and pub - m.last_ack >= limit for m in ms)

    def members(self, role: LockstepRole | None = None) -> list[str]:
        with self._cond:
            return sorted(n for n, m in self._members.items() if role is None or m.role == role)

    def wait_members(self, count: dict[LockstepRole, int], timeout_s: float,
                     cancelled: Callable[[], bool] = lambda: False) -> bool:
        """Wait until at least ``count[role]`` members of each role are present; False after
        ``timeout_s`` or (checked twice a second) once ``cancelled()`` is true."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                ok = all(sum(1 for m in self._members.values() if m.role == r) >= n
                         for r, n in count.items())
                if ok:
                    return True
                left = deadline - time.monotonic()
                if left <= 0 or cancelled():
                    return False
                self._cond.wait(min(left, 0.5))

    def wait(self, role: LockstepRole, seq: int, timeout_s: float) -> list[str]:
        """Block until every live, unsuspended member of ``role`` that must answer ``seq`` has.

        Returns the members that did not answer within ``timeout_s``; they are suspended (skipped
        from now on) until they answer a later sequence number.
        """
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                pending = [n for n, m in self._members.items()
                           if m.role == role and not m.suspended and m.joined_after_seq < seq
                           and m.last_ack < seq]
                if not pending:
                    return []
                left = deadline - time.monotonic()
                if left <= 0:
                    self.timeouts += 1
                    for n in pending:
                        self._members[n].last_ack = seq
                        self._members[n].suspended = True
                    return pending
                self._cond.wait(left)
