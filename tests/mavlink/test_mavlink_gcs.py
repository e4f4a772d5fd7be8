"""What ground stations (QGC, MAVProxy, MAVSDK) meet first (issue 15), against the real server.

* the link clock: HEARTBEAT on the wall clock while the simulated clock stands still (a lockstep
  wait), on a server with a frozen caller clock and end to end on ``scenenav sitl`` with the
  simulator stopped.
* MAVFTP: pymavlink's own MAVFTP client (the one MAVProxy uses) downloads ``@PARAM/param.pck``
  and decodes it with its own parser; other paths and requests get ArduPilot's NAKs.
"""

from __future__ import annotations

import errno
import json
import math
import os
import signal
import struct
import threading
import time

import pytest
from pymavlink import mavftp
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import (
    FakeVehicle,
    gcs_connection,
    running_server,
    server_config,
    wait_for,
)
from support.qgc_like import setup_complete
from support.sitl_session import SitlSession, monitor_connection

from autopilot_bridge import telemetry
from autopilot_bridge.mavlink_ftp import FtpError, FtpOp, FtpServer
from autopilot_bridge.mavlink_server import MavlinkServer
from autopilot_bridge.param_pack import PackedParam, PackQuery, pack_params, parse_query
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore, ParamType
from scenenav.core.errors import UserError

#: real-time SITL flights: `make test` runs them after the parallel part, apart from it
pytestmark = pytest.mark.realtime

M = mavlink2
# QGC declares the link lost after ~3.5 s without a heartbeat, MAVSDK after 3 s; ArduPilot sends
# one per second. 1.5 s leaves room for a loaded machine and still fails a starved link.
MAX_HEARTBEAT_GAP_S = 1.5


def heartbeat_times(conn, duration_s: float, kinds=("HEARTBEAT",)) -> dict[str, list[float]]:
    """Arrival times (monotonic) of each kind of message during ``duration_s``."""
    out: dict[str, list[float]] = {k: [] for k in kinds}
    deadline = time.monotonic() + duration_s
    while (now := time.monotonic()) < deadline:
        msg = conn.recv_match(blocking=True, timeout=min(0.1, deadline - now))
        if msg is not None and msg.get_type() in out and msg.get_srcSystem() == 1:
            out[msg.get_type()].append(time.monotonic())
    return out


def gaps(times: list[float], start: float, end: float) -> list[float]:
    points = [start, *times, end]
    return [b - a for a, b in zip(points, points[1:], strict=False)]


# ----------------------------------------------------------------------------- item 8: link clock


def test_heartbeat_keeps_the_wall_clock_while_the_caller_clock_is_frozen():
    """The poller's (simulated) clock stands at 42 s for 4.5 wall seconds: heartbeats go on at
    1 Hz, while the telemetry that follows simulated time (ATTITUDE) does not advance."""
    server = MavlinkServer(FakeVehicle(), ParameterStore(), server_config())
    conn = gcs_connection(server.tcp_port)
    stop = threading.Event()

    def poll_frozen() -> None:
        while not stop.is_set():
            server.poll(42.0)
            time.sleep(0.005)

    poller = threading.Thread(target=poll_frozen, daemon=True)
    poller.start()
    try:
        start = time.monotonic()
        got = heartbeat_times(conn, 4.5, ("HEARTBEAT", "ATTITUDE"))
        end = time.monotonic()
        beats = got["HEARTBEAT"]
        assert len(beats) >= 4, beats
        assert max(gaps(beats, start, end)) < MAX_HEARTBEAT_GAP_S, gaps(beats, start, end)
        assert len(got["ATTITUDE"]) <= 1          # sent once at connect, then the clock froze
    finally:
        stop.set()
        poller.join(5)
        conn.close()
        server.close()


