"""MAVSDK-Python (4.x, the embedded C library) as its users fly ArduPilot, against
``scenenav sitl --lockstep`` (one flight; the simulator waits for the autopilot, MAVSDK's timers run
on the wall clock): every ``Telemetry.set_rate_*`` of a message ArduCopter has succeeds (the others
are DENIED as ArduCopter answers them), the Geofence plugin uploads a polygon and a circle that the
autopilot serves back as mission_type FENCE, ``goto_location`` flies there facing the target
(WP_YAW_BEHAVIOR), not its yaw (ArduCopter ignores DO_REPOSITION's param4), ``hold`` stops the vehicle, ``return_to_launch`` lands
it at home (truth.csv)."""

from __future__ import annotations

import math
import time

import pytest
from support.sitl_session import (
    TIMEOUT_S,
    SitlSession,
    enu_to_latlon,
    final_position,
    monitor_connection,
    wait_until,
    write_params,
)

# set_rate_* whose message ArduCopter 4.5 has no ap_message for: DENIED there too
NOT_ARDUPILOT = {"set_rate_altitude", "set_rate_odometry", "set_rate_imu", "set_rate_ground_truth",
                 "set_rate_actuator_control_target", "set_rate_actuator_output_status"}
ALT_M = 20.0
PARAMS = {"RTL_LOIT_TIME": 0, "LAND_SPEED": 200, "WPNAV_SPEED_DN": 300, "DISARM_DELAY": 30}


def _try(fn) -> bool:
    from mavsdk.plugins.action import ActionError
    try:
        fn()
        return True
    except ActionError:
        time.sleep(0.2)
        return False


def test_mavsdk_rates_geofence_goto_hold_and_return_to_launch(tmp_path):
    mavsdk = pytest.importorskip("mavsdk")
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.geofence import Circle, FenceType, Geofence, GeofenceData, Point, Polygon
    from mavsdk.plugins.telemetry import FlightMode, Telemetry, TelemetryError
    from support.fake_vehicle import wait_for

    sitl = SitlSession(tmp_path, "--lockstep", "--perception", "off",
                       "--set", "autopilot.params_file=" + write_params(tmp_path, **PARAMS))
    sdk = monitor = None
    try:
        sitl.wait_ready()
        sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION))
        assert sdk.add_any_connection(f"tcpout://127.0.0.1:{sitl.port}") == \
            mavsdk.ConnectionResult.SUCCESS
        system = sdk.first_autopilot(TIMEOUT_S)
        assert system is not None
        action, telemetry = Action(system), Telemetry(system)

        failed = {}
        for name in sorted(m for m in dir(Telemetry) if m.startswith("set_rate_") and not m.endswith("_async")):
            try:
                getattr(telemetry, name)(2.0)
            except TelemetryError as exc:
                failed[name] = str(exc).split(";")[0]
        assert set(failed) == NOT_ARDUPILOT, failed
        assert set(failed.values()) == {"COMMAND_DENIED"}

        lat0, lon0 = enu_to_latlon(0.0, 0.0)
        d = 0.0008
        square = [Point(lat0 - d, lon0 - d), Point(lat0 - d, lon0 + d), Point(lat0 + d, lon0 + d),
                  Point(lat0 + d, lon0 - d)]
        Geofence(system).upload_geofence(GeofenceData(
            [Polygon(square, FenceType.INCLUSION)],
            [Circle(Point(lat0 + d / 2, lon0 - d / 2), 10.0, FenceType.EXCLUSION)]))
        monitor = monitor_connection(sitl.port)
        monitor.mav.mission_request_list_send(1, 1, 1)
        count = wait_for(monitor, "MISSION_COUNT", 10, lambda m: m.mission_type == 1)
        assert count is not None and count.count == 5                 # 4 vertices + the circle

        assert wait_until(lambda: _try(action.arm), 60, period_s=1.0), "could not arm"
        action.set_takeoff_altitude(ALT_M)
        action.takeoff()
        assert wait_until(lambda: telemetry.position().relative_altitude_m > ALT_M - 1.0, 60), \
            "takeoff never reached its altitude"
        east, north = 25.0, -20.0
        bearing = math.degrees(math.atan2(east, north)) % 360.0      # WP_YAW_BEHAVIOR 2: face it
        lat, lon = enu_to_latlon(east, north)
        amsl = telemetry.position().absolute_altitude_m
        action.goto_location(lat, lon, amsl, (bearing + 90.0) % 360.0)      # a yaw 90 deg off
        assert wait_until(lambda: _dist_m(telemetry.position(), lat, lon) < 3.0, 60), "goto never got there"
        off = abs((telemetry.heading().heading_deg - bearing + 180.0) % 360.0 - 180.0)
        assert off < 20.0, f"heading {off:.0f} deg off the bearing to the target: the goto's yaw was applied?"

        action.hold()
        assert wait_until(lambda: math.hypot(telemetry.velocity_ned().north_m_s,
                                             telemetry.velocity_ned().east_m_s) < 0.3, 30), "hold did not stop"
        assert FlightMode(telemetry.flight_mode()) == FlightMode.HOLD
        hb = wait_for(monitor, "HEARTBEAT", 10, lambda h: h.get_srcComponent() == 1 and h.custom_mode in (5, 16, 17))
        assert hb is not None, "hold is not LOITER / POSHOLD / BRAKE"
        action.return_to_launch()
        assert wait_until(lambda: not telemetry.armed(), 120), "never disarmed after the RTL"
    finally:
        if monitor is not None:
            monitor.close()
        if sdk is not None:
            sdk.destroy()
        sitl.stop()

    end = final_position(sitl.truth())
    assert math.hypot(end[0], end[1]) < 2.0, f"landed {end} m from home (0, 0)"


def _dist_m(pos, lat: float, lon: float) -> float:
    dn = (pos.latitude_deg - lat) * 111_320.0
    de = (pos.longitude_deg - lon) * 111_320.0 * math.cos(math.radians(lat))
    return math.hypot(dn, de)
