"""System commands (COMMAND_LONG / COMMAND_INT) as ArduCopter 4.5 answers them: RUN_PREARM_CHECKS,
DO_SET_HOME, PREFLIGHT_STORAGE, SET_EKF_SOURCE_SET, PREFLIGHT_REBOOT_SHUTDOWN, DO_MOTOR_TEST. Registered into ``commands.CommandHandler`` by the server (``CommandHandler.register``).

Shell module (pymavlink constants). Facts from ArduPilot's ``GCS_Common.cpp``:

* RUN_PREARM_CHECKS: TEMPORARILY_REJECTED while armed; otherwise the pre-arm checks run and every
  failure goes out as a CRITICAL STATUSTEXT ("PreArm: ..."); the answer is ACCEPTED either way (the
  result is the failures, and SYS_STATUS's pre-arm bit).
* DO_SET_HOME: param1 = 1, or param5 = param6 = 0 (lat = lon = 0), sets home at the current
  location; else at param5/param6 (x/y degE7 for COMMAND_INT), param7 altitude (AMSL for GLOBAL
  frames, above the current home for GLOBAL_RELATIVE_ALT). Invalid coordinates -> DENIED; the
  vehicle refuses (no position estimate, more than 50 km from the EKF origin) -> FAILED. Allowed while
  armed, as ArduCopter (RTL then returns to the new home). A HOME_POSITION follows (HomeChangedEvent).
* PREFLIGHT_STORAGE: param1 = 2 erases the stored parameters (ArduPilot ``AP_Param::erase_all``):
  here the persisted values are dropped so the next start uses the defaults, and the text is
  ArduPilot's "All parameters reset, reboot board"; param1 0 (read) / 1 (write) are ACCEPTED
  without action (this store writes every change at once); anything else -> DENIED. While armed
  -> TEMPORARILY_REJECTED.
* PREFLIGHT_REBOOT_SHUTDOWN (``GCS_MAVLINK::handle_preflight_reboot``): armed -> FAILED; param1 other
  than 1 (reboot) or 3 (reboot to the bootloader: SITL simply restarts) -> UNSUPPORTED; else ACCEPTED,
  and after the ACK the autopilot starts again (``Vehicle.reboot``, then the server hands over the
  stored mission, fence and rally again and sends the boot banner). Differs: the links stay open
  (ArduPilot SITL's process restarts and its TCP clients reconnect); stream rates stay as set.
* DO_MOTOR_TEST (``Copter::mavlink_motor_test_start``): param1 motor (test order), param2 throttle
  type, param3 throttle, param4 timeout s, param5 (COMMAND_INT: x) motor count, cast as ArduCopter
  casts them; NaN or negative -> DENIED; the rules are in ``autopilot_bridge.motor_test``.
* SET_EKF_SOURCE_SET: param1 1..3 selects the EK3_SRC<n>_* parameters (``handle_command_set_ekf_source_set``);
  other values -> DENIED. Of the sources only POSXY changes what this EKF fuses (as with set 1).
"""

from __future__ import annotations

import math
from typing import Callable, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.commands import CommandRequest, CommandResult, MavResult
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    HomeLocation,
    MavFrame,
    MavSeverity,
    MotorTestRequest,
    Outcome,
    Vehicle,
    VehicleTelemetry,
)

STORAGE_READ, STORAGE_WRITE, STORAGE_ERASE = 0, 1, 2   # PREFLIGHT_STORAGE param1 (MAV_CMD docs)
SET_HOME_USE_CURRENT = 1.0                             # DO_SET_HOME param1
REBOOT_AUTOPILOT, REBOOT_TO_BOOTLOADER = 1.0, 3.0      # PREFLIGHT_REBOOT_SHUTDOWN param1


class SystemServices(Protocol):
    """Server facilities the system commands use."""

    def telemetry(self) -> VehicleTelemetry: ...

    def statustext(self, severity: MavSeverity, text: str) -> None: ...

    def erase_stored_params(self) -> None: ...

    def request_reboot(self) -> None: ...