def test_heartbeat_schedule_uses_the_injected_wall_clock():
    """Deterministic: a fake wall clock advanced 0.1 s per poll, the caller's clock frozen. Ten
    wall seconds give ten heartbeats; the 4 Hz ATTITUDE stream stays at its first message."""
    wall = [1000.0]
    server = MavlinkServer(FakeVehicle(), ParameterStore(), server_config(),
                           monotonic_s=lambda: wall[0])
    conn = gcs_connection(server.tcp_port)
    try:
        deadline = time.monotonic() + 10
        while server.tcp_client_count == 0 and time.monotonic() < deadline:
            server.poll(7.0)
        for _ in range(100):
            server.poll(7.0)
            wall[0] += 0.1
        server.poll(7.0)
        counts = {"HEARTBEAT": 0, "ATTITUDE": 0}
        while (msg := conn.recv_match(blocking=True, timeout=0.5)) is not None:
            if msg.get_type() in counts:
                counts[msg.get_type()] += 1
        assert counts["HEARTBEAT"] in (10, 11), counts
        assert counts["ATTITUDE"] == 1, counts
    finally:
        conn.close()
        server.close()


def test_sitl_heartbeats_go_on_while_the_simulator_stands_still(tmp_path):
    """End to end: ``scenenav sitl --lockstep``; the simulator process is stopped (SIGSTOP) for
    4.5 s, so no clock tick reaches the autopilot, as in a long lockstep wait. A ground station
    still gets a heartbeat every second."""
    sitl = SitlSession(tmp_path, "--lockstep", "--perception", "off")
    conn = None
    sim_pid = None
    try:
        sitl.wait_ready()
        conn = monitor_connection(sitl.port)
        assert heartbeat_times(conn, 2.0)["HEARTBEAT"], "no heartbeat at all"
        sim_pid = sitl.child_pid("sim")
        assert sim_pid is not None
        os.kill(sim_pid, signal.SIGSTOP)
        while conn.recv_match(blocking=True, timeout=0.05) is not None:
            pass                                  # what was sent before the stop
        start = time.monotonic()
        beats = heartbeat_times(conn, 4.5)["HEARTBEAT"]
        end = time.monotonic()
        os.kill(sim_pid, signal.SIGCONT)
        sim_pid = None
        assert len(beats) >= 3, beats
        assert max(gaps(beats, start, end)) < MAX_HEARTBEAT_GAP_S, gaps(beats, start, end)
    finally:
        if sim_pid is not None:
            os.kill(sim_pid, signal.SIGCONT)
        if conn is not None:
            conn.close()
        sitl.stop()


# ----------------------------------------------------------------------------- item 1: MAVFTP


def ftp_get(conn, path: str):
    """pymavlink's MAVFTP client: (error code, file bytes). The local name ``-`` keeps the download in
    memory (without it the client writes the file into the current directory)."""
    client = mavftp.MAVFTP(conn, 1, 1)
    client.cmd_get([path, "-"])
    ret = client.process_ftp_reply("OpenFileRO", timeout=10)
    return ret.error_code, client.get_result


