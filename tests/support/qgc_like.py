"""A QGroundControl-like ground station (pymavlink), written from what QGC's source does with an
ArduPilot vehicle, for the interop tests (``tests/interop/test_qgc_like.py``).

What it does, in QGC's order (``InitialConnectStateMachine``, ``ParameterManager``,
``APMFirmwarePlugin``, ``ArduCopterFirmwarePlugin``, ``PlanManager``, the APM setup components):

1. connect: waits for the autopilot's HEARTBEAT (component 1, ARDUPILOTMEGA), sends its own at 1 Hz
   as system 255 / component 190 (MAV_TYPE_GCS); REQUEST_MESSAGE AUTOPILOT_VERSION (capabilities:
   MISSION_FENCE and MISSION_RALLY or the Plan view says the vehicle has no geofence / rally points),
   PROTOCOL_VERSION and COMPONENT_INFORMATION (each must be answered by a COMMAND_ACK, whatever the
   result: QGC moves on after the ACK, but waits for its timeout without one);
2. parameters: MAVLink FTP OpenFileRO ``@PARAM/param.pck``, burst read, TerminateSession; on a NAK
   FileNotFound the PARAM_REQUEST_LIST stream (what QGC does when the file is not there); then the
   parameter names its APM setup pages read must exist and those pages must show setup complete;
3. mission, fence and rally download (MISSION_REQUEST_LIST / COUNT / REQUEST_INT / ITEM_INT / ACK
   with mission_type 0, 1, 2);
4. stream rates as ``APMFirmwarePlugin::initializeStreamRates`` requests them (REQUEST_DATA_STREAM
   per group) and the messages its instrument panel shows must arrive;
5. flight: takeoff as ``APMFirmwarePlugin::guidedModeTakeoff`` (GUIDED, arm, NAV_TAKEOFF), "Go to
   location" (COMMAND_INT DO_REPOSITION, frame GLOBAL = AMSL, param1 -1, param2 change-mode, param4
   NaN), Pause (``pauseVehicle``: ArduCopter's BRAKE), "Change altitude"
   (``guidedModeChangeAltitude``: GUIDED, then SET_POSITION_TARGET_LOCAL_NED in LOCAL_OFFSET_NED
   with only x/y/z valid, z = -change), RTL (DO_SET_MODE) until the vehicle has landed and disarmed.

All the while the autopilot's heartbeats are timed on the wall clock: QGC declares the link lost
after about 3.5 s without one. Every check is recorded (``checks``) instead of stopping the script,
so a test sees all that failed.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from dataclasses import dataclass, field

from pymavlink import mavftp
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from support.fake_vehicle import gcs_connection

M = mavlink2
log = logging.getLogger(__name__)
QGC_LINK_LOSS_S = 3.5
PROTOCOL_VERSION_ID, COMPONENT_INFORMATION_ID = 300, 395   # not in the ardupilotmega dialect
COPTER = {"GUIDED": 4, "RTL": 6, "BRAKE": 17, "LOITER": 5}
# QGC's APMFirmwarePlugin::initializeStreamRates defaults (Hz)
STREAM_RATES_HZ = {M.MAV_DATA_STREAM_RAW_SENSORS: 2, M.MAV_DATA_STREAM_EXTENDED_STATUS: 2,
                   M.MAV_DATA_STREAM_RC_CHANNELS: 2, M.MAV_DATA_STREAM_POSITION: 3,
                   M.MAV_DATA_STREAM_EXTRA1: 10, M.MAV_DATA_STREAM_EXTRA2: 10,
                   M.MAV_DATA_STREAM_EXTRA3: 3}
# what QGC's fly view and instrument panel show, from those streams
SHOWN_MESSAGES = ("SYS_STATUS", "GPS_RAW_INT", "GLOBAL_POSITION_INT", "ATTITUDE", "VFR_HUD",
                  "BATTERY_STATUS", "EKF_STATUS_REPORT", "NAV_CONTROLLER_OUTPUT", "HOME_POSITION")
# parameters QGC's APM setup pages (airframe, radio, flight modes, sensors, power, safety) read
SETUP_PAGE_PARAMS = (
    ["FRAME_CLASS", "FRAME_TYPE", "RCMAP_ROLL", "RCMAP_PITCH", "RCMAP_YAW", "RCMAP_THROTTLE",
     "FLTMODE1", "FLTMODE2", "FLTMODE3", "FLTMODE4", "FLTMODE5", "FLTMODE6", "FLTMODE_CH", "SIMPLE",
     "SUPER_SIMPLE", "COMPASS_ENABLE", "COMPASS_AUTODEC", "COMPASS_DEC", "BATT_MONITOR",
     "BATT_CAPACITY", "BATT_VOLT_PIN", "BATT_CURR_PIN", "BATT_VOLT_MULT", "BATT_AMP_PERVLT",
     "BATT_ARM_VOLT", "BATT_LOW_VOLT", "BATT_CRT_VOLT", "BATT_FS_LOW_ACT", "BATT_FS_CRT_ACT",
     "FS_THR_ENABLE", "FS_THR_VALUE", "FS_GCS_ENABLE", "FS_EKF_ACTION", "FS_EKF_THRESH",
     "FENCE_ENABLE", "FENCE_TYPE", "FENCE_ACTION", "FENCE_ALT_MAX", "FENCE_RADIUS", "FENCE_MARGIN",
     "RTL_ALT", "RTL_ALT_FINAL", "RTL_LOIT_TIME", "LAND_SPEED", "ARMING_CHECK", "WPNAV_SPEED",
     "WPNAV_SPEED_UP", "WPNAV_SPEED_DN", "ANGLE_MAX", "PILOT_SPEED_UP", "RALLY_INCL_HOME",
     "RALLY_LIMIT_KM", "SYSID_MYGCS", "INS_GYRO_FILTER", "INS_ACCEL_FILTER"]
    + [f"RC{n}_{k}" for n in range(1, 9) for k in ("MIN", "MAX", "TRIM", "REVERSED", "DZ")]
    + [f"COMPASS_{k}{s}" for s in ("", "2", "3") for k in ("DEV_ID", "USE")]
    + [f"COMPASS_OFS{s}_{a}" for s in ("", "2", "3") for a in "XYZ"]
    + [f"INS_ACC{s}{k}_{a}" for s in ("", "2", "3") for k in ("OFFS", "SCAL") for a in "XYZ"])

# MAVLink FTP (QGC's FTPManager)
FTP_TERMINATE, FTP_RESET, FTP_OPEN_RO, FTP_READ, FTP_BURST = 1, 2, 4, 5, 15
FTP_ACK, FTP_NAK = 128, 129
FTP_ERR_EOF, FTP_ERR_NOT_FOUND = 6, 10
FTP_DATA = 239


def setup_complete(p: dict[str, float]) -> dict[str, bool]:
    """``setupComplete()`` of the APM components that need setup (airframe, radio, sensors)."""
    channels = [int(p[f"RCMAP_{a}"]) for a in ("ROLL", "PITCH", "YAW", "THROTTLE")]
    radio = all(c > 0 for c in channels) and any(
        (int(p[f"RC{c}_MIN"]), int(p[f"RC{c}_MAX"]), int(p[f"RC{c}_TRIM"])) != (1100, 1900, 1500)
        for c in channels)
    compass_needed = any(
        int(p[f"COMPASS_DEV_ID{s}"]) != 0 and int(p[f"COMPASS_USE{s}"]) != 0
        and any(p[f"COMPASS_OFS{s}_{a}"] == 0.0 for a in "XYZ") for s in ("", "2", "3"))
    accel_needed = all(p[f"INS_ACCOFFS_{a}"] == 0.0 for a in "XYZ")
    return {"airframe": int(p["FRAME_CLASS"]) > 0, "radio": radio,
            "sensors": not compass_needed and not accel_needed}


@dataclass
class Check:
    name: str
    ok: bool
    detail: str = ""


@dataclass
class QgcLike:
    """The ground station on the autopilot's TCP port; ``run_all()`` does steps 1 to 5."""

    port: int
    timeout_s: float = 120.0
    checks: list[Check] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)
    param_source: str = ""
    heartbeat_times: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.conn = gcs_connection(self.port, source_system=255, source_component=190)
        self._last_hb_sent = 0.0
        self._latest: dict[str, mavlink2.MAVLink_message] = {}
        self._inbox: list[mavlink2.MAVLink_message] = []
        self._ftp_seq = 0

    # ------------------------------------------------------------------ plumbing
    def check(self, name: str, ok: bool, detail: str = "") -> bool:
        self.checks.append(Check(name, bool(ok), detail))
        log.info("QGC-like: %s %s %s", "ok" if ok else "FAIL", name, detail)
        return bool(ok)

    @property
    def failures(self) -> list[Check]:
        return [c for c in self.checks if not c.ok]

    def pump(self, duration_s: float = 0.0) -> None:
        """Read whatever arrived (for at least ``duration_s``, at most 100 messages a call when
        the time is up), sending our 1 Hz heartbeat."""
        end = time.monotonic() + duration_s
        n = 0
        while True:
            now = time.monotonic()
            if now - self._last_hb_sent >= 1.0:
                self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self._last_hb_sent = now
            msg = self.conn.recv_match(blocking=True, timeout=0.02)
            if msg is not None:
                self._take(msg)
                n += 1
            if now >= end and (msg is None or n >= 100):
                return

    def _take(self, msg) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        if kind == "HEARTBEAT" and msg.get_srcSystem() == 1 and msg.get_srcComponent() == 1:
            self.heartbeat_times.append(time.monotonic())
        self._latest[kind] = msg
        self._inbox.append(msg)

    def wait(self, kind: str, condition=None, timeout_s: float | None = None, fresh: bool = True):
        """The first ``kind`` message meeting ``condition`` (None after the timeout): from now on,
        or (``fresh`` False) also among those that came with the last one found."""
        if fresh:
            self._inbox.clear()
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        while time.monotonic() < deadline:
            self.pump()
            for i, msg in enumerate(self._inbox):
                if msg.get_type() == kind and (condition is None or condition(msg)):
                    del self._inbox[:i + 1]
                    return msg
            self._inbox.clear()
        return None

    def latest(self, kind: str):
        return self._latest.get(kind)

    def command(self, command: int, *params: float, timeout_s: float = 10.0) -> int | None:
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        ack = self.wait("COMMAND_ACK", lambda a: a.command == command, timeout_s)
        return None if ack is None else int(ack.result)

    def set_mode(self, name: str) -> bool:
        """QGC's setFlightMode: MAV_CMD_DO_SET_MODE with the custom mode."""
        result = self.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, COPTER[name])
        ok = result == M.MAV_RESULT_ACCEPTED
        ok = ok and self.wait("HEARTBEAT", lambda h: h.get_srcComponent() == 1
                              and h.custom_mode == COPTER[name], 10.0) is not None
        return self.check(f"mode {name}", ok, f"result {result}")

    def max_heartbeat_gap_s(self) -> float:
        t = self.heartbeat_times
        return max((b - a for a, b in zip(t[:-1], t[1:], strict=True)), default=math.inf)

    def close(self) -> None:
        self.conn.close()

    # ------------------------------------------------------------------ 1. connect
    def connect(self) -> None:
        hb = self.wait("HEARTBEAT", lambda h: h.get_srcComponent() == 1, self.timeout_s)
        if not self.check("heartbeat", hb is not None and hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA
                          and hb.type == M.MAV_TYPE_QUADROTOR, str(hb)):
            return
        result = self.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        version = self.wait("AUTOPILOT_VERSION", timeout_s=5.0, fresh=False)   # right after the ACK
        caps = 0 if version is None else int(version.capabilities)
        need = (M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE | M.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
                | M.MAV_PROTOCOL_CAPABILITY_FTP | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT)
        self.check("AUTOPILOT_VERSION", result == M.MAV_RESULT_ACCEPTED and caps & need == need,
                   f"result {result}, capabilities {caps:#x}")
        for msg_id in (PROTOCOL_VERSION_ID, COMPONENT_INFORMATION_ID):
            self.check(f"REQUEST_MESSAGE {msg_id} answered",
                       self.command(M.MAV_CMD_REQUEST_MESSAGE, msg_id) is not None)

    # ------------------------------------------------------------------ 2. parameters
    def _ftp(self, opcode: int, session: int = 0, offset: int = 0, size: int = 0,
             data: bytes = b"", timeout_s: float = 3.0):
        """One FTP request; its reply (opcode, req_opcode, size, burst_complete, offset, data)."""
        self._ftp_seq = (self._ftp_seq + 1) & 0xFFFF
        seq = self._ftp_seq
        head = struct.pack("<HBBBBBBI", seq, session, opcode, size or len(data), 0, 0, 0, offset)
        self.conn.mav.file_transfer_protocol_send(0, 1, 1, list((head + data).ljust(251, b"\0")))
        msg = self.wait("FILE_TRANSFER_PROTOCOL",
                        lambda m: struct.unpack_from("<H", bytes(m.payload))[0] == (seq + 1) & 0xFFFF,
                        timeout_s)
        return None if msg is None else _ftp_reply(bytes(msg.payload))

    def _burst(self, session: int, size: int) -> dict[int, bytes]:
        """BurstReadFile from 0: the chunks by offset until the NAK EOF (or a pause)."""
        self._ftp_seq = (self._ftp_seq + 1) & 0xFFFF
        head = struct.pack("<HBBBBBBI", self._ftp_seq, session, FTP_BURST, FTP_DATA, 0, 0, 0, 0)
        self.conn.mav.file_transfer_protocol_send(0, 1, 1, list(head.ljust(251, b"\0")))
        chunks: dict[int, bytes] = {}
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            msg = self.wait("FILE_TRANSFER_PROTOCOL", timeout_s=2.0, fresh=False)
            if msg is None:
                break
            op, req, n, complete, offset, data = _ftp_reply(bytes(msg.payload))
            if req != FTP_BURST:
                continue
            if op == FTP_ACK:
                chunks[offset] = data[:n]
            if op == FTP_NAK or complete or sum(len(c) for c in chunks.values()) >= size:
                break
        return chunks

    def load_parameters(self) -> None:
        reply = self._ftp(FTP_OPEN_RO, data=b"@PARAM/param.pck\0")
        if reply is not None and reply[0] == FTP_ACK:
            session = 0
            size = struct.unpack_from("<I", reply[5])[0]
            chunks = self._burst(session, size)
            data = bytearray(size)
            have = bytearray(size)
            for off, chunk in chunks.items():
                data[off:off + len(chunk)] = chunk
                have[off:off + len(chunk)] = b"\1" * len(chunk)
            off = 0
            while off < size:                               # QGC re-reads what the burst missed
                if have[off]:
                    off += 1
                    continue
                r = self._ftp(FTP_READ, session, off, FTP_DATA)
                if r is None or r[0] != FTP_ACK:
                    break
                data[off:off + r[2]] = r[5][:r[2]]
                have[off:off + r[2]] = b"\1" * r[2]
                off += max(r[2], 1)
            self._ftp(FTP_TERMINATE, session)
            decoded = mavftp.MAVFTP.ftp_param_decode(bytes(data)) if all(have) else None
            if self.check("FTP @PARAM/param.pck", decoded is not None, f"{size} bytes, {len(chunks)} chunks"):
                self.params = {n.decode(): float(v) for n, v, _ in decoded.params}
                self.param_source = "ftp"
        else:
            nak = None if reply is None else reply[5][0]
            self.check("FTP NAK is FileNotFound (QGC falls back at once)",
                       reply is not None and nak == FTP_ERR_NOT_FOUND, f"reply {reply}")
        if not self.params:
            self.params = self._param_stream()
            self.param_source = "PARAM_REQUEST_LIST"
        missing = [n for n in SETUP_PAGE_PARAMS if n not in self.params]
        self.check("setup-page parameters present", not missing, f"missing {missing}")
        if not missing:
            done = setup_complete(self.params)
            self.check("setup complete", all(done.values()), str(done))

    def _param_stream(self) -> dict[str, float]:
        self.conn.mav.param_request_list_send(1, 1)
        got: dict[str, float] = {}
        count = None
        while count is None or len(got) < count:
            msg = self.wait("PARAM_VALUE", timeout_s=10.0)
            if msg is None:
                break
            count = msg.param_count
            got[msg.param_id] = msg.param_value
        self.check("PARAM_REQUEST_LIST complete", count is not None and len(got) == count,
                   f"{len(got)} of {count}")
        return got

    # ------------------------------------------------------------------ 3. plan download
    def download(self, mission_type: int) -> list | None:
        self.conn.mav.mission_request_list_send(1, 1, mission_type)
        count = self.wait("MISSION_COUNT", lambda m: m.mission_type == mission_type, 5.0)
        if count is None:
            return None
        items = []
        for seq in range(count.count):
            self.conn.mav.mission_request_int_send(1, 1, seq, mission_type)
            item = self.wait("MISSION_ITEM_INT", lambda m, s=seq: m.seq == s
                             and m.mission_type == mission_type, 5.0)
            if item is None:
                return None
            items.append(item)
        self.conn.mav.mission_ack_send(1, 1, M.MAV_MISSION_ACCEPTED, mission_type)
        return items

    def download_plan(self) -> None:
        for name, mtype in (("mission", M.MAV_MISSION_TYPE_MISSION), ("fence", M.MAV_MISSION_TYPE_FENCE),
                            ("rally", M.MAV_MISSION_TYPE_RALLY)):
            items = self.download(mtype)
            self.check(f"{name} download", items is not None)

    # ------------------------------------------------------------------ 4. streams
    def request_streams(self) -> None:
        for stream, hz in STREAM_RATES_HZ.items():
            self.conn.mav.request_data_stream_send(1, 1, stream, hz, 1)
        self.pump(1.0)
        self._latest.clear()
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and any(k not in self._latest for k in SHOWN_MESSAGES):
            self.pump(0.2)
        missing = [k for k in SHOWN_MESSAGES if k not in self._latest]
        self.check("streamed messages", not missing, f"missing {missing}")

    # ------------------------------------------------------------------ 5. flight
    def rel_alt_m(self) -> float:
        msg = self.wait("GLOBAL_POSITION_INT", timeout_s=10.0)
        return math.nan if msg is None else msg.relative_alt * 1e-3

    def fly(self, alt_m: float, goto_lat_lon: tuple[float, float], climb_m: float) -> None:
        ekf = self.wait("EKF_STATUS_REPORT", lambda m: m.flags & M.EKF_POS_HORIZ_ABS, self.timeout_s)
        if not self.check("EKF has a position", ekf is not None):
            return
        # APMFirmwarePlugin::guidedModeTakeoff: GUIDED, arm, NAV_TAKEOFF (p7 above home)
        if not self.set_mode("GUIDED"):
            return
        armed = self.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        if not self.check("arm", armed == M.MAV_RESULT_ACCEPTED, f"result {armed}"):
            return
        result = self.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m)
        self.check("takeoff accepted", result == M.MAV_RESULT_ACCEPTED, f"result {result}")
        up = self.wait("GLOBAL_POSITION_INT", lambda p: p.relative_alt > (alt_m - 1.0) * 1000, 60.0)
        if not self.check("takeoff altitude", up is not None):
            return
        # Go to location: COMMAND_INT DO_REPOSITION, AMSL at the current altitude
        lat, lon = goto_lat_lon
        self.conn.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL, M.MAV_CMD_DO_REPOSITION, 0, 0,
                                       -1.0, M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0.0, math.nan,
                                       int(round(lat * 1e7)), int(round(lon * 1e7)), up.alt * 1e-3)
        ack = self.wait("COMMAND_ACK", lambda a: a.command == M.MAV_CMD_DO_REPOSITION, 10.0)
        self.check("go to location accepted", ack is not None and ack.result == M.MAV_RESULT_ACCEPTED)
        near = self.wait("GLOBAL_POSITION_INT", lambda p: _dist_m(p, lat, lon) < 3.0, 60.0)
        self.check("go to location reached", near is not None)
        # Pause: ArduCopter's BRAKE; the vehicle stops
        self.set_mode("BRAKE")
        still = self.wait("VFR_HUD", lambda v: v.groundspeed < 0.5, 30.0)
        self.check("paused (BRAKE stops)", still is not None)
        # Change altitude: GUIDED, then a LOCAL_OFFSET_NED position target with only x/y/z
        z0 = self.rel_alt_m()
        self.set_mode("GUIDED")
        self.conn.mav.set_position_target_local_ned_send(
            0, 1, 1, M.MAV_FRAME_LOCAL_OFFSET_NED, 0xFFF8, 0.0, 0.0, -climb_m, 0, 0, 0, 0, 0, 0, 0, 0)
        climbed = self.wait("GLOBAL_POSITION_INT",
                            lambda p: p.relative_alt * 1e-3 > z0 + climb_m - 1.0, 40.0)
        self.check("change altitude", climbed is not None, f"from {z0:.1f} m by {climb_m} m")
        # RTL until landed and disarmed
        self.set_mode("RTL")
        landed = self.wait("HEARTBEAT", lambda h: h.get_srcComponent() == 1
                           and not h.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 90.0)
        self.check("RTL landed and disarmed", landed is not None)

    def run_all(self, alt_m: float, goto_lat_lon: tuple[float, float], climb_m: float) -> None:
        self.connect()
        self.load_parameters()
        self.download_plan()
        self.request_streams()
        self.fly(alt_m, goto_lat_lon, climb_m)
        gap = self.max_heartbeat_gap_s()
        self.check("no heartbeat gap beyond QGC's link-loss time", gap <= QGC_LINK_LOSS_S,
                   f"largest gap {gap:.2f} s over {len(self.heartbeat_times)} heartbeats")


def _ftp_reply(payload: bytes):
    _seq, _session, opcode, size, req_opcode, burst_complete, _pad, offset = struct.unpack_from(
        "<HBBBBBBI", payload)
    return opcode, req_opcode, size, burst_complete, offset, payload[12:12 + max(size, 1)]


def _dist_m(p, lat: float, lon: float) -> float:
    dn = (p.lat * 1e-7 - lat) * 111_320.0
    de = (p.lon * 1e-7 - lon) * 111_320.0 * math.cos(math.radians(lat))
    return math.hypot(dn, de)