class SystemCommands:
    """The handlers above; ``handlers()`` goes into ``CommandHandler.register``."""

    def __init__(self, vehicle: Vehicle, services: SystemServices) -> None:
        self._vehicle = vehicle
        self._svc = services

    def handlers(self) -> dict[int, Callable[[CommandRequest, object], CommandResult]]:
        m = mavlink2
        return {
            m.MAV_CMD_RUN_PREARM_CHECKS: self._run_prearm_checks,
            m.MAV_CMD_DO_SET_HOME: self._do_set_home,
            m.MAV_CMD_PREFLIGHT_STORAGE: self._preflight_storage,
            m.MAV_CMD_SET_EKF_SOURCE_SET: self._set_ekf_source_set,
            m.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._preflight_reboot,
            m.MAV_CMD_DO_MOTOR_TEST: self._do_motor_test,
        }

    def _preflight_reboot(self, req: CommandRequest, link: object) -> CommandResult:
        if self._svc.telemetry().armed:
            return CommandResult(MavResult.FAILED)
        if req.p(1) not in (REBOOT_AUTOPILOT, REBOOT_TO_BOOTLOADER):
            return CommandResult(MavResult.UNSUPPORTED)
        self._svc.request_reboot()
        return CommandResult(MavResult.ACCEPTED)

    def _do_motor_test(self, req: CommandRequest, link: object) -> CommandResult:
        request = MotorTestRequest.from_params(req.p(1), req.p(2), req.p(3), req.p(4), req.p(5))
        if request is None:
            return CommandResult(MavResult.DENIED)
        return self._outcome(self._vehicle.motor_test(request))

    def _set_ekf_source_set(self, req: CommandRequest, link: object) -> CommandResult:
        number = req.p(1)
        if number not in (1.0, 2.0, 3.0):
            return CommandResult(MavResult.DENIED)
        return self._outcome(self._vehicle.set_ekf_source_set(int(number)))

    def _run_prearm_checks(self, req: CommandRequest, link: object) -> CommandResult:
        if self._svc.telemetry().armed:
            return CommandResult(MavResult.TEMPORARILY_REJECTED)
        for text in self._vehicle.run_prearm_checks():
            self._svc.statustext(MavSeverity.CRITICAL, text)
        return CommandResult(MavResult.ACCEPTED)

    def _do_set_home(self, req: CommandRequest, link: object) -> CommandResult:
        lat, lon = (req.x * 1e-7, req.y * 1e-7) if req.is_int else (req.p(5), req.p(6))
        alt = req.p(7)
        if req.p(1) == SET_HOME_USE_CURRENT or (lat == 0.0 and lon == 0.0):
            return self._outcome(self._vehicle.set_home(None))
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)
                and abs(lat) <= 90.0 and abs(lon) <= 180.0 and abs(alt) < 83_000.0):
            return CommandResult(MavResult.DENIED)
        if not req.is_int or req.frame in (MavFrame.GLOBAL, MavFrame.GLOBAL_INT):
            frame = AltFrame.AMSL
        elif req.frame in (MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_RELATIVE_ALT_INT):
            frame = AltFrame.RELATIVE_HOME
        else:
            return CommandResult(MavResult.DENIED)
        return self._outcome(self._vehicle.set_home(HomeLocation(lat, lon, alt, frame)))

    def _preflight_storage(self, req: CommandRequest, link: object) -> CommandResult:
        action = req.p(1)
        if action not in (STORAGE_READ, STORAGE_WRITE, STORAGE_ERASE):
            return CommandResult(MavResult.DENIED)
        if self._svc.telemetry().armed:
            return CommandResult(MavResult.TEMPORARILY_REJECTED)
        if action == STORAGE_ERASE:
            self._svc.erase_stored_params()
            self._svc.statustext(MavSeverity.WARNING, "All parameters reset, reboot board")
        return CommandResult(MavResult.ACCEPTED)

    def _outcome(self, outcome: Outcome) -> CommandResult:
        if outcome.ok:
            return CommandResult(MavResult.ACCEPTED)
        if outcome.reason:
            self._svc.statustext(MavSeverity.WARNING, outcome.reason)
        return CommandResult(MavResult.FAILED)