def test_pymavlink_mavftp_downloads_the_packed_parameter_file():
    params = ParameterStore(PARAM_SPECS, defaults={"WPNAV_SPEED": 800.0})
    assert params.set("RTL_ALT", 2500).ok and params.set("SN_ARM_BY", 0.25).ok
    with running_server(params=params) as (server, _):
        conn = gcs_connection(server.tcp_port)
        try:
            assert wait_for(conn, "HEARTBEAT") is not None
            version = _request_autopilot_version(conn)
            assert version.capabilities & M.MAV_PROTOCOL_CAPABILITY_FTP
            code, data = ftp_get(conn, "@PARAM/param.pck?withdefaults=1")
            assert code == 0 and data is not None
            pdata = mavftp.MAVFTP.ftp_param_decode(data)
            assert pdata is not None
            magic, num, total = struct.unpack_from("<HHH", data)
            assert (magic, num, total) == (0x671C, params.count, params.count)
            got = [(n.decode(), v, t) for n, v, t in pdata.params]
            want_types = {ParamType.INT8: 1, ParamType.INT16: 2, ParamType.INT32: 3,
                          ParamType.REAL32: 4}
            assert [g[0] for g in got] == params.names()             # every one, in index order
            for (name, value, ptype), spec in zip(got, params.specs(), strict=True):
                assert ptype == want_types[spec.ptype], name
                assert value == pytest.approx(params.get(name), rel=1e-6), name
            # defaults only where the value differs (as ArduPilot): the two sets; WPNAV_SPEED's
            # start-up default is the one given to the store
            values = {name: value for name, value, _ in got}
            defaults = {n.decode(): v for n, v, _ in pdata.defaults or []}
            changed = {n: d for n, d in defaults.items() if d != values[n]}
            assert changed == {"RTL_ALT": 1500, "SN_ARM_BY": pytest.approx(0.20, rel=1e-6)}
            assert values["WPNAV_SPEED"] == 800.0
            # without defaults, and a range of indices
            code, data = ftp_get(conn, "@PARAM/param.pck?start=2&count=3")
            assert code == 0
            pdata = mavftp.MAVFTP.ftp_param_decode(data)
            assert struct.unpack_from("<HHH", data) == (0x671B, 3, params.count)
            assert [n.decode() for n, _, _ in pdata.params] == params.names()[2:5]
            assert pdata.defaults is None
        finally:
            conn.close()


def _request_autopilot_version(conn):
    conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0,
                               M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)
    msg = wait_for(conn, "AUTOPILOT_VERSION")
    assert msg is not None
    return msg


def ftp_request(conn, seq: int, opcode: int, data: bytes = b"", size: int | None = None,
                offset: int = 0, session: int = 0):
    """One raw request; the reply (FILE_TRANSFER_PROTOCOL decoded as (header..., data))."""
    head = struct.pack("<HBBBBBBI", seq, session, opcode, len(data) if size is None else size,
                       0, 0, 0, offset)
    conn.mav.file_transfer_protocol_send(0, 1, 1, list((head + data).ljust(251, b"\0")))
    msg = wait_for(conn, "FILE_TRANSFER_PROTOCOL",
                   condition=lambda m: struct.unpack_from("<H", bytes(m.payload))[0] == seq + 1)
    assert msg is not None, f"no FTP reply to opcode {opcode}"
    payload = bytes(msg.payload)
    return struct.unpack_from("<HBBBBBBI", payload) + (payload[12:],)


def test_ftp_naks_as_ardupilot_without_such_a_file():
    with running_server() as (server, _):
        conn = gcs_connection(server.tcp_port)
        try:
            seq, session, op, size, req, _b, _p, _o, data = ftp_request(
                conn, 10, FtpOp.OPEN_FILE_RO, b"@PARAM/param.pck.bak")
            assert (seq, op, size, req, data[0]) == (11, FtpOp.NAK, 1, FtpOp.OPEN_FILE_RO,
                                                      FtpError.FILE_NOT_FOUND)
            for k, (opcode, name) in enumerate(((FtpOp.LIST_DIRECTORY, b"/APM/LOGS"),
                                                (FtpOp.REMOVE_FILE, b"/x.txt"),
                                                (FtpOp.CALC_FILE_CRC32, b"/x.txt"))):
                reply = ftp_request(conn, 20 + 2 * k, opcode, name)
                assert (reply[2], reply[4], reply[8][0]) == (FtpOp.NAK, opcode,
                                                             FtpError.FILE_NOT_FOUND), opcode
            reply = ftp_request(conn, 30, FtpOp.READ_FILE, size=80)         # nothing open
            assert (reply[2], reply[8][0]) == (FtpOp.NAK, FtpError.FILE_NOT_FOUND)
            reply = ftp_request(conn, 32, FtpOp.CREATE_FILE, b"/new.txt")   # read-only
            assert (reply[2], reply[3], reply[8][0], reply[8][1]) == (
                FtpOp.NAK, 2, FtpError.FAIL_ERRNO, errno.EROFS)
            reply = ftp_request(conn, 34, FtpOp.TRUNCATE_FILE, b"/x.txt")
            assert (reply[2], reply[8][0]) == (FtpOp.NAK, FtpError.UNKNOWN_COMMAND)
            reply = ftp_request(conn, 36, FtpOp.OPEN_FILE_RO, b"@PARAM/param.pck", size=3)
            assert (reply[2], reply[8][0]) == (FtpOp.NAK, FtpError.INVALID_DATA_SIZE)
            reply = ftp_request(conn, 38, FtpOp.RESET_SESSIONS)
            assert reply[2] == FtpOp.ACK
        finally:
            conn.close()


