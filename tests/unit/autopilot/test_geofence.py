"""Geofence and rally rules (autopilot_bridge.geofence), as ArduCopter's AC_Fence / AP_Rally."""

from __future__ import annotations

import pytest

from autopilot_bridge.failsafe import FailsafeAction, FailsafeKind
from autopilot_bridge.geofence import (
    FenceCommand,
    FenceGeometry,
    FenceMonitor,
    FenceSettings,
    FenceType,
    breaches,
    parse_fence,
    rally_or_home,
)
from autopilot_bridge.vehicle_interface import MavFrame, MissionItem

DEG_PER_M = 1e-5      # test frame: lat/lon degrees = metres * 1e-5 (to_local below inverts it)


def to_local(lat: float, lon: float) -> tuple[float, float]:
    return lon / DEG_PER_M, lat / DEG_PER_M


def item(seq, command, x_m, y_m, param1=0.0):
    return MissionItem(seq=seq, command=int(command), frame=int(MavFrame.GLOBAL), param1=param1,
                       lat_e7=round(y_m * DEG_PER_M * 1e7), lon_e7=round(x_m * DEG_PER_M * 1e7))


SQUARE = [item(i, FenceCommand.POLYGON_VERTEX_INCLUSION, x, y, 4)
          for i, (x, y) in enumerate([(-50, -50), (50, -50), (50, 50), (-50, 50)])]
HOLE = [item(4, FenceCommand.CIRCLE_EXCLUSION, 20, 0, 10.0)]
HOME = (0.0, 0.0, 0.0)


def test_parse_polygons_and_circles_and_refuse_incomplete_polygon():
    geometry, reason = parse_fence(SQUARE + HOLE, to_local)
    assert reason == "" and geometry is not None
    assert len(geometry.polygons) == 1 and geometry.polygons[0].inclusion
    assert geometry.polygons[0].vertices_xy_m[1] == pytest.approx((50.0, -50.0))
    assert geometry.circles[0].radius_m == 10.0 and not geometry.circles[0].inclusion
    assert parse_fence(SQUARE[:3], to_local)[0] is None
    assert parse_fence([item(0, FenceCommand.CIRCLE_INCLUSION, 0, 0, 0.0)], to_local)[0] is None


def test_breach_types():
    geometry, _ = parse_fence(SQUARE + HOLE, to_local)
    s = FenceSettings(enabled=True, types=FenceType.ALT_MAX | FenceType.CIRCLE | FenceType.POLYGON,
                      alt_max_m=30.0, radius_m=150.0)
    assert breaches(s, geometry, (0.0, 0.0, 10.0), HOME, False)[0] == FenceType.NONE
    found, distance = breaches(s, geometry, (60.0, 0.0, 10.0), HOME, False)
    assert found == FenceType.POLYGON and distance == pytest.approx(10.0)
    assert breaches(s, geometry, (22.0, 0.0, 10.0), HOME, False)[0] == FenceType.POLYGON   # hole
    assert breaches(s, geometry, (0.0, 0.0, 31.0), HOME, False)[0] == FenceType.ALT_MAX
    assert breaches(s, FenceGeometry(), (160.0, 0.0, 5.0), HOME, False)[0] == FenceType.CIRCLE
    low = FenceSettings(enabled=True, types=FenceType.ALT_MIN, alt_min_m=5.0)
    assert breaches(low, geometry, (0.0, 0.0, 2.0), HOME, False)[0] == FenceType.ALT_MIN
    assert breaches(low, geometry, (0.0, 0.0, 2.0), HOME, True)[0] == FenceType.NONE     # landing


def test_monitor_action_give_up_distance_and_clear():
    s = FenceSettings(enabled=True, types=FenceType.CIRCLE, radius_m=100.0, action=1)
    m = FenceMonitor()
    assert m.update(0.0, True, True, False, False, (90.0, 0.0, 10.0), HOME, s) == []
    events = m.update(0.1, True, True, False, False, (101.0, 0.0, 10.0), HOME, s)
    assert [(e.kind, e.action, e.text) for e in events] == [
        (FailsafeKind.FENCE, FailsafeAction.RTL, "Fence Breached")]
    assert m.update(0.2, True, True, False, False, (102.0, 0.0, 10.0), HOME, s) == []  # not new
    events = m.update(0.3, True, True, False, False, (99.0, 0.0, 10.0), HOME, s)
    assert [e.action for e in events] == [FailsafeAction.CLEARED]
    far = FenceMonitor().update(0.0, True, True, False, False, (250.0, 0.0, 10.0), HOME, s)
    assert [e.action for e in far] == [FailsafeAction.LAND]                   # > 100 m outside
    for action, expected in [(0, FailsafeAction.REPORT), (2, FailsafeAction.LAND),
                             (4, FailsafeAction.BRAKE), (5, FailsafeAction.LAND)]:
        s2 = FenceSettings(enabled=True, types=FenceType.CIRCLE, radius_m=100.0, action=action)
        ev = FenceMonitor().update(0.0, True, True, False, False, (120.0, 0.0, 5.0), HOME, s2)
        assert [e.action for e in ev] == [expected], action
    grounded = FenceMonitor().update(0.0, True, False, False, False, (120.0, 0.0, 0.0), HOME, s)
    assert grounded == []
    disabled = FenceSettings(enabled=False, types=FenceType.CIRCLE, radius_m=100.0)
    assert FenceMonitor().update(0.0, True, True, False, False, (500.0, 0, 5), HOME, disabled) == []


