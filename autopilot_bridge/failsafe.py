"""Failsafes of the flight core (pure: no zenoh, no pymavlink): GCS heartbeat loss and vision loss.

``FailsafeMonitor.update(inputs, settings)`` is called once per control tick with simulated time and
returns the :class:`FailsafeEvent` s of that tick; the flight core applies their ``action`` (mode
change or position hold) and announces their ``text`` (STATUSTEXT to the ground stations, an Event
on the bus).

GCS failsafe (ArduCopter ``FS_GCS_ENABLE`` / ``FS_GCS_TIMEOUT``, ``ArduCopter/events.cpp``):

* armed only once a heartbeat of the ground station ``SYSID_MYGCS`` has been seen;
* triggers when no such heartbeat arrived for ``FS_GCS_TIMEOUT`` seconds while the vehicle is
  armed and flying (on the ground nothing happens; ArduCopter would disarm there);
* action by ``FS_GCS_ENABLE``: 1 RTL, 3 SmartRTL-or-RTL (no SmartRTL here: RTL), 4 SmartRTL-or-Land
  (no SmartRTL: LAND), 5 LAND; 0 disables it (2, "continue mission", is deprecated in ArduCopter
  and refused by the parameter store);
* clears (announced, no mode change, as ArduCopter) when heartbeats come back.

Vision failsafe (scenenav, GPS-denied flight with EK3_SRC1_POSXY = 6):

* evaluated while armed, flying, in a position-controlled mode, neither taking off nor landing, and
  high enough for scene matching (``SN_VIS_MIN_ALT``); the clock starts at the newest of the last
  usable fix and the moment these conditions began to hold (so a take-off climb never trips: the
  fixes may start only above SN_VIS_MIN_ALT, where perception rates them);
* no usable fix for ``SN_VIS_TIMEOUT`` s -> HOLD: stop and hold position on dead reckoning;
* ... unless ``SN_VIS_DR_MAX`` > 0: then the vehicle first flies on in its mode on dead reckoning
  (announced; DEAD_RECKONING) and holds only once the EKF's horizontal 1-sigma position uncertainty
  exceeds ``SN_VIS_DR_MAX`` m, as ArduCopter flies on through a GPS loss until its EKF failsafe
  (``FS_EKF_THRESH``) or dead-reckoning failsafe (``FS_DR_TIMEOUT``) acts: a vehicle over ground
  that cannot be matched (water, forest, a district of tall buildings, the map's edge) gets no fix by
  hovering there, but may by flying on. A fix during it -> back to NORMAL (announced);
* a usable fix during the hold -> RESUME; still none ``SN_VIS_FS_LAND`` s later -> LAND;
* ``SN_VIS_TIMEOUT`` = 0 disables it. Disarming resets both failsafes.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from enum import Enum, IntEnum

from autopilot_bridge.vehicle_interface import MavSeverity

logger = logging.getLogger(__name__)


class GcsFailsafeAction(IntEnum):
    """FS_GCS_ENABLE values (ArduCopter 4.5)."""

    DISABLED = 0
    RTL = 1
    CONTINUE_MISSION = 2      # deprecated in ArduCopter 4.0+, not accepted by the parameter store
    SMARTRTL_OR_RTL = 3
    SMARTRTL_OR_LAND = 4
    LAND = 5


class FailsafeKind(Enum):
    GCS = "gcs"
    VISION = "vision"
    EKF = "ekf"            # failsafe_checks.EkfCheck
    BATTERY = "battery"    # failsafe_checks.BatteryFailsafe
    FENCE = "fence"        # geofence.FenceMonitor
    RADIO = "radio"        # pilot.PilotMixin._radio_failsafe_check (RC overrides stop, FS_THR_ENABLE)


class FailsafeAction(Enum):
    """What the flight core must do for a failsafe event."""

    RTL = "rtl"
    LAND = "land"
    HOLD = "hold"          # stop and hold the current position on dead reckoning
    RESUME = "resume"      # release a HOLD (the position source is back)
    CLEARED = "cleared"    # announcement only (GCS heartbeats are back)
    REPORT = "report"      # announcement only (the failsafe's action is "report" or not applicable)
    ALT_HOLD = "alt_hold"  # switch to ALT_HOLD (FS_EKF_ACTION 2)
    BRAKE = "brake"        # switch to BRAKE, LAND if refused (FENCE_ACTION 4)
    LAND_START_OR_RTL = "land_start_or_rtl"   # the mission's landing sequence (AUTO_RTL), else RTL


class VisionFailsafeState(Enum):
    NORMAL = "normal"
    DEAD_RECKONING = "dead_reckoning"   # no fix for SN_VIS_TIMEOUT, flying on (SN_VIS_DR_MAX > 0)
    HOLD = "hold"
    LAND = "land"


@dataclass(frozen=True)
class FailsafeEvent:
    kind: FailsafeKind
    action: FailsafeAction
    severity: MavSeverity
    text: str


@dataclass(frozen=True)
class FailsafeSettings:
    """The parameters the failsafes obey (read every tick, so changes apply at once)."""

    gcs_action: int = int(GcsFailsafeAction.DISABLED)   # FS_GCS_ENABLE
    gcs_timeout_s: float = 5.0                          # FS_GCS_TIMEOUT
    vision_timeout_s: float = 5.0                       # SN_VIS_TIMEOUT (0 = off)
    vision_land_after_s: float = 10.0                   # SN_VIS_FS_LAND
    vision_dr_max_m: float = 0.0                        # SN_VIS_DR_MAX (0 = hold at the timeout)


@dataclass(frozen=True)
class FailsafeInputs:
    """The vehicle state the failsafes look at, all times in simulated seconds."""

    now_s: float
    armed: bool
    flying: bool
    position_mode: bool                 # a position-controlled mode (GUIDED, AUTO, LOITER, RTL, LAND)
    landing: bool                       # in a landing descent (LAND, RTL/AUTO final descent)
    gcs_last_heartbeat_s: float | None  # newest heartbeat of SYSID_MYGCS (None: never seen)
    vision_required: bool               # the horizontal position source is external navigation
    vision_height_ok: bool              # high enough above home for scene matching
    last_vision_fix_s: float | None     # newest usable fix (None: none yet)
    taking_off: bool = False            # climbing in a take-off (AUTO NAV_TAKEOFF, GUIDED takeoff)
    position_std_m: float = 0.0         # the EKF's horizontal 1-sigma position uncertainty


@functools.lru_cache(maxsize=64)
def gcs_action_of(value: int) -> FailsafeAction | None:
    """The action for an FS_GCS_ENABLE value (None: disabled or unknown)."""
    try:
        setting = GcsFailsafeAction(int(value))
    except ValueError:
        return None
    if setting in (GcsFailsafeAction.RTL, GcsFailsafeAction.SMARTRTL_OR_RTL,
                   GcsFailsafeAction.CONTINUE_MISSION):
        return FailsafeAction.RTL
    if setting in (GcsFailsafeAction.SMARTRTL_OR_LAND, GcsFailsafeAction.LAND):
        return FailsafeAction.LAND
    return None


class FailsafeMonitor:
    """GCS and vision failsafe state machines (see the module docstring)."""

    def __init__(self) -> None:
        self._gcs_active = False
        self._vision = VisionFailsafeState.NORMAL
        self._vision_since_s: float | None = None   # when vision became expected
        self._hold_start_s = 0.0

    @property
    def gcs_active(self) -> bool:
        return self._gcs_active

    @property
    def vision_state(self) -> VisionFailsafeState:
        return self._vision

    @property
    def any_active(self) -> bool:
        """A failsafe has acted (dead reckoning on without fixes is a warning, not a failsafe)."""
        return self._gcs_active or self._vision in (VisionFailsafeState.HOLD, VisionFailsafeState.LAND)

    def reset(self) -> None:
        """Disarmed: forget both failsafes."""
        self._gcs_active = False
        self._vision = VisionFailsafeState.NORMAL
        self._vision_since_s = None

    def update(self, inp: FailsafeInputs, settings: FailsafeSettings) -> list[FailsafeEvent]:
        events: list[FailsafeEvent] = []
        if not inp.armed:
            self.reset()
            return events
        self._update_gcs(inp, settings, events)
        self._update_vision(inp, settings, events)
        return events

    # ------------------------------------------------------------------ GCS
    def _update_gcs(self, inp: FailsafeInputs, settings: FailsafeSettings,
                    events: list[FailsafeEvent]) -> None:
        action = gcs_action_of(settings.gcs_action)
        last = inp.gcs_last_heartbeat_s
        if action is None or last is None:
            if self._gcs_active:
                self._gcs_active = False
                events.append(FailsafeEvent(FailsafeKind.GCS, FailsafeAction.CLEARED,
                                            MavSeverity.INFO, "GCS Failsafe Cleared"))
            return
        lost = inp.now_s - last > settings.gcs_timeout_s
        if lost and not self._gcs_active and inp.flying:
            self._gcs_active = True
            name = "RTL" if action == FailsafeAction.RTL else "Land"
            logger.warning("GCS failsafe: no heartbeat for %.1f s -> %s", inp.now_s - last, name)
            events.append(FailsafeEvent(FailsafeKind.GCS, action, MavSeverity.CRITICAL,
                                        f"GCS Failsafe: no heartbeat for "
                                        f"{inp.now_s - last:.0f}s, {name}"))
        elif not lost and self._gcs_active:
            self._gcs_active = False
            events.append(FailsafeEvent(FailsafeKind.GCS, FailsafeAction.CLEARED,
                                        MavSeverity.INFO, "GCS Failsafe Cleared"))

    # ------------------------------------------------------------------ vision
    def _update_vision(self, inp: FailsafeInputs, settings: FailsafeSettings,
                       events: list[FailsafeEvent]) -> None:
        if not inp.vision_required or settings.vision_timeout_s <= 0.0:
            if self._vision == VisionFailsafeState.HOLD:
                self._vision = VisionFailsafeState.NORMAL
                events.append(FailsafeEvent(FailsafeKind.VISION, FailsafeAction.RESUME,
                                            MavSeverity.INFO,
                                            "Vision failsafe cleared: not required"))
            elif self._vision == VisionFailsafeState.DEAD_RECKONING:
                self._vision = VisionFailsafeState.NORMAL
            self._vision_since_s = None
            return
        expected = (inp.flying and inp.position_mode and not inp.landing and not inp.taking_off
                    and inp.vision_height_ok)
        if self._vision == VisionFailsafeState.LAND:
            return
        if self._vision in (VisionFailsafeState.NORMAL, VisionFailsafeState.DEAD_RECKONING):
            self._update_vision_flying(inp, settings, expected, events)
            return
        # HOLD
        fresh = (inp.last_vision_fix_s is not None
                 and inp.now_s - inp.last_vision_fix_s <= settings.vision_timeout_s
                 and inp.last_vision_fix_s >= self._hold_start_s)
        if fresh:
            self._vision = VisionFailsafeState.NORMAL
            self._vision_since_s = inp.now_s
            events.append(FailsafeEvent(FailsafeKind.VISION, FailsafeAction.RESUME,
                                        MavSeverity.INFO, "Vision Failsafe Cleared: fixes are back"))
            return
        held = inp.now_s - self._hold_start_s
        if inp.landing or held > settings.vision_land_after_s:
            self._vision = VisionFailsafeState.LAND
            logger.warning("vision failsafe: still no fix after %.1f s of hold -> land", held)
            events.append(FailsafeEvent(FailsafeKind.VISION, FailsafeAction.LAND,
                                        MavSeverity.CRITICAL,
                                        f"Vision Failsafe: no fix for {held:.0f}s more, Land"))

    def _update_vision_flying(self, inp: FailsafeInputs, settings: FailsafeSettings, expected: bool,
                              events: list[FailsafeEvent]) -> None:
        """NORMAL or DEAD_RECKONING: start the clock, fly on while the estimate allows, then HOLD."""
        if not expected:
            self._vision_since_s = None
            if self._vision == VisionFailsafeState.DEAD_RECKONING:
                self._vision = VisionFailsafeState.NORMAL
            return
        if self._vision_since_s is None:
            self._vision_since_s = inp.now_s
        ref = self._vision_since_s
        if inp.last_vision_fix_s is not None:
            ref = max(ref, inp.last_vision_fix_s)
        stale = inp.now_s - ref
        if stale <= settings.vision_timeout_s:
            if self._vision == VisionFailsafeState.DEAD_RECKONING:
                self._vision = VisionFailsafeState.NORMAL
                events.append(FailsafeEvent(FailsafeKind.VISION, FailsafeAction.REPORT,
                                            MavSeverity.INFO, "Vision fixes are back: dead reckoning ended"))
            return
        dr_max = settings.vision_dr_max_m
        if dr_max > 0.0 and inp.position_std_m <= dr_max:
            if self._vision == VisionFailsafeState.NORMAL:
                self._vision = VisionFailsafeState.DEAD_RECKONING
                logger.warning("vision lost for %.1f s: dead reckoning on (position 1-sigma %.1f m)",
                               stale, inp.position_std_m)
                events.append(FailsafeEvent(
                    FailsafeKind.VISION, FailsafeAction.REPORT, MavSeverity.WARNING,
                    f"Vision lost for {stale:.0f}s: dead reckoning (1-sigma "
                    f"{inp.position_std_m:.1f}m of {dr_max:.0f}m)"))
            return
        self._vision = VisionFailsafeState.HOLD
        self._hold_start_s = inp.now_s
        why = (f"no fix for {stale:.0f}s, holding" if dr_max <= 0.0 else
               f"no fix for {stale:.0f}s and 1-sigma {inp.position_std_m:.1f}m > {dr_max:.0f}m, holding")
        logger.warning("vision failsafe: %s", why)
        events.append(FailsafeEvent(FailsafeKind.VISION, FailsafeAction.HOLD, MavSeverity.CRITICAL,
                                    f"Vision Failsafe: {why}"))