def test_ftp_read_burst_resend_and_session_rules():
    """The protocol rules on the pure server: open twice, a resend answered with the very same
    reply, a burst that ends with EndOfFile + burst_complete, stale sessions reopen after 3 s."""
    content = bytes(range(256)) * 3                       # 768 bytes
    ftp = FtpServer(lambda path: content if path == "/f" else None)

    def req(seq, opcode, data=b"", size=None, offset=0, session=0):
        head = struct.pack("<HBBBBBBI", seq, session, opcode,
                           len(data) if size is None else size, 0, 0, 0, offset)
        return (head + data).ljust(251, b"\0")

    def unpack(payload):
        return struct.unpack_from("<HBBBBBBI", payload) + (payload[12:],)

    (open_reply,) = ftp.handle("c", req(0, FtpOp.OPEN_FILE_RO, b"/f"), 0.0)
    head = unpack(open_reply)
    assert head[2] == FtpOp.ACK and struct.unpack_from("<I", head[8])[0] == 768
    (again,) = ftp.handle("c", req(0, FtpOp.OPEN_FILE_RO, b"/f"), 0.1)
    assert again == open_reply                             # a resend: the same bytes
    (busy,) = ftp.handle("c", req(2, FtpOp.OPEN_FILE_RO, b"/f"), 1.0)
    assert unpack(busy)[2] == FtpOp.NAK and unpack(busy)[8][0] == FtpError.FAIL
    (read,) = ftp.handle("c", req(4, FtpOp.READ_FILE, size=100, offset=700), 1.0)
    r = unpack(read)
    assert (r[2], r[3], r[7]) == (FtpOp.ACK, 68, 700) and r[8][:68] == content[700:]
    burst = [unpack(p) for p in ftp.handle("c", req(6, FtpOp.BURST_READ_FILE, size=200), 1.0)]
    assert [b[0] for b in burst] == [7, 8, 9, 10, 11]
    assert b"".join(b[8][:b[3]] for b in burst[:-1]) == content
    assert [b[7] for b in burst] == [0, 200, 400, 600, 768]
    assert burst[-1][2] == FtpOp.NAK and burst[-1][8][0] == FtpError.END_OF_FILE
    assert burst[-1][5] == 1 and all(b[5] == 0 for b in burst[:-1])
    # idle for more than 3 s: the open file is given up and the session opens again
    (reopen,) = ftp.handle("c", req(20, FtpOp.OPEN_FILE_RO, b"/f"), 5.0)
    assert unpack(reopen)[2] == FtpOp.ACK
    # another client has its own sessions; TerminateSession closes
    (other,) = ftp.handle("d", req(0, FtpOp.READ_FILE, size=10), 5.0)
    assert unpack(other)[8][0] == FtpError.FILE_NOT_FOUND
    (term,) = ftp.handle("c", req(22, FtpOp.TERMINATE_SESSION), 5.0)
    assert unpack(term)[2] == FtpOp.ACK
    (closed,) = ftp.handle("c", req(24, FtpOp.READ_FILE, size=10), 5.0)
    assert unpack(closed)[8][0] == FtpError.FILE_NOT_FOUND
    assert ftp.handle("c", req(26, FtpOp.ACK), 5.0) == []
    assert ftp.handle("c", b"\x01\x02", 5.0) == []


