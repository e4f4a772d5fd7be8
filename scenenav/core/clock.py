"""The run's clock: lockstep or realtime, the control tick rate and the lockstep wait limits.

Part of the lockstep protocol (``scenenav.core.lockstep``): the simulator node paces itself with it
and the app layer puts it in the scenario (``clock:`` section, docs/scenarios.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from scenenav.core.config import check
from scenenav.core.contracts import ClockMode


@dataclass(frozen=True)
class ClockConfig:
    mode: ClockMode = ClockMode.LOCKSTEP
    speed_factor: float = 1.0          # realtime mode: simulated seconds per wall second
    tick_rate_hz: float = 100.0        # control tick (IMU, motor commands); physics sub-steps within
    member_timeout_s: float = 30.0     # wall seconds to wait for one lockstep answer before going on
    startup_timeout_s: float = 120.0   # wall seconds to wait for the expected nodes to appear
    # Lockstep: 0 waits for the camera members' answer at the tick a frame is published (its fix is
    # fused at the next tick); N waits N ticks later, so their work overlaps N ticks of flight and
    # the fix is fused N ticks later (still deterministic). Fewer than the ticks between two frames.
    camera_answer_ticks: int = 0       # control ticks a camera member may take to answer a frame
    # Lockstep: when fewer camera members than the run expected remain (one crashed or was stopped),
    # the clock waits up to this many wall seconds for one to join (the launcher's restart of a
    # perception node loads in 2.5-4 s on a quiet machine; your own node started again) before it
    # goes on without; 0 = never wait. Kept short: a node stopped on purpose costs this much.
    rejoin_timeout_s: float = 10.0

    def __post_init__(self) -> None:
        check(self.speed_factor > 0, "speed_factor", self.speed_factor, "a positive number")
        check(10.0 <= self.tick_rate_hz <= 1000.0, "tick_rate_hz", self.tick_rate_hz,
              "10 to 1000 Hz")
        check(self.member_timeout_s > 0, "member_timeout_s", self.member_timeout_s, "> 0 s")
        check(self.startup_timeout_s > 0, "startup_timeout_s", self.startup_timeout_s, "> 0 s")
        check(0.0 <= self.rejoin_timeout_s <= 3600.0, "rejoin_timeout_s", self.rejoin_timeout_s,
              "wall seconds in [0, 3600] (0 = never wait for a camera member to join again)")
        check(isinstance(self.camera_answer_ticks, int) and not isinstance(self.camera_answer_ticks, bool)
              and self.camera_answer_ticks >= 0, "camera_answer_ticks", self.camera_answer_ticks,
              "an integer >= 0 (and fewer than the control ticks between two camera frames)")
