"""Where the autopilot's MAVLink endpoints listen and send from (autopilot_bridge.config)."""

from __future__ import annotations

import pytest

from autopilot_bridge.config import AutopilotNodeConfig, parse_udp_out, udp_bind_host_for
from scenenav.core.errors import UserError


def test_the_udp_socket_binds_where_it_can_reach_its_target():
    assert udp_bind_host_for("127.0.0.1") == "127.0.0.1"
    assert udp_bind_host_for("127.0.0.2") == "127.0.0.1"          # all of 127/8 is loopback
    assert udp_bind_host_for("localhost") == "127.0.0.1"
    assert udp_bind_host_for("192.168.1.50") == "0.0.0.0"         # another machine
    assert udp_bind_host_for("no-such-host.invalid") == "0.0.0.0"


def test_the_tcp_host_is_an_ipv4_address():
    assert AutopilotNodeConfig().mavlink_tcp_host == "127.0.0.1"
    assert AutopilotNodeConfig(mavlink_tcp_host="0.0.0.0").mavlink_tcp_host == "0.0.0.0"
    for bad in ("laptop", "1.2.3", "::1"):
        with pytest.raises(UserError, match="mavlink_tcp_host"):
            AutopilotNodeConfig(mavlink_tcp_host=bad)
    assert parse_udp_out("10.0.0.7:14550") == ("10.0.0.7", 14550)