def test_param_pack_shares_name_prefixes_and_options():
    params = [PackedParam("SN_ARM_BX", ParamType.REAL32, 0.13, 0.13),
              PackedParam("SN_ARM_BY", ParamType.REAL32, 0.25, 0.20),
              PackedParam("SN_ARM_FX", ParamType.INT8, -5, -5),
              PackedParam("SN_ARM_FXY_LNG16", ParamType.INT32, 70000, 1),
              PackedParam("SN_ARM_FXY_LNG17", ParamType.INT16, -300, -300)]
    data = pack_params(params, PackQuery(with_defaults=True))
    # SN_ARM_BY shares 8 characters with SN_ARM_BX: type byte float + default flag, then
    # (suffix length 1 - 1) << 4 | 8, "Y", the value and the default
    second = data[6 + 2 + 9 + 4:]
    assert second[:3] == bytes((0x14, 0x08)) + b"Y"
    assert struct.unpack_from("<ff", second, 3) == pytest.approx((0.25, 0.20), rel=1e-6)
    decoded = mavftp.MAVFTP.ftp_param_decode(data)
    assert [(n.decode(), v) for n, v, _ in decoded.params] == [
        ("SN_ARM_BX", pytest.approx(0.13, rel=1e-6)), ("SN_ARM_BY", pytest.approx(0.25, rel=1e-6)),
        ("SN_ARM_FX", -5), ("SN_ARM_FXY_LNG16", 70000), ("SN_ARM_FXY_LNG17", -300)]
    # 15 characters shared with the name before (the most the low nibble holds): suffix "7"
    assert data.endswith(bytes((0x02, 15)) + b"7" + struct.pack("<h", -300))
    assert parse_query("withdefaults=1&start=1&count=2") == PackQuery(True, 1, 2)
    assert parse_query("withdefaults=x") is None and parse_query("") == PackQuery()
    assert telemetry.CAPABILITIES & M.MAV_PROTOCOL_CAPABILITY_FTP


# ----------------------------------------------------------------------------- item 9: persistence


def test_persist_file_keeps_only_the_set_parameters(tmp_path):
    store_file = tmp_path / "eeprom.json"
    first = ParameterStore(PARAM_SPECS, defaults={"EK3_SRC1_POSXY": 6}, persist_path=store_file)
    assert first.set("RTL_ALT", 2500).ok and first.set("LAND_SPEED", 50).ok   # 50: the default
    assert first.set("RTL_ALT", 1e12).ok is False                              # refused: not kept
    assert json.loads(store_file.read_text()) == {"LAND_SPEED": 50, "RTL_ALT": 2500}
    # the next start, with other defaults: the set values win, the rest are the new defaults
    second = ParameterStore(PARAM_SPECS, defaults={"RTL_ALT": 3000}, persist_path=store_file)
    assert second.get("RTL_ALT") == 2500 and second.get("EK3_SRC1_POSXY") == 3
    assert second.persisted_names == {"RTL_ALT", "LAND_SPEED"}
    assert second.default_at(second.index_of("RTL_ALT")) == 3000   # param.pck's default
    store_file.write_text('{"RTL_ALT": "high"}')
    with pytest.raises(UserError, match="RTL_ALT"):
        ParameterStore(PARAM_SPECS, persist_path=store_file)


def _read_param(conn, name: str) -> float | None:
    conn.mav.param_request_read_send(1, 1, name.encode(), -1)
    msg = wait_for(conn, "PARAM_VALUE", timeout_s=20, condition=lambda m: m.param_id == name)
    return None if msg is None else msg.param_value


