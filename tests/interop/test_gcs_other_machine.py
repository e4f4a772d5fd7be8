"""A ground station on another machine flies ``scenenav sitl``: ``--tcp-host 0.0.0.0`` lets it
connect over TCP, ``--udp-out <its address>:<port>`` sends it telemetry over UDP, and its requests
come back on both (PARAM_REQUEST_READ answered with PARAM_VALUE). The other machine is a network
namespace behind a veth pair (``support.other_machine``); the client is pymavlink, which MAVProxy
and many ground-station scripts are built on. Until session 23 the UDP socket was bound to
127.0.0.1, and the kernel refused every datagram to another machine (EINVAL, counted as
``tx_dropped``): ``--udp-out`` to a laptop sent nothing."""

from __future__ import annotations

import socket
import sys

from support.fake_vehicle import free_port
from support.lineproc import wait_until
from support.other_machine import OtherMachine
from support.sitl_session import SitlSession

CLIENT = r'''
import sys
from pymavlink import mavutil
host, tcp_port, node_addr, udp_port = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])

def ask(conn, name):
    for _ in range(3):
        conn.mav.param_request_read_send(conn.target_system, conn.target_component, name.encode(), -1)
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
        if msg is not None:
            return msg.param_value
    return None

tcp = mavutil.mavlink_connection(f"tcp:{host}:{tcp_port}", source_system=250, autoreconnect=False)
hb = tcp.wait_heartbeat(timeout=30)
print("tcp heartbeat", hb is not None, flush=True)
print("tcp SYSID_THISMAV", ask(tcp, "SYSID_THISMAV") if hb else None, flush=True)
udp = mavutil.mavlink_connection(f"udpin:{node_addr}:{udp_port}", source_system=251)
hb = udp.wait_heartbeat(timeout=30)
print("udp heartbeat", hb is not None, flush=True)
print("udp SYSID_THISMAV", ask(udp, "SYSID_THISMAV") if hb else None, flush=True)
'''


def test_a_ground_station_on_another_machine(tmp_path):
    machine = OtherMachine()
    udp_port = free_port(socket.SOCK_DGRAM)
    sitl = SitlSession(tmp_path, "--tcp-host", "0.0.0.0", "--udp-out", f"{machine.node_addr}:{udp_port}",
                       "--perception", "off")
    try:
        sitl.wait_ready()
        text = "\n".join(sitl.lines)
        assert f"MAVLink TCP server: 0.0.0.0:{sitl.port}" in text
        assert f"{machine.host_addr}:{sitl.port}" in text or machine.netns is None, text[-2000:]
        script = tmp_path / "client.py"
        script.write_text(CLIENT)
        log = tmp_path / "client.log"
        client = machine.start([sys.executable, str(script), machine.host_addr, str(sitl.port),
                                machine.node_addr, str(udp_port)], log)
        try:
            assert client.wait(timeout=120) == 0, log.read_text()
        finally:
            if client.poll() is None:
                client.kill()
        out = log.read_text()
        print("other machine:", machine.describe())
        assert "tcp heartbeat True" in out and "udp heartbeat True" in out, out
        assert "tcp SYSID_THISMAV 1.0" in out and "udp SYSID_THISMAV 1.0" in out, out
        mavlink = (sitl.run_dir / "mavlink.json").read_text()
        assert '"udp_bind_host": "0.0.0.0"' in mavlink and '"tcp_host": "0.0.0.0"' in mavlink, mavlink
    finally:
        sitl.stop()
        machine.close()
    assert wait_until(lambda: sitl.proc.poll() is not None)
