"""Real ground-station clients against the real MAVLink server (a FakeVehicle behind it, so every
call the server makes into the vehicle is visible): what QGC, MAVProxy and MAVSDK users meet first.

* MAVProxy loads the parameters by MAVFTP (``@PARAM/param.pck?withdefaults=1``) as it does from
  ArduPilot, shows one and sets one by PARAM_SET.
* MAVSDK's Geofence plugin uploads a polygon and a circle as mission_type FENCE.
* MAVProxy ``guided LAT LON ALT`` (DO_REPOSITION with p4 = 0) and MAVSDK ``goto_location`` (its
  yaw in p4) reposition without a yaw or a speed: ArduCopter ignores both.
"""

from __future__ import annotations

import math

import pytest
from support.fake_vehicle import running_server
from support.lineproc import MavproxyProcess, wait_until

from autopilot_bridge.modes import CopterMode
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.vehicle_interface import AltFrame

LAT, LON = 47.3980, 8.5450


def repositions(vehicle) -> list[tuple]:
    return [args for name, args in vehicle.calls if name == "reposition"]


def test_mavproxy_fetches_parameters_by_ftp_and_guided_ignores_yaw(tmp_path):
    params = ParameterStore(PARAM_SPECS)
    assert params.set("RTL_ALT", 2500).ok
    with running_server(params=params) as (server, vehicle):
        mp = MavproxyProcess(server.tcp_port, tmp_path, timeout_s=60)
        try:
            mp.expect(f"Received {params.count} parameters (ftp)")
            mark = mp.send("param show RTL_ALT")
            line = mp.expect("RTL_ALT", mark)
            assert "2500" in mp.lines[line], mp.lines[line]
            mp.send("param set WPNAV_SPEED 750")
            assert wait_until(lambda: params.get("WPNAV_SPEED") == 750.0, 30)

            mp.send(f"guided {LAT} {LON} 30")
            assert wait_until(lambda: repositions(vehicle), 30), mp.tail()
            lat, lon, alt, frame, speed, yaw = repositions(vehicle)[-1]
            assert (round(lat, 4), round(lon, 4), alt) == (LAT, LON, 30.0)
            assert frame == AltFrame.RELATIVE_HOME and vehicle.mode == CopterMode.GUIDED
            assert speed is None and yaw is None        # p1 -1 and p4 0 ignored, as ArduCopter
        finally:
            mp.close()


def test_mavsdk_goto_location_repositions_without_a_yaw():
    mavsdk = pytest.importorskip("mavsdk")
    from mavsdk.plugins.action import Action

    with running_server() as (server, vehicle):
        vehicle.mode = CopterMode.GUIDED
        sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION))
        try:
            assert sdk.add_any_connection(f"tcpout://127.0.0.1:{server.tcp_port}") == \
                mavsdk.ConnectionResult.SUCCESS
            system = sdk.first_autopilot(30.0)
            assert system is not None
            Action(system).goto_location(LAT, LON, 520.0, 90.0)
            assert wait_until(lambda: repositions(vehicle), 30)
            lat, lon, alt, frame, speed, yaw = repositions(vehicle)[-1]
            assert (round(lat, 4), round(lon, 4)) == (LAT, LON)
            assert math.isclose(alt, 520.0, abs_tol=0.01) and frame == AltFrame.AMSL
            assert speed is None and yaw is None        # MAVSDK's 90 (deg) not applied
        finally:
            sdk.destroy()


def test_mavsdk_geofence_upload_reaches_the_vehicle_as_a_fence():
    """MAVSDK's Geofence plugin uploads mission_type FENCE (AUTOPILOT_VERSION claims
    MISSION_FENCE); the vehicle gets the inclusion polygon and the exclusion circle."""
    mavsdk = pytest.importorskip("mavsdk")
    from mavsdk.plugins.geofence import Circle, FenceType, Geofence, GeofenceData, Point, Polygon

    from autopilot_bridge.geofence import FenceCommand

    with running_server() as (server, vehicle):
        sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION))
        try:
            assert sdk.add_any_connection(f"tcpout://127.0.0.1:{server.tcp_port}") == \
                mavsdk.ConnectionResult.SUCCESS
            system = sdk.first_autopilot(30.0)
            assert system is not None
            square = [Point(LAT, LON), Point(LAT, LON + 0.002), Point(LAT + 0.002, LON + 0.002),
                      Point(LAT + 0.002, LON)]
            data = GeofenceData([Polygon(square, FenceType.INCLUSION)],
                                [Circle(Point(LAT + 0.001, LON + 0.001), 20.0, FenceType.EXCLUSION)])
            Geofence(system).upload_geofence(data)
            fences = [args[0] for name, args in vehicle.calls if name == "fence_changed"]
            assert fences, "no fence reached the vehicle"
            items = fences[-1]
            assert [i.command for i in items] == [FenceCommand.POLYGON_VERTEX_INCLUSION] * 4 + [
                FenceCommand.CIRCLE_EXCLUSION]
            assert all(int(i.param1) == 4 for i in items[:4]) and items[4].param1 == 20.0
            assert round(items[2].lat_deg, 4) == round(LAT + 0.002, 4)
        finally:
            sdk.destroy()