def test_sitl_parameters_persist_between_starts_and_wipe(tmp_path):
    """Parameters set while one ``scenenav sitl`` runs are there after it is started again (and
    only those: the second start is GPS-denied and keeps its own EK3_SRC1_POSXY); ``--wipe``
    forgets them."""
    store_file = tmp_path / "instance0.json"
    sitl = SitlSession(tmp_path, "--perception", "off", params_store=store_file, run_name="run1")
    try:
        sitl.wait_ready()
        conn = gcs_connection(sitl.port)
        for name, value in (("RTL_ALT", 2500.0), ("WPNAV_SPEED", 750.0)):
            conn.mav.param_set_send(1, 1, name.encode(), value, M.MAV_PARAM_TYPE_REAL32)
            assert wait_for(conn, "PARAM_VALUE", timeout_s=20, condition=lambda m, n=name, v=value:
                            m.param_id == n and m.param_value == v) is not None
        conn.close()
    finally:
        sitl.stop()
    assert json.loads(store_file.read_text()) == {"RTL_ALT": 2500, "WPNAV_SPEED": 750.0}

    sitl = SitlSession(tmp_path, "--perception", "off", "--no-gps", params_store=store_file,
                       run_name="run2")
    try:
        sitl.wait_ready()
        assert any("parameters kept in" in ln for ln in sitl.lines)
        conn = gcs_connection(sitl.port)
        assert _read_param(conn, "RTL_ALT") == 2500.0
        assert _read_param(conn, "WPNAV_SPEED") == 750.0
        assert _read_param(conn, "EK3_SRC1_POSXY") == 6.0       # this start's own default
        conn.close()
    finally:
        sitl.stop()
    assert json.loads((tmp_path / "run2" / "params.json").read_text())["RTL_ALT"] == 2500

    sitl = SitlSession(tmp_path, "--perception", "off", "--wipe", params_store=store_file,
                       run_name="run3")
    try:
        sitl.wait_ready()
        conn = gcs_connection(sitl.port)
        assert _read_param(conn, "RTL_ALT") == 1500.0
        conn.close()
    finally:
        sitl.stop()


def test_safe_limits_table_agrees_with_the_specs():
    """docs/mavlink.md lists every parameter with a safe limit, with that limit."""
    from support import REPO_ROOT
    doc = (REPO_ROOT / "docs" / "mavlink.md").read_text()
    table = doc[doc.index("Safe limits"):doc.index("| name | type | default")]

    def fmt(v):
        return "-" if v is None else f"{v:g}"

    airframe = ("MOT_", "SN_ARM_", "SN_I", "SN_MASS_KG", "SN_ROT_")
    for spec in PARAM_SPECS:
        if spec.safe_min is None and spec.safe_max is None:
            continue
        if spec.name.startswith(airframe):
            assert (spec.safe_min, spec.safe_max) == (spec.min_value, spec.max_value), spec.name
            continue
        row = f"| `{spec.name}` | {fmt(spec.safe_min)} | {fmt(spec.safe_max)} |"
        grouped = f"`{spec.name}`," in table or f", `{spec.name}` |" in table
        assert row in table or (grouped and spec.safe_min == 0 and spec.safe_max is None), spec.name


# ----------------------------------------------------------------------------- item 2: QGC's set

# What QGC's APM setup pages read (src/AutoPilotPlugins/APM: APMRadioComponent, APMSensorsComponent,
# APMAirframeComponent, the flight mode, power and safety pages).
QGC_SETUP_PARAMS = (
    ["RCMAP_ROLL", "RCMAP_PITCH", "RCMAP_YAW", "RCMAP_THROTTLE", "FLTMODE_CH", "SIMPLE",
     "SUPER_SIMPLE", "FRAME_CLASS", "FRAME_TYPE", "ARMING_CHECK", "COMPASS_ENABLE",
     "BATT_MONITOR", "BATT_CAPACITY", "BATT_LOW_VOLT", "BATT_CRT_VOLT", "BATT_FS_LOW_ACT",
     "BATT_FS_CRT_ACT", "BATT_VOLT_MULT", "BATT_AMP_PERVLT", "FENCE_ENABLE", "FENCE_TYPE",
     "FENCE_ACTION", "FENCE_ALT_MAX", "FENCE_RADIUS", "FS_THR_ENABLE", "FS_THR_VALUE",
     "FS_GCS_ENABLE", "RTL_ALT", "RTL_LOIT_TIME", "RTL_ALT_FINAL", "LAND_SPEED"]
    + [f"FLTMODE{i}" for i in range(1, 7)]
    + [f"RC{n}_{k}" for n in range(1, 17) for k in ("MIN", "MAX", "TRIM", "REVERSED", "DZ")]
    + [f"COMPASS_{k}{s}" for s in ("", "2", "3") for k in ("DEV_ID", "USE")]
    + [f"COMPASS_OFS{s}_{a}" for s in ("", "2", "3") for a in "XYZ"]
    + [f"INS_ACC{s}{k}_{a}" for s in ("", "2", "3") for k in ("OFFS", "SCAL") for a in "XYZ"])


