"""Real ground-station software against the emulator: MAVProxy, MAVSDK, mavlogdump.py."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest
from support.fake_vehicle import HOME, free_port, gcs_connection, running_server, wait_for
from support.lineproc import VENV_BIN, MavproxyProcess, wait_until

from autopilot_bridge.modes import CopterMode

MAVLOGDUMP = VENV_BIN / "mavlogdump.py"
TIMEOUT_S = 60.0

WPL = """QGC WPL 110
0\t1\t0\t16\t0\t0\t0\t0\t{lat:.7f}\t{lon:.7f}\t{alt:.2f}\t1
1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t10\t1
2\t0\t3\t16\t0\t0\t0\t0\t47.3980000\t8.5458000\t20\t1
3\t0\t3\t16\t0\t0\t0\t0\t47.3985000\t8.5462000\t25\t1
4\t0\t3\t20\t0\t0\t0\t0\t0\t0\t0\t1
"""


def _wait_until(predicate, timeout_s: float = TIMEOUT_S) -> bool:
    return wait_until(predicate, timeout_s)


def _mavproxy(port: int, workdir: Path) -> MavproxyProcess:
    return MavproxyProcess(port, workdir, f"--out=udp:127.0.0.1:{free_port()}", timeout_s=TIMEOUT_S)


def test_mavproxy_params_and_waypoints(tmp_path):
    wpl = tmp_path / "mission.txt"
    wpl.write_text(WPL.format(lat=HOME[0], lon=HOME[1], alt=HOME[2]))
    with running_server() as (server, vehicle):
        mp = _mavproxy(server.tcp_port, tmp_path)
        try:
            mp.expect(f"Received {server.params.count} parameters")
            mark = len(mp.lines)
            mp.send("param show WPNAV_SPEED")
            line = mp.lines[mp.expect("WPNAV_SPEED", mark)]
            assert float(line.split()[-1]) == 1000.0

            mp.send("param set WPNAV_SPEED 1200")
            assert _wait_until(lambda: server.params.get("WPNAV_SPEED") == 1200.0)
            assert vehicle.params_seen.get("WPNAV_SPEED") == 1200.0

            mark = len(mp.lines)
            mp.send(f"wp load {wpl}")
            mp.expect("TYPE_MISSION: ACCEPTED", mark)
            assert _wait_until(lambda: len(vehicle.mission) == 4)
            assert [i.command for i in vehicle.mission] == [22, 16, 16, 20]
            assert vehicle.mission[2].alt_m == 25.0

            mark = len(mp.lines)
            mp.send("wp list")
            mp.expect("Requesting 5 waypoints", mark)
            mp.expect("47.3985000000 8.5462000000 25.000000", mark)

            mp.send("mode GUIDED")
            assert _wait_until(lambda: vehicle.mode == CopterMode.GUIDED)
            mp.send("arm throttle")
            assert _wait_until(lambda: vehicle.armed)
        finally:
            mp.close()
        assert server.stats["handler_errors"] == 0


def test_mavsdk_connects_reads_params_and_uploads_a_mission():
    mavsdk = pytest.importorskip("mavsdk")
    from mavsdk.plugins.mission_raw import MissionItem, MissionRaw
    from mavsdk.plugins.param import Param

    with running_server() as (server, vehicle):
        sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION))
        try:
            assert sdk.add_any_connection(f"tcpout://127.0.0.1:{server.tcp_port}") == \
                mavsdk.ConnectionResult.SUCCESS
            system = sdk.first_autopilot(TIMEOUT_S)
            assert system is not None
            assert system.autopilot_type() == mavsdk.Autopilot.ARDUPILOT
            param = Param(system)
            assert param.get_param_float("WPNAV_SPEED") == 1000.0
            assert param.get_param_int("RTL_ALT") == 1500
            assert param.get_param_int("FRAME_CLASS") == 1
            param.set_param_float("WPNAV_ACCEL", 300.0)
            assert server.params.get("WPNAV_ACCEL") == 300.0

            items = [MissionItem(seq=i, frame=0 if i == 0 else 6, command=16,
                                 current=1 if i == 0 else 0, autocontinue=1,
                                 x=int(round((HOME[0] + 0.0004 * i) * 1e7)),
                                 y=int(round(HOME[1] * 1e7)),
                                 z=HOME[2] if i == 0 else 10.0 + i, mission_type=0)
                     for i in range(5)]
            mission = MissionRaw(system)
            mission.upload_mission(items)
            assert len(vehicle.mission) == 4
            down = mission.download_mission()
            assert [(d.seq, d.x, d.z) for d in down[1:]] == [(i.seq, i.x, i.z) for i in items[1:]]
        finally:
            sdk.destroy()
        assert server.stats["handler_errors"] == 0


def test_tlog_has_both_directions_and_mavlogdump_reads_it(tmp_path):
    tlog = tmp_path / "flight.tlog"
    with running_server(tlog_path=str(tlog)) as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            conn.mav.param_request_read_send(1, 1, b"WPNAV_SPEED", -1)
            assert wait_for(conn, "PARAM_VALUE") is not None
            assert wait_for(conn, "HEARTBEAT") is not None
        finally:
            conn.close()
    out = subprocess.run([sys.executable, str(MAVLOGDUMP), "--types",
                          "PARAM_REQUEST_READ,PARAM_VALUE,HEARTBEAT", str(tlog)],
                         capture_output=True, text=True, timeout=TIMEOUT_S, check=True).stdout
    assert "PARAM_REQUEST_READ" in out and "WPNAV_SPEED" in out   # GCS -> vehicle
    assert "PARAM_VALUE" in out and "HEARTBEAT" in out            # vehicle -> GCS
    from pymavlink import mavutil
    log = mavutil.mavlink_connection(str(tlog))
    srcs = set()
    while (msg := log.recv_match(blocking=False)) is not None:
        srcs.add(msg.get_srcSystem())
    assert {1, 255} <= srcs


def test_mavsdk_over_udp_like_a_listening_ground_station():
    mavsdk = pytest.importorskip("mavsdk")
    from mavsdk.plugins.param import Param

    gcs_port = free_port(socket.SOCK_DGRAM)
    with running_server(udp_target_port=gcs_port, tcp_enabled=False) as (server, vehicle):
        sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION))
        try:
            assert sdk.add_any_connection(f"udpin://127.0.0.1:{gcs_port}") == \
                mavsdk.ConnectionResult.SUCCESS
            system = sdk.first_autopilot(TIMEOUT_S)
            assert system is not None
            assert Param(system).get_param_float("WPNAV_SPEED_UP") == 250.0
        finally:
            sdk.destroy()
