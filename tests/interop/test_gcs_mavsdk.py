"""MAVSDK-Python (4.x, the embedded C library; no mavsdk_server) flies ``scenenav sitl``.

Connect over TCP, arm, take off, upload a mission with the MissionRaw plugin, fly it, land; the
final position is checked against the last waypoint from the run's truth.csv (ground truth).
MissionRaw, because with ArduPilot item 0 of a mission is home: MAVSDK's Mission plugin puts the
first waypoint there and ArduCopter (and this autopilot) would skip it.
"""

from __future__ import annotations

import math
import time

import pytest
from support.sitl_session import TIMEOUT_S, SitlSession, enu_to_latlon, final_position, wait_until

#: real-time SITL flights: `make test` runs them after the parallel part, apart from it
pytestmark = pytest.mark.realtime

WAYPOINTS_ENU = [(25.0, 0.0), (25.0, 25.0), (5.0, 30.0)]
ALT_M = 15.0


def test_mavsdk_arm_takeoff_mission_land(tmp_path):
    mavsdk = pytest.importorskip("mavsdk")
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.mission_raw import MissionItem as RawItem
    from mavsdk.plugins.mission_raw import MissionRaw
    from mavsdk.plugins.telemetry import Telemetry

    sitl = SitlSession(tmp_path, "--speedup", "3", "--perception", "off",
                       "--set", "autopilot.params_file=" + str(_params(tmp_path)))
    sdk = None
    try:
        sitl.wait_ready()
        sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION))
        assert sdk.add_any_connection(f"tcpout://127.0.0.1:{sitl.port}") == \
            mavsdk.ConnectionResult.SUCCESS
        system = sdk.first_autopilot(TIMEOUT_S)
        assert system is not None
        assert system.autopilot_type() == mavsdk.Autopilot.ARDUPILOT
        action, mission, telemetry = Action(system), MissionRaw(system), Telemetry(system)
        # the EKF needs about a second of simulated time to align before arming is possible
        assert wait_until(lambda: _try(action.arm), 60, period_s=1.0), "could not arm"
        action.set_takeoff_altitude(ALT_M)
        action.takeoff()
        assert wait_until(lambda: telemetry.position().relative_altitude_m > ALT_M - 1.0), \
            "takeoff never reached its altitude"

        items = [RawItem(seq=0, frame=0, command=16, current=1, autocontinue=1,
                         x=0, y=0, z=0.0, mission_type=0)]                       # home
        items.append(RawItem(seq=1, frame=2, command=178, autocontinue=1, param1=1.0,
                             param2=8.0, param3=-1.0, mission_type=0))          # 8 m/s
        for x, y in WAYPOINTS_ENU:
            lat, lon = enu_to_latlon(x, y)
            items.append(RawItem(seq=len(items), frame=6, command=16, autocontinue=1,
                                 x=int(round(lat * 1e7)), y=int(round(lon * 1e7)), z=ALT_M,
                                 mission_type=0))
        mission.upload_mission(items)
        mission.start_mission()
        assert wait_until(mission.is_mission_finished), "mission never finished"
        progress = mission.mission_progress()
        assert progress.current == progress.total

        action.land()
        assert wait_until(lambda: not telemetry.armed()), "never disarmed after landing"
    finally:
        if sdk is not None:
            sdk.destroy()
        sitl.stop()

    end = final_position(sitl.truth())
    last = WAYPOINTS_ENU[-1]
    assert math.hypot(end[0] - last[0], end[1] - last[1]) < 2.0, f"landed at {end}, not at {last}"
    assert end[2] < 0.5
    events = sitl.events()
    assert [f"Reached command #{i}" in events for i in (2, 3, 4)] == [True] * 3


def _params(tmp_path):
    path = tmp_path / "params.json"
    path.write_text('{"LAND_SPEED": 100, "WPNAV_SPEED_DN": 250, "DISARM_DELAY": 30}\n')
    return path


def _try(fn) -> bool:
    from mavsdk.plugins.action import ActionError
    try:
        fn()
        return True
    except ActionError:
        time.sleep(0.2)
        return False