def _all_params(conn) -> dict[str, float]:
    conn.mav.param_request_list_send(1, 1)
    got: dict[str, float] = {}
    count = None
    while count is None or len(got) < count:
        msg = wait_for(conn, "PARAM_VALUE", timeout_s=10.0)
        assert msg is not None, f"only {len(got)} of {count} parameters"
        count = msg.param_count
        got[msg.param_id] = msg.param_value
    return got


def test_qgc_finds_every_setup_parameter_and_setup_complete():
    params = ParameterStore(PARAM_SPECS)
    with running_server(params=params) as (server, _):
        conn = gcs_connection(server.tcp_port)
        try:
            got = _all_params(conn)
            assert len(got) == params.count
            missing = [n for n in QGC_SETUP_PARAMS if n not in got]
            assert not missing, missing
            assert setup_complete(got) == {"airframe": True, "radio": True, "sensors": True}
            # the SITL calibration values, as ArduPilot's copter.parm
            assert got["INS_ACCOFFS_X"] == pytest.approx(0.001) and got["RC3_MIN"] == 1000
            assert [got[f"FLTMODE{i}"] for i in range(1, 7)] == [7, 9, 6, 3, 5, 0]
            # a protection that does not exist cannot be switched on
            conn.mav.param_set_send(1, 1, b"BATT_FS_LOW_ACT", 5.0, M.MAV_PARAM_TYPE_INT8)
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "BATT_FS_LOW_ACT" in m.text)
            assert text is not None and "not supported" in text.text   # 5 = terminate
            assert params.get("BATT_FS_LOW_ACT") == 0
            # one that changes nothing is stored as sent
            conn.mav.param_set_send(1, 1, b"RC3_MIN", 1100.0, M.MAV_PARAM_TYPE_INT16)
            assert wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "RC3_MIN"
                            and m.param_value == 1100.0) is not None
        finally:
            conn.close()
    # QGC would flag a radio that was never calibrated: the check can fail
    uncalibrated = dict(got, **{f"RC{c}_{k}": v for c in range(1, 5)
                                for k, v in (("MIN", 1100), ("MAX", 1900), ("TRIM", 1500))})
    assert not setup_complete(uncalibrated)["radio"]
    assert not setup_complete(dict(got, INS_ACCOFFS_X=0, INS_ACCOFFS_Y=0,
                                       INS_ACCOFFS_Z=0))["sensors"]


def test_gcs_parameters_are_documented_as_changing_nothing():
    """Every such parameter is in the docs table (`RCn_...` stands for RC1..RC16, `_X/Y/Z` for
    the three axes), and says so in its own description."""
    import re

    from support import REPO_ROOT

    from autopilot_bridge.gcs_param_specs import ACTIVE_GCS_PARAM_NAMES, GCS_PARAM_SPECS, PILOT_INPUT_PARAM_NAMES
    doc = (REPO_ROOT / "docs" / "mavlink.md").read_text()
    section = doc[doc.index("### Parameters QGC's setup pages read"):doc.index("## Failsafes")]
    names: set[str] = set()
    for token in re.findall(r"`([A-Z0-9_/n]+)`", section):
        token = token.replace("RCn_", "RC{n}_")
        axes = ["X", "Y", "Z"] if token.endswith("_X/Y/Z") else [None]
        for axis in axes:
            t = token[:-len("X/Y/Z")] + axis if axis else token
            if "{n}" in t:
                names.update(t.format(n=n) for n in range(1, 17))
            else:
                names.add(t)
    for spec in GCS_PARAM_SPECS:
        active = spec.name in ACTIVE_GCS_PARAM_NAMES or spec.name in PILOT_INPUT_PARAM_NAMES
        assert ("changes nothing" in spec.description) != active, spec.name
        assert spec.name in names, spec.name