def test_rally_or_home_as_ap_rally():
    points = [(200.0, 0.0, 20.0), (0.0, 300.0, 20.0)]
    assert list(rally_or_home(points, (150.0, 0.0, 10.0), HOME, 0.3, True)) == [200.0, 0.0, 0.0]
    assert list(rally_or_home(points, (40.0, 0.0, 10.0), HOME, 0.3, True)) == [0.0, 0.0, 0.0]
    assert list(rally_or_home(points, (40.0, 0.0, 10.0), HOME, 0.3, False)) == [200.0, 0.0, 0.0]
    # nearest point beyond RALLY_LIMIT_KM and home nearer -> home
    assert list(rally_or_home([(900.0, 0.0, 20.0)], (300.0, 0.0, 10.0), HOME, 0.3, False)) == [0, 0, 0]
    assert list(rally_or_home([], (300.0, 0.0, 10.0), HOME, 0.3, True)) == [0, 0, 0]


def test_do_fence_enable_switches_fences_at_run_time_as_gcs_fence():
    """MAV_CMD_DO_FENCE_ENABLE on a flight core: on/off over FENCE_ENABLE without storing it, the
    floor alone, a type mask, ENABLE refused with nothing present, unknown actions refused; the
    mission item does the same."""
    from support.nav import nav_state

    from autopilot_bridge.flight_core import FlightCore
    from autopilot_bridge.param_specs import PARAM_SPECS
    from autopilot_bridge.params import ParameterStore
    from autopilot_bridge.vehicle_interface import MissionCommand

    core = FlightCore(ParameterStore(PARAM_SPECS))
    core.params.set("FENCE_TYPE", 15.0)
    assert not core.fence_settings().enabled                     # FENCE_ENABLE 0
    assert core.fence_enable(1, 0).ok
    s = core.fence_settings()
    # every FENCE_TYPE fence on; the stored parameter untouched
    assert s.enabled and s.types == FenceType(15)
    assert core.params.get_int("FENCE_ENABLE") == 0
    assert core.fence_enable(2, 0).ok                            # the floor only
    assert core.fence_settings().types == FenceType.ALT_MAX | FenceType.CIRCLE | FenceType.POLYGON
    assert core.fence_enable(0, int(FenceType.CIRCLE)).ok        # one type by mask
    assert core.fence_settings().types == FenceType.ALT_MAX | FenceType.POLYGON
    assert core.fence_enable(0, 0).ok
    assert not core.fence_settings().enabled
    bad = core.fence_enable(3, 0)
    assert not bad.ok and "unknown" in bad.reason
    # ENABLE needs a fence present: a polygon only once one is uploaded
    core.params.set("FENCE_TYPE", float(FenceType.POLYGON))
    assert not core.fence_enable(1, int(FenceType.POLYGON)).ok
    core.fence_changed(tuple(SQUARE))
    assert core.fence_enable(1, int(FenceType.POLYGON)).ok and core.fence_settings().enabled
    texts = [t for _, t in core.drain_texts()]
    assert "Fence enabled" in texts and "Fence disabled" in texts
    # SYS_STATUS GEOFENCE bits as AC_Fence sys_status_*: present, enabled (not with FENCE_ACTION 0,
    # report only), healthy while not breached
    from autopilot_bridge.vehicle_interface import SensorFlag
    present, enabled, health = core._sensor_flags(False)
    assert present & enabled & health & SensorFlag.GEOFENCE
    core.fence._breaches = FenceType.POLYGON                    # as FenceMonitor.update sets it
    assert not core._sensor_flags(False)[2] & SensorFlag.GEOFENCE
    core.fence._breaches = FenceType.NONE
    core.params.set("FENCE_ACTION", 0.0)
    assert not core._sensor_flags(False)[1] & SensorFlag.GEOFENCE
    core.params.set("FENCE_TYPE", 0.0)
    present, enabled, health = core._sensor_flags(False)
    assert not present & SensorFlag.GEOFENCE and health & SensorFlag.GEOFENCE
    # the mission item
    off = MissionItem(seq=1, command=int(MissionCommand.DO_FENCE_ENABLE), frame=int(MavFrame.MISSION),
                      param1=0.0)
    core._start_do(off, nav_state(position=(0.0, 0.0, 10.0)))
    assert not core.fence_settings().enabled
    core.close()
