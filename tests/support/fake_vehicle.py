"""Test helpers for the MAVLink server: an in-memory Vehicle and polling/GCS utilities.

``FakeVehicle`` has just enough kinematics to make the protocol observable: arming with a
pre-arm check that can fail with a reason, takeoff sets the altitude, landing zeroes it, mode
changes raise events, the mission is stored. Every state-changing call is recorded in
``calls`` so tests can assert that garbage never reached the vehicle.
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import threading
import time
from typing import Callable, Iterator

# pymavlink clients speak MAVLink 2 (mavutil reads this when a connection sets its dialect)
os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.mavlink_server import MavlinkServer, MavlinkServerConfig
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.vehicle_interface import (
    AltFrame,
    GlobalPositionTarget,
    HomeChangedEvent,
    HomeLocation,
    LandedState,
    LocalPositionTarget,
    MavSeverity,
    MissionCommand,
    MissionItem,
    MissionState,
    ModeChangedEvent,
    MotorTestRequest,
    Odometry,
    Outcome,
    SpeedType,
    StatusTextEvent,
    SystemStatus,
    VehicleEvent,
    VehicleTelemetry,
)

HOME = (47.397742, 8.545594, 488.0)  # lat, lon, alt AMSL (PX4/ArduPilot SITL default area)

# Calls that change what the vehicle does (as opposed to read-only or bookkeeping calls).
MOVING_CALLS = frozenset({"arm", "disarm", "set_mode", "takeoff", "land", "return_to_launch",
                          "start_mission", "set_current_mission_item", "reposition",
                          "change_speed", "set_position_target_local_ned",
                          "set_position_target_global_int", "condition_yaw", "set_roi",
                          "pause_continue", "rc_channels_override", "manual_control"})


class FakeVehicle:
    """In-memory Vehicle (see autopilot_bridge.vehicle_interface.Vehicle)."""

    def __init__(self, prearm_failure: str | None = None) -> None:
        self.prearm_failure = prearm_failure
        self.time_boot_ms = 0
        self.armed = False
        self.mode = CopterMode.STABILIZE
        self.relative_alt_m = 0.0
        self.mission: tuple[MissionItem, ...] = ()
        self.mission_seq = 0
        self.params_seen: dict[str, float] = {}
        self.calls: list[tuple[str, tuple]] = []
        self.vision: list[tuple] = []
        self._events: list[VehicleEvent] = []
        self._lock = threading.Lock()

    # ----------------------------------------------------------------- helpers for tests
    def moving_calls(self) -> list[tuple[str, tuple]]:
        with self._lock:
            return [c for c in self.calls if c[0] in MOVING_CALLS]

    def push_event(self, event: VehicleEvent) -> None:
        with self._lock:
            self._events.append(event)

    def _record(self, name: str, *args: object) -> None:
        self.calls.append((name, args))

    # ----------------------------------------------------------------- Vehicle
    def telemetry(self) -> VehicleTelemetry:
        with self._lock:
            flying = self.relative_alt_m > 0.0
            return VehicleTelemetry(
                time_boot_ms=self.time_boot_ms, armed=self.armed, mode=self.mode,
                landed_state=LandedState.IN_AIR if flying else LandedState.ON_GROUND,
                system_status=SystemStatus.ACTIVE if flying else SystemStatus.STANDBY,
                lat_deg=HOME[0], lon_deg=HOME[1], alt_amsl_m=HOME[2] + self.relative_alt_m,
                relative_alt_m=self.relative_alt_m,
                position_ned_m=(0.0, 0.0, -self.relative_alt_m),
                attitude_rpy_rad=(0.01, -0.02, math.radians(90.0)), heading_deg=90.0,
                battery_voltage_v=12.4, battery_current_a=1.5, battery_remaining_pct=87,
                home_set=True, home_lat_deg=HOME[0], home_lon_deg=HOME[1],
                home_alt_amsl_m=HOME[2], origin_set=True, origin_lat_deg=HOME[0],
                origin_lon_deg=HOME[1], origin_alt_amsl_m=HOME[2], mission_current_seq=self.mission_seq,
                mission_state=MissionState.NOT_STARTED if self.mission else MissionState.NO_MISSION,
                ekf_flags=0x1FF)

    def drain_events(self) -> list[VehicleEvent]:
        with self._lock:
            events, self._events = self._events, []
        return events

    def fence_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        with self._lock:
            self._record("fence_changed", items)
            return Outcome(True)

    def rally_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        with self._lock:
            self._record("rally_changed", items)
            return Outcome(True)

    def set_ekf_source_set(self, number: int) -> Outcome:
        with self._lock:
            self._record("set_ekf_source_set", number)
            return Outcome(True)

    def run_prearm_checks(self) -> list[str]:
        with self._lock:
            self._record("run_prearm_checks")
            return [self.prearm_failure] if self.prearm_failure else []

    def set_home(self, home: HomeLocation | None) -> Outcome:
        with self._lock:
            self._record("set_home", home)
            self._events.append(HomeChangedEvent())
            return Outcome(True)

    def set_gps_global_origin(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Outcome:
        with self._lock:
            self._record("set_gps_global_origin", lat_deg, lon_deg, alt_amsl_m)
            return Outcome(True)

    def motor_test(self, request: MotorTestRequest) -> Outcome:
        with self._lock:
            self._record("motor_test", request)
            return Outcome(not self.armed)

    def reboot(self) -> None:
        with self._lock:
            self._record("reboot")
            self.mission = ()

    def arm(self, force: bool) -> Outcome:
        with self._lock:
            self._record("arm", force)
            if self.prearm_failure and not force:
                return Outcome(False, self.prearm_failure)
            self.armed = True
            self._events.append(StatusTextEvent(MavSeverity.INFO, "Arming motors"))
            return Outcome(True)

    def disarm(self, force: bool) -> Outcome:
        with self._lock:
            self._record("disarm", force)
            if self.relative_alt_m > 0.0 and not force:
                return Outcome(False, "Disarm: vehicle is flying")
            self.armed = False
            return Outcome(True)

    def _set_mode(self, mode: CopterMode) -> None:
        if mode != self.mode:
            self.mode = mode
            self._events.append(ModeChangedEvent(mode))

    def set_mode(self, mode: CopterMode) -> Outcome:
        with self._lock:
            self._record("set_mode", mode)
            if mode == CopterMode.AUTO and not self.mission:
                return Outcome(False, "Flight mode change failed: no mission")
            self._set_mode(mode)
            return Outcome(True)

    def takeoff(self, alt_m: float, must_navigate: bool = True) -> Outcome:
        with self._lock:
            if must_navigate:
                self._record("takeoff", alt_m)
            else:                                   # NAV_TAKEOFF param3 != 0
                self._record("takeoff", alt_m, must_navigate)
            if not self.armed:
                return Outcome(False, "Takeoff: motors not armed")
            if self.mode != CopterMode.GUIDED:
                return Outcome(False, "Takeoff: mode must be GUIDED")
            self.relative_alt_m = alt_m
            return Outcome(True)

    def land(self) -> Outcome:
        with self._lock:
            self._record("land")
            self._set_mode(CopterMode.LAND)
            self.relative_alt_m = 0.0
            return Outcome(True)

    def return_to_launch(self) -> Outcome:
        with self._lock:
            self._record("return_to_launch")
            self._set_mode(CopterMode.RTL)
            return Outcome(True)

    def start_mission(self, first_seq: int, last_seq: int) -> Outcome:
        with self._lock:
            self._record("start_mission", first_seq, last_seq)
            if not self.mission:
                return Outcome(False, "Mission: no mission")
            self._set_mode(CopterMode.AUTO)
            self.mission_seq = 1
            return Outcome(True)

    def set_current_mission_item(self, seq: int) -> Outcome:
        with self._lock:
            self._record("set_current_mission_item", seq)
            self.mission_seq = seq
            return Outcome(True)

    def jump_to_landing_sequence(self) -> Outcome:
        """The first DO_LAND_START of the mission (the real core takes the nearest), mode AUTO_RTL."""
        with self._lock:
            self._record("jump_to_landing_sequence")
            starts = [i.seq for i in self.mission if i.command == MissionCommand.DO_LAND_START]
            if not starts:
                return Outcome(False, "Mode change to AUTO RTL failed: No landing sequence found")
            self.mission_seq = starts[0]
            self._set_mode(CopterMode.AUTO_RTL)
            return Outcome(True)

    def fence_enable(self, action: int, fence_mask: int) -> Outcome:
        """Records the call; actions other than 0, 1, 2 are refused as the real core refuses them."""
        with self._lock:
            self._record("fence_enable", action, fence_mask)
            if action not in (0, 1, 2):
                return Outcome(False, f"Fence: unknown DO_FENCE_ENABLE action {action}")
            return Outcome(True)

    def reposition(self, lat_deg: float, lon_deg: float, alt_m: float, alt_frame: AltFrame,
                   speed_m_s: float | None, yaw_deg: float | None) -> Outcome:
        with self._lock:
            self._record("reposition", lat_deg, lon_deg, alt_m, alt_frame, speed_m_s, yaw_deg)
            return Outcome(True)

    def change_speed(self, speed_type: SpeedType, speed_m_s: float) -> Outcome:
        with self._lock:
            self._record("change_speed", speed_type, speed_m_s)
            return Outcome(True)

    def condition_yaw(self, angle_deg: float, rate_deg_s: float, direction: int,
                      relative: bool) -> Outcome:
        with self._lock:
            self._record("condition_yaw", angle_deg, rate_deg_s, direction, relative)
            return Outcome(True)

    def set_roi(self, lat_deg: float, lon_deg: float, alt_m: float, alt_frame: AltFrame) -> Outcome:
        with self._lock:
            self._record("set_roi", lat_deg, lon_deg, alt_m, alt_frame)
            return Outcome(True)

    def rc_channels_override(self, channels: tuple[int, ...]) -> None:
        with self._lock:
            self._record("rc_channels_override", channels)

    def manual_control(self, x: float, y: float, z: float, r: float) -> None:
        with self._lock:
            self._record("manual_control", x, y, z, r)

    def pause_continue(self, pause: bool) -> Outcome:
        with self._lock:
            self._record("pause_continue", pause)
            if self.mode not in (CopterMode.GUIDED, CopterMode.AUTO):
                return Outcome(False, "Failed to pause" if pause else "Failed to resume")
            return Outcome(True)

    def set_position_target_local_ned(self, target: LocalPositionTarget) -> None:
        with self._lock:
            self._record("set_position_target_local_ned", target)

    def set_position_target_global_int(self, target: GlobalPositionTarget) -> None:
        with self._lock:
            self._record("set_position_target_global_int", target)

    def vision_position_estimate(self, usec: int, x_ned_m: float, y_ned_m: float,
                                 z_ned_m: float, roll_rad: float, pitch_rad: float,
                                 yaw_rad: float, covariance: tuple[float, ...],
                                 reset_counter: int) -> None:
        with self._lock:
            self.vision.append((usec, x_ned_m, y_ned_m, z_ned_m, roll_rad, pitch_rad, yaw_rad))

    def odometry(self, odom: Odometry) -> None:
        with self._lock:
            self.vision.append(("odometry", odom))

    def param_changed(self, name: str, value: float) -> None:
        with self._lock:
            self.params_seen[name] = value

    def mission_changed(self, items: tuple[MissionItem, ...]) -> Outcome:
        with self._lock:
            self._record("mission_changed", len(items))
            self.mission = items
            return Outcome(True)


# --------------------------------------------------------------------------- server helpers


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A currently free localhost port (bind to port 0)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def server_config(**overrides: object) -> MavlinkServerConfig:
    """Server config on free ports, UDP target on a free port nobody listens to."""
    base: dict[str, object] = dict(tcp_port=0, udp_bind_port=0,
                                   udp_target_port=free_port(socket.SOCK_DGRAM))
    base.update(overrides)
    return MavlinkServerConfig(**base)  # type: ignore[arg-type]


class PolledServer:
    """Runs ``server.poll(time.monotonic())`` in a background thread (tests with real clients)."""

    def __init__(self, server: MavlinkServer, period_s: float = 0.005) -> None:
        self.server = server
        self._period_s = period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mavlink-poll", daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.server.poll(time.monotonic())
            time.sleep(self._period_s)

    def __enter__(self) -> PolledServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.server.close()


@contextlib.contextmanager
def running_server(vehicle: FakeVehicle | None = None, params: ParameterStore | None = None,
                   **cfg: object) -> Iterator[tuple[MavlinkServer, FakeVehicle]]:
    """A polled server with a FakeVehicle on free ports."""
    vehicle = vehicle or FakeVehicle()
    server = MavlinkServer(vehicle, params or ParameterStore(), server_config(**cfg))
    with PolledServer(server):
        yield server, vehicle


def gcs_connection(port: int, source_system: int = 255,
                   source_component: int = 190) -> mavutil.mavfile:
    """A pymavlink TCP client (ground station identity 255/190 like MAVProxy)."""
    conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=source_system,
                                      source_component=source_component, dialect="ardupilotmega",
                                      autoreconnect=False)
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    return conn


def _backlog(conn: mavutil.mavfile) -> list:
    """Messages received but not yet asked for (kept so no test loses a reply)."""
    if not hasattr(conn, "_test_backlog"):
        conn._test_backlog = []  # type: ignore[attr-defined]
    return conn._test_backlog  # type: ignore[attr-defined]


def _matches(msg: mavlink2.MAVLink_message, kinds: tuple[str, ...],
             condition: Callable[[mavlink2.MAVLink_message], bool] | None) -> bool:
    return msg.get_type() in kinds and (condition is None or bool(condition(msg)))


def wait_for(conn: mavutil.mavfile, kind: str | list[str], timeout_s: float = 10.0,
             condition: Callable[[mavlink2.MAVLink_message], bool] | None = None
             ) -> mavlink2.MAVLink_message | None:
    """First message of ``kind`` satisfying ``condition`` within ``timeout_s`` (or None).

    Other messages read meanwhile stay in a backlog for later calls, in arrival order.
    """
    kinds = (kind,) if isinstance(kind, str) else tuple(kind)
    backlog = _backlog(conn)
    for i, msg in enumerate(backlog):
        if _matches(msg, kinds, condition):
            del backlog[i]
            return msg
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(blocking=True, timeout=0.2)
        if msg is None or msg.get_type() == "BAD_DATA":
            continue
        if _matches(msg, kinds, condition):
            return msg
        backlog.append(msg)
        if len(backlog) > 20000:
            del backlog[:10000]
    return None


def drain(conn: mavutil.mavfile, kind: str, quiet_s: float = 0.3) -> list:
    """All messages of ``kind`` in the backlog and arriving until ``quiet_s`` of silence."""
    backlog = _backlog(conn)
    out = [m for m in backlog if m.get_type() == kind]
    backlog[:] = [m for m in backlog if m.get_type() != kind]
    while (msg := conn.recv_match(blocking=True, timeout=quiet_s)) is not None:
        if msg.get_type() == kind:
            out.append(msg)
        else:
            backlog.append(msg)
    return out


def command_ack(conn: mavutil.mavfile, command: int, timeout_s: float = 10.0
                ) -> mavlink2.MAVLink_message | None:
    return wait_for(conn, "COMMAND_ACK", timeout_s, lambda m: m.command == command)
