"""A QGroundControl-like ground station (``support.qgc_like``, from QGC's source) connects to
``scenenav sitl`` and flies: connect sequence, MAVFTP ``@PARAM/param.pck``, the parameters its APM
setup pages read (setup complete), mission / fence / rally download, QGC's stream rates, take-off,
Go to location, Pause (BRAKE), Change altitude, RTL to landing -- with no heartbeat gap beyond QGC's
3.5 s link-loss time, on the wall clock (``--speedup 1``: a real-time flight must keep up with the
wall clock, which a loaded 2-core machine does not at 3x) and in lockstep."""

from __future__ import annotations

import math

import pytest
from support.qgc_like import QgcLike
from support.sitl_session import SitlSession, enu_to_latlon, final_position, write_params

ALT_M, CLIMB_M = 20.0, 5.0          # above the roofs near the start
GOTO_ENU = (20.0, 20.0)
PARAMS = {"RTL_ALT": 1500, "RTL_LOIT_TIME": 0, "LAND_SPEED": 200, "WPNAV_SPEED_DN": 300,
          "DISARM_DELAY": 30}


def _fly(tmp_path, *mode: str) -> QgcLike:
    sitl = SitlSession(tmp_path, *mode, "--perception", "off",
                       "--set", "autopilot.params_file=" + write_params(tmp_path, **PARAMS))
    qgc = None
    try:
        sitl.wait_ready()
        qgc = QgcLike(sitl.port)
        qgc.run_all(ALT_M, enu_to_latlon(*GOTO_ENU), CLIMB_M)
    finally:
        if qgc is not None:
            qgc.close()
        sitl.stop()
    end = final_position(sitl.truth())
    qgc.check("landed at home (truth)", math.hypot(end[0], end[1]) < 2.0 and end[2] < 0.5, str(end))
    return qgc


def _report(qgc: QgcLike) -> str:
    return "\n".join(f"{'ok  ' if c.ok else 'FAIL'} {c.name}: {c.detail}" for c in qgc.checks)


@pytest.mark.realtime
def test_qgc_like_session_on_the_wall_clock(tmp_path):
    qgc = _fly(tmp_path, "--speedup", "1")
    assert not qgc.failures, _report(qgc)
    assert qgc.param_source == "ftp"


def test_qgc_like_session_in_lockstep(tmp_path):
    qgc = _fly(tmp_path, "--lockstep")
    assert not qgc.failures, _report(qgc)
