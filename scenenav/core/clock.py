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

    def __post_init__(self) -> None:
        check(self.speed_factor > 0, "speed_factor", self.speed_factor, "a positive number")
        check(10.0 <= self.tick_rate_hz <= 1000.0, "tick_rate_hz", self.tick_rate_hz,
              "10 to 1000 Hz")
        check(self.member_timeout_s > 0, "member_timeout_s", self.member_timeout_s, "> 0 s")
        check(self.startup_timeout_s > 0, "startup_timeout_s", self.startup_timeout_s, "> 0 s")
