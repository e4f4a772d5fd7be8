"""The short GPS-denied flight the outside-node tests fly on an external perception node's fixes."""

from __future__ import annotations

from support import REPO_ROOT

#: The example node written from docs/interfaces.md alone (zenoh, numpy, OpenCV).
EXAMPLE_NODE = REPO_ROOT / "examples" / "perception_node_python" / "node.py"


def external_flight(name: str, duration_s: float) -> dict:
    """Over the houses east of the centre, world seen flat (as tests/e2e/test_autopilot_node.py's
    GPS-denied flight): the take-off waits ~7 s at rest for the gyro bias (the pre-arm check of a
    dead-reckoned climb, issue 12), then 50 m is reached after about 10 s, fixes are used from 35 m
    (SN_VIS_MIN_ALT, the flat worlds' value; the 3-D default is 50 m). A new dict each call."""
    return {
        "name": name, "seed": 5, "duration_s": duration_s,
        "flight": {"mode": "autopilot", "altitude_m": 50, "start_enu_m": [60, -60],
                   "route_enu_m": [[60, -95], [95, -95]]},
        "sim": {"gps": {"enabled": False}, "camera": {"rate_hz": 5.0, "relief": False}},
        "perception": {"reference": "orthophoto"},
        "recorder": {"camera_every_n": 0},
        "autopilot": {"mavlink_tcp_port": 0, "mavlink_udp_out": "none",
                      "params": {"SN_VIS_MIN_ALT": 35, "WPNAV_SPEED_UP": 500, "WPNAV_SPEED_DN": 300,
                                 "LAND_SPEED": 200}},
    }