# ----------------------------------------------------------------------------- item 12: telemetry


def _command(conn, command: int, *params: float) -> int:
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(1, 1, command, 0, *p)
    ack = wait_for(conn, "COMMAND_ACK", condition=lambda m: m.command == command)
    assert ack is not None, command
    return ack.result


def test_new_telemetry_and_unknown_message_interval_answered_as_ardupilot():
    from pymavlink.quaternion import Quaternion
    from support.fake_vehicle import HOME
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            # ArduPilot: DENIED and "No ap_message for mavlink id (N)" (GCS_Common.cpp)
            assert _command(conn, M.MAV_CMD_SET_MESSAGE_INTERVAL, 140, 100_000) == \
                M.MAV_RESULT_DENIED
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "ap_message" in m.text)
            assert text is not None and text.text == "No ap_message for mavlink id (140)"
            assert text.severity == M.MAV_SEVERITY_INFO
            # one ArduPilot has but without the sensor sends nothing of: accepted (no rangefinder)
            assert _command(conn, M.MAV_CMD_SET_MESSAGE_INTERVAL,
                            M.MAVLINK_MSG_ID_DISTANCE_SENSOR, 100_000) == M.MAV_RESULT_ACCEPTED
            # ATTITUDE_QUATERNION on request, agreeing with ATTITUDE's angles
            assert _command(conn, M.MAV_CMD_SET_MESSAGE_INTERVAL,
                            M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 200_000) == M.MAV_RESULT_ACCEPTED
            q = wait_for(conn, "ATTITUDE_QUATERNION")
            assert q is not None
            want = Quaternion([0.01, -0.02, math.radians(90.0)]).q
            assert [q.q1, q.q2, q.q3, q.q4] == pytest.approx(list(want), abs=1e-6)
            # streamed by default, in ArduPilot's groups
            nav = wait_for(conn, "NAV_CONTROLLER_OUTPUT")     # EXTENDED_STATUS, from boot
            assert nav is not None and nav.wp_dist == 0
            power = wait_for(conn, "POWER_STATUS")
            assert power is not None and power.Vcc == 5000
            assert power.flags & M.MAV_POWER_STATUS_BRICK_VALID
            st = wait_for(conn, "SYSTEM_TIME")
            assert st is not None and abs(st.time_unix_usec / 1e6 - time.time()) < 60
            # GPS_GLOBAL_ORIGIN when asked
            assert _command(conn, M.MAV_CMD_REQUEST_MESSAGE,
                            M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN) == M.MAV_RESULT_ACCEPTED
            origin = wait_for(conn, "GPS_GLOBAL_ORIGIN")
            assert origin is not None
            assert (origin.latitude, origin.longitude) == (round(HOME[0] * 1e7),
                                                           round(HOME[1] * 1e7))
            assert server.stats["handler_errors"] == 0
        finally:
            conn.close()


# ----------------------------------------------------------------------------- item 3: modes


def test_brake_poshold_circle_smart_rtl_accepted_drift_refused_with_the_arducopter_text():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            custom = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            for mode in (17, 16, 7, 21):       # BRAKE (QGC's Pause), POSHOLD, CIRCLE, SMART_RTL
                assert _command(conn, M.MAV_CMD_DO_SET_MODE, custom, mode) == \
                    M.MAV_RESULT_ACCEPTED
                hb = wait_for(conn, "HEARTBEAT", condition=lambda m, n=mode: m.custom_mode == n)
                assert hb is not None and hb.base_mode & M.MAV_MODE_FLAG_GUIDED_ENABLED
            assert _command(conn, M.MAV_CMD_DO_SET_MODE, custom, 11) == M.MAV_RESULT_FAILED
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "DRIFT" in m.text)
            assert text is not None and text.text == "Flight mode change failed: DRIFT not supported"
        finally:
            conn.close()
