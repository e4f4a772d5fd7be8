"""MAVProxy loads the parameters by MAVFTP (``@PARAM/param.pck?withdefaults=1``), as it does from
ArduPilot, from the real MAVLink server (a FakeVehicle behind it), and sets one by PARAM_SET."""

from __future__ import annotations

from support.fake_vehicle import running_server
from support.lineproc import MavproxyProcess, wait_until

from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore


def test_mavproxy_fetches_parameters_by_ftp(tmp_path):
    params = ParameterStore(PARAM_SPECS)
    assert params.set("RTL_ALT", 2500).ok
    with running_server(params=params) as (server, _):
        mp = MavproxyProcess(server.tcp_port, tmp_path, timeout_s=60)
        try:
            mp.expect(f"Received {params.count} parameters (ftp)")
            mark = mp.send("param show RTL_ALT")
            line = mp.expect("RTL_ALT", mark)
            assert "2500" in mp.lines[line], mp.lines[line]
            mp.send("param set WPNAV_SPEED 750")
            assert wait_until(lambda: params.get("WPNAV_SPEED") == 750.0, 30)
            assert server.stats["rx_msgs"] > 0
        finally:
            mp.close()
