"""Autopilot node: the flight core (``flight_core.FlightCore``) on the bus, with the MAVLink server
(``mavlink_server.MavlinkServer``) in the same process so ground stations fly the simulated vehicle.

Inputs (``scenenav/<ns>/...``)
  ``clock``                          ClockTick     one control step per tick (lockstep TICK member)
  ``sensors/imu``                    ImuSample     the tick's accelerometer and gyro
  ``sensors/baro``                   BaroSample    height (EKF)
  ``sensors/compass``                CompassSample heading (EKF)
  ``sensors/gps``                    GpsSample     GPS fixes (EKF, when EK3_SRC1_POSXY = 3)
  ``sensors/power``                  PowerSample   battery voltage and current (BATTERY_STATUS, SYS_STATUS)
  ``sensors/flow``                   FlowSample    optical flow and range (EKF velocity, FLOW_TYPE > 0 and
                                                   EK3_SRC1_VELXY = 5)
  ``perception/fix/*``               VisionFix     scene-matching fixes of the followed perception node
                                                   (and its camera flow, fused with SN_CAM_FLOW 1)
  liveliness ``nodes/perception/*``  which perception nodes are live (the newest one is followed)
  liveliness ``lockstep/member/camera/*``  which of them answer camera frames in lockstep
  MAVLink (TCP 127.0.0.1:5760, UDP out 127.0.0.1:14550 by default): commands, missions,
  parameters, GUIDED targets, VISION_POSITION_ESTIMATE / ODOMETRY (external navigation)
Outputs
  ``actuators/motors``               MotorCommand  every tick; with ``node_id`` "autopilot" it is also
                                                   the tick's lockstep answer (no LockstepAck)
  ``autopilot/estimate``             NavEstimate   20 Hz (simulated time; the autopilot's own estimate)
  ``autopilot/status``               AutopilotStatus 1 Hz and on change
  ``events/autopilot``               Event         every STATUSTEXT and other notable changes
  ``info/autopilot``                 NodeInfo      at start
  liveliness ``nodes/autopilot/autopilot`` and ``lockstep/member/tick/autopilot`` (declared after the
  subscribers); ``<run>/autopilot.tlog`` (MAVLink log), ``<run>/params.json`` (parameters;
  the set ones also in ``autopilot.params_store`` when given, kept between runs),
  ``<run>/mavlink.json`` (the MAVLink ports), ``<run>/autopilot_stats.json`` (counters, at exit)

Threading: no hand-off per sample. Every input is handled in the thread that delivers it (Zenoh's
receive thread for the samples, with ``indirect=False``; Zenoh's callback thread for liveliness),
under one lock, in arrival order: the ClockTick's flight-core step and its MotorCommand run in the
receive thread that decoded the ClockTick, right after the tick's sensors (the simulator publishes
them before its ClockTick from one session). A small service thread polls the MAVLink server every
10 ms when no tick did (after every tick the receive thread polls it), so ground stations are
answered while the simulator waits, and ends a vision wait that timed out. Lockstep determinism for
vision: a fix is handed to the core only at a tick whose ``camera_seq_acked`` covers its frame, and
a tick that needs the followed node's fix of that frame (when that node is a lockstep camera member)
is parked, with the inputs after it, until the fix (or the node's ack) arrives or
``autopilot.vision_wait_s`` wall seconds have passed; the thread delivering the fix steps it.

Configuration: an ``AutopilotSetup`` (``autopilot_bridge.config``) that the app layer derives from
the scenario (``scenenav.app.nodes``); the node never reads the scenario. The node never looks at
``truth/``. Malformed bus messages are counted and dropped by
``scenenav.core.bus``; NaN sensor values by the core (``autopilot_stats.json``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from autopilot_bridge.config import AutopilotSetup, PositionSource, udp_bind_host_for
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.fusion import CameraFlowReading, GpsReading, ImuReading, flow_reading
from autopilot_bridge.mavlink_server import MavlinkServer, MavlinkServerConfig
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore, load_param_file
from autopilot_bridge.route_mission import build_route_mission
from autopilot_bridge.signing import key_path_beside
from autopilot_bridge.vehicle_interface import MissionState
from scenenav.core.bus import Bus, BusConfig
from scenenav.core.contracts import (
    AutopilotStatus,
    BaroSample,
    ClockMode,
    ClockTick,
    CompassSample,
    DecodeError,
    Event,
    FlowSample,
    GpsSample,
    ImuSample,
    LockstepAck,
    LockstepRole,
    MotorCommand,
    NavEstimate,
    NodeInfo,
    PowerSample,
    RunState,
    Severity,
    VisionFix,
    decode,
)
from scenenav.core.errors import UserError
from scenenav.core.formats.atomic_file import write_atomic
from scenenav.core.formats.run_folder import MAVLINK_FILE
from scenenav.core.keys import Keys
from scenenav.core.presence import announce_node

log = logging.getLogger(__name__)

NODE_ID = "autopilot"
IDLE_POLL_S = 0.01
STATUS_PERIOD_US = 1_000_000
AUTO_START_RETRY_US = 1_000_000
STATS_FILE = "autopilot_stats.json"
SIGNING_KEY_FILE = "signing_key.json"   # a SETUP_SIGNING key when there is no parameter store
TLOG_FILE = "autopilot.tlog"
PARAMS_FILE = "params.json"


class ItemKind(Enum):
    CLOCK = "clock"
    IMU = "imu"
    BARO = "baro"
    COMPASS = "compass"
    GPS = "gps"
    POWER = "power"
    FLOW = "flow"
    FIX = "fix"
    ACK = "ack"                    # lockstep acks (a camera member answered a frame)
    PERCEPTION = "perception"      # liveliness of nodes/perception/<id>
    CAMERA_MEMBER = "camera"       # liveliness of lockstep/member/camera/<id>


#: inputs handled while a tick waits for its fix (the rest are held until it is stepped)
_PASS_WHILE_PARKED = frozenset((ItemKind.FIX, ItemKind.ACK, ItemKind.PERCEPTION,
                                ItemKind.CAMERA_MEMBER))


@dataclass(frozen=True)
class _Item:
    kind: ItemKind
    msg: Any = None
    node_id: str = ""
    alive: bool = False


class AutopilotNode:
    """The autopilot's bus shell; see the module docstring."""

    def __init__(self, setup: AutopilotSetup, bus_cfg: BusConfig,
                 run_dir: Path | None = None) -> None:
        self.setup = setup
        self.acfg = setup.node
        self.run_dir = run_dir
        self.keys = Keys(bus_cfg.namespace)
        self.stats: Counter[str] = Counter()
        defaults: dict[str, float] = {}
        if setup.position_source == PositionSource.EXTNAV:
            # no GPS: external navigation (scene matching) for position, no velocity source
            defaults.update({"EK3_SRC1_POSXY": int(PositionSource.EXTNAV),
                             "EK3_SRC1_VELXY": int(PositionSource.NONE)})
        if self.acfg.params_file:
            defaults.update(load_param_file(Path(self.acfg.params_file)))
        defaults.update(self.acfg.params)
        self.params = ParameterStore(PARAM_SPECS, path=run_dir / PARAMS_FILE if run_dir else None,
                                     defaults=defaults,
                                     persist_path=self.acfg.params_store or None)
        if self.acfg.params_store:
            log.info("parameters kept in %s (%d set there)", self.acfg.params_store,
                     len(self.params.persisted_names))
            self.params.save()      # the run folder's params.json shows the values flown
        self.core = FlightCore(self.params, setup.core)
        self.server = self._open_server()
        # input state: every input is handled under this lock by the thread delivering it
        self._lock = threading.RLock()
        self._replay: deque[_Item] = deque()
        self._stop = threading.Event()
        self._last_poll = 0.0
        self._closed = False
        self._imu: ImuSample | None = None
        self._last_tick = -1
        self._now_us = 0
        self._first_tick_seen = False
        self._parked: ClockTick | None = None
        self._parked_deadline = 0.0
        self._held: list[_Item] = []
        self._next_estimate_us = 0
        self._next_status_us = 0
        self._last_status: tuple | None = None
        self._motor = (0.0, 0.0, 0.0, 0.0)
        # perception following
        self._live: dict[str, int] = {}
        self._live_counter = 0
        self._camera_members: set[str] = set()
        self._live_before_start: set[str] = set()
        self._followed: str | None = None
        self._fix_buffer: list[VisionFix] = []
        self._answered_seq: dict[str, int] = {}     # newest frame a node fixed, acked or gave up
        # nodes whose fix did not come within vision_wait_s: not waited for until they answer again
        self._hung: set[str] = set()
        self._last_fix_t_s: dict[str, float] = {}
        self._swap_gap_from: tuple[str, float] | None = None
        # the run's own mission (None: a ground station or the guidance node sends one over MAVLink)
        self._auto_start = setup.mission is not None
        self._auto_started = False
        self._mission_loaded = False
        self._next_auto_try_us = 0
        self._auto_last_reason = ""
        # bus
        self.bus = Bus(bus_cfg)
        self._worker = threading.Thread(target=self._service, name="autopilot-service", daemon=True)
        self._worker.start()
        k = self.keys
        self._subscribers: list[Any] = []
        self._subscribe_ordered(k.clock, ClockTick, ItemKind.CLOCK)
        self._subscribe_ordered(k.imu, ImuSample, ItemKind.IMU)
        self._subscribe_ordered(k.baro, BaroSample, ItemKind.BARO)
        self._subscribe_ordered(k.compass, CompassSample, ItemKind.COMPASS)
        self._subscribe_ordered(k.gps, GpsSample, ItemKind.GPS)
        self._subscribe_ordered(k.power, PowerSample, ItemKind.POWER)
        self._subscribe_ordered(k.flow, FlowSample, ItemKind.FLOW)
        self._subscribe_ordered(k.vision_fix_all, VisionFix, ItemKind.FIX)
        self._subscribe_ordered(k.lockstep_ack_all, LockstepAck, ItemKind.ACK)
        self.bus.watch_liveliness(f"{k.root}/nodes/perception/*",
                                  lambda key, alive: self._feed(_Item(
                                      ItemKind.PERCEPTION, node_id=key.rsplit("/", 1)[-1],
                                      alive=alive)))
        self.bus.watch_liveliness(f"{k.root}/lockstep/member/camera/*",
                                  lambda key, alive: self._feed(_Item(
                                      ItemKind.CAMERA_MEMBER, node_id=key.rsplit("/", 1)[-1],
                                      alive=alive)))
        # announce only once subscribed
        self.presence = announce_node(self.bus, k, "autopilot", NODE_ID)
        self.bus.declare_token(k.lockstep_member(LockstepRole.TICK, NODE_ID))
        detail = (f"mavlink tcp {self.server.tcp_port or 'off'}, "
                  f"source {self.params.get_int('EK3_SRC1_POSXY')}")
        self.bus.publish(k.node_info(NODE_ID), NodeInfo(0, NODE_ID, "autopilot", detail))
        log.info("autopilot node up (%s)", detail)

    # ------------------------------------------------------------------ setup
    def _open_server(self) -> MavlinkServer:
        a = self.acfg
        udp = a.udp_target
        tlog = str(self.run_dir / TLOG_FILE) if self.run_dir else ""
        # the SETUP_SIGNING key: beside the kept parameters (scenenav sitl), else in the run folder
        key_path = (str(key_path_beside(a.params_store)) if a.params_store
                    else str(self.run_dir / SIGNING_KEY_FILE) if self.run_dir else "")
        cfg = MavlinkServerConfig(
            tcp_enabled=a.mavlink_tcp_port != 0, tcp_host=a.mavlink_tcp_host, tcp_port=a.mavlink_tcp_port or 5760,
            udp_enabled=udp is not None, udp_target_host=udp[0] if udp else "127.0.0.1",
            udp_bind_host=udp_bind_host_for(udp[0]) if udp else "127.0.0.1",
            udp_target_port=udp[1] if udp else 14550, tlog_path=tlog, signing_key_path=key_path)
        try:
            server = MavlinkServer(self.core, self.params, cfg)
        except UserError as exc:
            # Taken (another run, a real SITL): bind a free port instead and report the bound one
            # in mavlink.json, so there is no race between choosing a port and binding it.
            log.warning("%s; serving MAVLink TCP on a free port instead (see mavlink.json)", exc)
            self.stats["mavlink_tcp_port_taken"] += 1
            try:
                server = MavlinkServer(self.core, self.params, dataclasses.replace(cfg, tcp_port=0))
            except UserError as exc2:
                log.error("%s; MAVLink TCP server disabled for this run", exc2)
                self.stats["mavlink_tcp_unavailable"] += 1
                server = MavlinkServer(self.core, self.params,
                                       dataclasses.replace(cfg, tcp_enabled=False))
        if self.run_dir is not None:
            info = {"tcp_host": cfg.tcp_host if server.tcp_port else None,
                    "tcp_port": server.tcp_port, "udp_port": server.udp_port,
                    "udp_out": f"{cfg.udp_target_host}:{cfg.udp_target_port}" if udp else None,
                    "udp_bind_host": cfg.udp_bind_host if udp else None,
                    "system_id": server.system_id}
            write_atomic(self.run_dir / MAVLINK_FILE, json.dumps(info, indent=2))
        return server

    # ------------------------------------------------------------------ callbacks (Zenoh threads)
    def _subscribe_ordered(self, key: str, cls: type, kind: ItemKind) -> None:
        """Decode and handle in the Zenoh receive thread itself (``indirect=False``).

        Handling the samples in the network thread keeps the publisher's per-session order across
        keys (a tick's IMU sample before its ClockTick) and costs no thread hand-off per sample:
        the ClockTick's step and its MotorCommand run right here.
        """
        def handler(sample: zenoh.Sample) -> None:
            try:
                k = str(sample.key_expr)
                try:
                    msg = decode(cls, sample.payload.to_bytes())
                except DecodeError as exc:
                    self.bus.dropped[k] += 1
                    n = self.bus.dropped[k]
                    if n <= 5 or n % 100 == 0:
                        log.warning("dropped malformed message #%d on %s: %s", n, k, exc)
                    return
                self._feed(_Item(kind, msg, node_id=k.rsplit("/", 1)[-1]))
            except Exception:  # noqa: BLE001 - never raise into Zenoh's network thread
                self.stats["worker_errors"] += 1
                log.exception("subscriber for %s failed", key)
        self._subscribers.append(self.bus.session.declare_subscriber(
            key, zenoh.handlers.Callback(handler, indirect=False)))

    # ------------------------------------------------------------------ inputs
    def _feed(self, item: _Item) -> None:
        """Handle one input in the calling thread (a Zenoh thread), with the inputs a tick that was
        parked held back; then any it releases."""
        with self._lock:
            if self._closed:
                return
            self._process(item)
            while self._replay:
                self._process(self._replay.popleft())

    def _process(self, item: _Item) -> None:
        if self._parked is not None and item.kind not in _PASS_WHILE_PARKED:
            self._held.append(item)
            if item.kind == ItemKind.CLOCK:     # the simulator moved on: stop waiting
                self._unpark()
            return
        self._handle(item)
        if self._parked is not None and self._parked_fix_ready():
            self._unpark()

    def _service(self) -> None:
        """The service thread: the MAVLink server's poll while no tick polls it, and the end of a
        vision wait that timed out."""
        while not self._stop.wait(IDLE_POLL_S):
            try:
                with self._lock:
                    self._service_once()
                    while self._replay:
                        self._process(self._replay.popleft())
            except Exception:  # noqa: BLE001 - the thread must survive any bug in one message
                self.stats["worker_errors"] += 1
                log.exception("autopilot service error")

    def _service_once(self) -> None:
        if self._parked is not None and time.monotonic() > self._parked_deadline:
            self.stats["vision_wait_timeouts"] += 1
            self._mark_answered(self._followed or "", self._parked.camera_seq_acked)
            self._hung.add(self._followed or "")
            self._event(Severity.WARNING, f"no fix from {self._followed} for frame "
                                          f"{self._parked.camera_seq_acked} within "
                                          f"{self.acfg.vision_wait_s:.1f} s; stepping without its "
                                          f"fixes until it answers again")
            self._unpark()
        if time.monotonic() - self._last_poll >= IDLE_POLL_S:
            self._poll_server()

    def _unpark(self) -> None:
        tick, self._parked = self._parked, None
        held, self._held = self._held, []
        if tick is not None:
            self._run_tick(tick)
        self._replay.extendleft(reversed(held))

    def _handle(self, item: _Item) -> None:
        kind = item.kind
        core = self.core
        if kind == ItemKind.IMU:
            self._imu = item.msg
        elif kind == ItemKind.BARO:
            core.on_baro(item.msg.timestamp_us * 1e-6, item.msg.altitude_m)
        elif kind == ItemKind.COMPASS:
            core.on_compass(item.msg.timestamp_us * 1e-6, item.msg.heading_rad)
        elif kind == ItemKind.GPS:
            g: GpsSample = item.msg
            core.on_gps(GpsReading(g.timestamp_us * 1e-6, g.lat_deg, g.lon_deg, g.alt_m,
                                   tuple(g.velocity_enu_m_s), g.eph_m, g.epv_m, g.fix_type,
                                   g.satellites))
        elif kind == ItemKind.POWER:
            p: PowerSample = item.msg
            core.on_power(p.timestamp_us * 1e-6, p.voltage_v, p.current_a)
        elif kind == ItemKind.FLOW:
            core.on_flow(flow_reading(item.msg))
        elif kind == ItemKind.FIX:
            self._on_fix_item(item.node_id, item.msg)
        elif kind == ItemKind.ACK:
            ack: LockstepAck = item.msg
            if ack.role == LockstepRole.CAMERA.value:
                self._mark_answered(item.node_id, ack.seq)
                self._answers_again(item.node_id)
        elif kind == ItemKind.PERCEPTION:
            self._on_perception_live(item.node_id, item.alive)
        elif kind == ItemKind.CAMERA_MEMBER:
            if item.alive:
                self._camera_members.add(item.node_id)
            else:
                self._camera_members.discard(item.node_id)
        elif kind == ItemKind.CLOCK:
            self._on_clock(item.msg)

    # ------------------------------------------------------------------ clock
    def _on_clock(self, tick: ClockTick) -> None:
        if tick.state == RunState.FINISHED.value:
            self._event(Severity.INFO, "simulation finished")
            return
        if tick.tick <= self._last_tick:
            self.stats["clock_out_of_order"] += 1
            return
        if not self._first_tick_seen:
            self._first_tick_seen = True
            self._live_before_start = set(self._live)
        if tick.mode == ClockMode.LOCKSTEP.value and self._must_wait_for_fix(tick):
            self._parked = tick
            self._parked_deadline = time.monotonic() + self.acfg.vision_wait_s
            self.stats["vision_waits"] += 1
            return
        self._run_tick(tick)

    def _must_wait_for_fix(self, tick: ClockTick) -> bool:
        node = self._followed
        if node is None or tick.camera_seq_acked < 0 or node not in self._camera_members:
            return False
        if node in self._hung:
            return False
        if node not in self._live_before_start and node not in self._answered_seq:
            return False
        return self._answered_seq.get(node, -1) < tick.camera_seq_acked

    def _answers_again(self, node_id: str) -> None:
        if node_id in self._hung:
            self._hung.discard(node_id)
            self._event(Severity.INFO, f"{node_id} answers again; waiting for its fixes again")

    def _mark_answered(self, node_id: str, seq: int) -> None:
        self._answered_seq[node_id] = max(self._answered_seq.get(node_id, -1), seq)

    def _parked_fix_ready(self) -> bool:
        """The followed node's fix for the parked tick's frame is here, or its ack (a node
        publishes the fix before the ack from one session, so after the ack no fix is coming)."""
        tick = self._parked
        return tick is not None and self._answered_seq.get(self._followed or "", -1) >= \
            tick.camera_seq_acked

    def _run_tick(self, tick: ClockTick) -> None:
        t0 = time.perf_counter()
        self._step_tick(tick)
        self.stats["tick_work_us"] += int((time.perf_counter() - t0) * 1e6)

    def _step_tick(self, tick: ClockTick) -> None:
        k = self.keys
        self._last_tick = tick.tick
        self._now_us = tick.timestamp_us
        now_s = tick.timestamp_us * 1e-6
        lockstep = tick.mode == ClockMode.LOCKSTEP.value
        self._deliver_fixes(tick.camera_seq_acked if lockstep else None)
        imu = self._imu
        if imu is not None and imu.tick == tick.tick:
            motors = self.core.step(imu.dt_s, ImuReading(imu.accel_flu_m_s2, imu.gyro_flu_rad_s),
                                    now_s)
            self._motor = tuple(float(m) for m in motors)
        else:
            self.stats["ticks_without_imu"] += 1
        # the motor command is also the tick's lockstep answer (MotorCommand.node_id): no LockstepAck
        self.bus.publish(k.motors, MotorCommand(tick.timestamp_us, tick.tick, self._motor,
                                                self.core.armed, NODE_ID))
        self.stats["ticks"] += 1
        self._fly_own_mission(tick.timestamp_us)
        self._publish_outputs(tick.timestamp_us)
        self._poll_server()

    def _poll_server(self) -> None:
        self._last_poll = time.monotonic()
        self.core.set_gcs_heartbeat(self.server.last_gcs_heartbeat_s)
        self.server.poll(self._now_us * 1e-6)
        self._publish_texts()

    # ------------------------------------------------------------------ outputs
    def _publish_outputs(self, t_us: int) -> None:
        k = self.keys
        core = self.core
        if t_us >= self._next_estimate_us:
            self._next_estimate_us = t_us + int(round(1e6 / self.acfg.estimate_rate_hz))
            est = core.estimate()
            if est is not None:
                self.bus.publish(k.nav_estimate, NavEstimate(
                    t_us, tuple(float(a) for a in est.position_enu_m),
                    tuple(float(a) for a in est.velocity_enu_m_s),
                    tuple(float(a) for a in est.q_wxyz), float(est.heading_rad),
                    tuple(float(a) for a in est.position_std_m), int(core.position_source),
                    self._followed or ""))
        st = core.status()
        # mission_complete on the bus means "the scenario's mission is done" (it ends the run);
        # an idle (ground-station) session reports it to the GCS over MAVLink only.
        complete = st.mission_complete and self.setup.mission_ends_run
        snapshot = (st.armed, st.mode, st.landed, st.mission_seq, st.mission_count, complete,
                    st.gps_used)
        if snapshot != self._last_status or t_us >= self._next_status_us:
            self._last_status = snapshot
            self._next_status_us = t_us + STATUS_PERIOD_US
            self.bus.publish(k.autopilot_status, AutopilotStatus(t_us, *snapshot))
        self._publish_texts()

    def _publish_texts(self) -> None:
        for severity, text in self.core.drain_texts():
            self._event(Severity(int(severity)), text)

    def _event(self, severity: Severity, text: str) -> None:
        log.info("event: %s", text)
        self.bus.publish(self.keys.events(NODE_ID), Event(self._now_us, NODE_ID, int(severity), text))

    # ------------------------------------------------------------------ perception following
    def _on_perception_live(self, node_id: str, alive: bool) -> None:
        if alive:
            if node_id in self._live:
                return
            self._live_counter += 1
            self._live[node_id] = self._live_counter
            if node_id != self._followed:
                self._follow(node_id, f"perception node {node_id} is live")
        else:
            if self._live.pop(node_id, None) is None:
                return
            if node_id == self._followed:
                newest = max(self._live, key=self._live.get) if self._live else None
                self._follow(newest, f"perception node {node_id} left")

    def _follow(self, node_id: str | None, why: str) -> None:
        old = self._followed
        self._followed = node_id
        self._fix_buffer.clear()
        self.core.set_vision_available(node_id is not None)
        if old is not None and old in self._last_fix_t_s and node_id is not None:
            self._swap_gap_from = (old, self._last_fix_t_s[old])
        self.stats["vision_swaps"] += 1
        self._event(Severity.INFO if node_id else Severity.WARNING,
                    f"vision: {why}; following {node_id or 'no perception node'}"
                    + (f" (was {old})" if old else ""))

    def _on_fix_item(self, node_id: str, fix: VisionFix) -> None:
        self._mark_answered(node_id, fix.frame_seq)
        self._answers_again(node_id)
        if node_id != self._followed:
            self._last_fix_t_s[node_id] = fix.timestamp_us * 1e-6
            self.stats["fixes_not_followed"] += 1
            return
        self._fix_buffer.append(fix)

    def _deliver_fixes(self, acked_seq: int | None) -> None:
        if not self._fix_buffer:
            return
        node = self._followed or ""
        lockstep_member = node in self._camera_members
        ready: list[VisionFix] = []
        keep: list[VisionFix] = []
        for fix in self._fix_buffer:
            if acked_seq is None or not lockstep_member or fix.frame_seq <= acked_seq:
                ready.append(fix)
            else:
                keep.append(fix)
        self._fix_buffer = keep
        for fix in sorted(ready, key=lambda f: f.frame_seq):
            t_s = fix.timestamp_us * 1e-6
            if self._swap_gap_from is not None:
                old, t_old = self._swap_gap_from
                self._swap_gap_from = None
                self._event(Severity.INFO, f"vision: fix gap {t_s - t_old:.2f} s between the last "
                                           f"fix of {old} and the first of {node}")
            self._last_fix_t_s[node] = t_s
            cov = np.asarray(fix.covariance_xy_m2, dtype=float).reshape(2, 2)
            self.core.on_vision_fix(t_s, fix.position_xy_enu_m, cov, fix.valid, fix.accepted, node,
                                    fix.heading_rad, fix.heading_std_rad)
            if fix.flow_interval_us > 0:
                self.core.on_camera_flow(CameraFlowReading(
                    t_s, (float(fix.flow_flu_rad_s[0]), float(fix.flow_flu_rad_s[1])),
                    fix.flow_interval_us * 1e-6, float(fix.flow_quality)))
            self.stats["fixes_delivered"] += 1

    # ------------------------------------------------------------------ the run's own mission
    def _fly_own_mission(self, t_us: int) -> None:
        if not self._auto_start or self._auto_started or not self.core.aligned:
            return
        core = self.core
        mission = self.setup.mission
        assert mission is not None
        if not self._mission_loaded:
            route = mission.route_enu_m
            items = build_route_mission(core.geo, route, mission.altitude_m, self.acfg.mission_end)
            core.mission_changed(items)
            loader = getattr(self.server.missions, "load_items", None)
            if callable(loader):
                loader(items)
            self._mission_loaded = True
            self._event(Severity.INFO, f"scenario mission: {len(items)} items, "
                                       f"{len(route)} waypoints at {mission.altitude_m:.0f} m")
        if t_us < self._next_auto_try_us:
            return
        self._next_auto_try_us = t_us + AUTO_START_RETRY_US
        steps = ((lambda: core.set_mode(CopterMode.GUIDED)) if not core.armed else None,
                 (lambda: core.arm(False)) if not core.armed else None,
                 lambda: core.set_mode(CopterMode.AUTO))
        for step in steps:
            if step is None:
                continue
            outcome = step()
            if not outcome.ok:
                if outcome.reason != self._auto_last_reason:
                    self._auto_last_reason = outcome.reason
                    self._event(Severity.WARNING, f"auto start waiting: {outcome.reason}")
                return
        self._auto_started = True
        self._event(Severity.INFO, "auto start: armed, mission started")

    # ------------------------------------------------------------------ lifecycle
    def _ekf_at_exit(self) -> dict[str, Any]:
        """What the EKF learnt, at the end of the run: the wind (drag fusion) and the compass
        heading's bias (SN_MAG_BIAS_SD); empty if it never aligned."""
        est = self.core.estimate()
        if est is None:
            return {}
        return {"wind_enu_m_s": [round(float(w), 3) for w in est.wind_enu_m_s],
                "compass_bias_deg": round(math.degrees(float(est.compass_bias_rad)), 3)}

    def close(self) -> dict:
        self._stop.set()
        self._worker.join(timeout=5.0)
        for sub in self._subscribers:       # no input after this: the server and core close
            try:
                sub.undeclare()
            except zenoh.ZError:
                pass
        self._subscribers.clear()
        with self._lock:
            self._closed = True
        self.server.close()
        self.core.close()
        stats: dict[str, Any] = {"node": dict(self.stats), "core": dict(self.core.stats),
                                 "bus_dropped": dict(self.bus.dropped),
                                 "mavlink": dict(self.server.stats),
                                 "mission_state": MissionState(self.core.mission_state).name,
                                 "armed": self.core.armed, "mode": self.core.mode.name,
                                 "ekf_at_exit": self._ekf_at_exit()}
        self.presence.close()
        self.bus.close()
        if self.run_dir is not None:
            try:
                (self.run_dir / STATS_FILE).write_text(json.dumps(stats, indent=2, default=str))
            except OSError as exc:
                log.warning("could not write %s: %s", STATS_FILE, exc)
        log.info("autopilot node stats: %s", stats)
        return stats

