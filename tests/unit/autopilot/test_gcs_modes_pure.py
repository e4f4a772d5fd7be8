"""The pure parts of the ground-station modes and pilot input: RC scaling (ArduCopter's
pwm_to_angle_dz / pwm_to_range_dz, climb rate, throttle curve), override semantics, CIRCLE's
geometry and rate limit, SmartRTL's path, RTL's return height, and AP_Mission's command
sequencing (DO_JUMP) on a flight core without a simulator. Small hand-checked cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.nav import nav_state

from autopilot_bridge.auto_mission import is_nav_command, spline_samples
from autopilot_bridge.circle import Circle, CircleSettings, centre_ahead
from autopilot_bridge.config import GuidanceConfig
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.guidance_law import rtl_return_height_m
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.rc_input import (
    ChannelCalibration,
    PilotSticks,
    RcOverrides,
    climb_rate_m_s,
    lean_angles_rad,
    read_sticks,
    stabilize_throttle,
)
from autopilot_bridge.smart_rtl import BreadcrumbPath, simplify
from autopilot_bridge.vehicle_interface import MavFrame, MissionCommand, MissionItem

CAL = ChannelCalibration(1000, 1500, 2000, False, 20)
THR = ChannelCalibration(1000, 1500, 2000, False, 30)


def test_channel_scaling_with_dead_zones():
    assert CAL.angle(1510) == 0.0 and CAL.angle(1490) == 0.0          # inside the dead zone
    assert CAL.angle(2000) == 1.0 and CAL.angle(1000) == -1.0
    assert CAL.angle(1760) == pytest.approx(240 / 480)
    assert ChannelCalibration(1000, 1500, 2000, True, 20).angle(1760) == pytest.approx(-0.5)
    assert THR.range(1030) == 0.0 and THR.range(900) == 0.0 and THR.range(2000) == 1.0
    assert THR.range(1515) == pytest.approx(0.5)


def test_climb_rate_and_throttle_curve():
    mid = PilotSticks(0.0, 0.0, 0.0, 0.5)
    assert climb_rate_m_s(mid, 0.1, 2.5, 1.5) == 0.0
    assert climb_rate_m_s(PilotSticks(0, 0, 0, 1.0), 0.1, 2.5, 1.5) == pytest.approx(2.5)
    assert climb_rate_m_s(PilotSticks(0, 0, 0, 0.0), 0.1, 2.5, 1.5) == pytest.approx(-1.5)
    assert climb_rate_m_s(PilotSticks(0, 0, 0, 0.8), 0.1, 2.5, 1.5) == pytest.approx(2.5 * 0.2 / 0.4)
    # mid stick is the hover throttle, the ends are 0 and 1
    for hover in (0.3, 0.39, 0.5, 0.6):
        assert stabilize_throttle(mid, hover) == pytest.approx(hover)
        assert stabilize_throttle(PilotSticks(0, 0, 0, 1.0), hover) == pytest.approx(1.0)
        assert stabilize_throttle(PilotSticks(0, 0, 0, 0.0), hover) == pytest.approx(0.0)
    # circular lean limit
    roll, pitch = lean_angles_rad(PilotSticks(1.0, 1.0, 0.0, 0.5), math.radians(30))
    assert math.hypot(roll, pitch) == pytest.approx(math.radians(30)) and roll == pytest.approx(pitch)


def test_override_semantics():
    rc = RcOverrides()
    rc.rc_channels_override((1600, 0, 1200, 65535) + (65535,) * 4 + (0,) * 8 + (1300, 65535), 1.0)
    assert [rc.pwm(c) for c in (1, 2, 3, 4, 17, 18)] == [1600, 0, 1200, 0, 1300, 0]
    rc.rc_channels_override((65535, 1400, 65535, 0) + (65535,) * 4 + (0,) * 8 + (65534, 0), 2.0)
    assert [rc.pwm(c) for c in (1, 2, 3, 4, 17)] == [1600, 1400, 1200, 0, 0]   # 65534 releases 17
    assert rc.active(4.9, 3.0) and not rc.active(5.0, 3.0)
    assert rc.active(1000.0, -1.0) and not rc.active(2.0, 0.0)
    sticks = read_sticks(rc, (1, 2, 3, 4), lambda ch: THR if ch == 3 else CAL)
    assert sticks is not None and sticks.yaw == 0.0 and sticks.roll > 0 and sticks.pitch < 0
    only_throttle = RcOverrides()
    only_throttle.rc_channels_override((0, 0, 1500, 0, 0, 0, 0, 0), 0.0)
    s = read_sticks(only_throttle, (1, 2, 3, 4), lambda ch: THR if ch == 3 else CAL)
    assert s is not None and s.centred and climb_rate_m_s(s, 0.1, 2.5, 1.5) == 0.0
    assert read_sticks(RcOverrides(), (1, 2, 3, 4), lambda ch: CAL) is None
    mc = RcOverrides()
    mc.manual_control(1000, -500, 250, 32767, (1, 2, 3, 4), 0.0)   # r unused
    assert [mc.pwm(c) for c in (1, 2, 3, 4)] == [1250, 1000, 1250, 0]   # pitch forward = low PWM


def test_circle_centre_ahead_and_rate_limit():
    cfg = GuidanceConfig()
    assert centre_ahead((0.0, 0.0, 5.0), math.pi / 2, 10.0) == pytest.approx((10.0, 0.0))
    circle = Circle(cfg, (0.0, 10.0), 5.0, CircleSettings(10.0, 20.0), (0.0, 0.0, 5.0))
    assert circle.circling                                    # starts on the edge
    nav = nav_state()
    speeds = []
    for _ in range(2000):
        t = circle.update(nav, 0.01)
        speeds.append(math.hypot(*t.velocity_enu_m_s[:2]))
        assert math.hypot(t.position_enu_m[0], t.position_enu_m[1] - 10.0) == pytest.approx(10.0)
    # v_max = sqrt(0.5 * WPNAV_ACCEL * r) = sqrt(12.5) < 20 deg/s * r = 3.49 m/s
    assert max(speeds) == pytest.approx(min(math.sqrt(0.5 * cfg.wp_accel_m_s2 * 10.0),
                                            math.radians(20) * 10.0), rel=1e-6)
    assert circle.angle_total_rad > 0                         # clockwise
    turns = Circle(cfg, (0.0, 0.0), 5.0, CircleSettings(3.0, -20.0), (0.0, 3.0, 5.0), turns=1.0)
    done = False
    for _ in range(5000):
        turns.update(nav, 0.01)
        done = done or bool(turns.pop_events())
    assert turns.complete and done and turns.angle_total_rad == pytest.approx(-2 * math.pi, abs=0.01)


def test_breadcrumbs_simplify_and_overflow():
    line = [np.array([float(i), 0.0, 10.0]) for i in range(10)]
    assert len(simplify(line, 0.5)) == 2
    corner = line + [np.array([9.0, float(j), 10.0]) for j in range(1, 10)]
    kept = simplify(corner, 0.5)
    assert len(kept) == 3 and np.allclose(kept[1], (9.0, 0.0, 10.0))
    path = BreadcrumbPath()
    path.start((0.0, 0.0, 0.0), 2.0, 5)
    assert path.add((1.0, 0.0, 0.0)) is None and len(path.points) == 1   # within SRTL_ACCURACY
    messages = [path.add((3.0 * i, 3.0 * (i % 2), 10.0)) for i in range(1, 12)]
    assert "SmartRTL deactivated: buffer full" in messages and not path.usable
    path.start((0.0, 0.0, 0.0), 2.0, 300)
    for p in ((0, 0, 10), (20, 0, 10), (20, 20, 10)):
        path.add(p)
    back = path.route_home((20.0, 20.0, 10.0))
    assert np.allclose(back[0], (20, 0, 10)) and np.allclose(back[-1], (0, 0, 2.0))   # home + 2 m


def test_rtl_return_height_cone_and_climb_min():
    cfg = GuidanceConfig(rtl_alt_m=15.0, rtl_cone_slope=3.0, rtl_climb_min_m=0.0)
    assert rtl_return_height_m(cfg, 5.0, 100.0) == 15.0          # far: RTL_ALT
    assert rtl_return_height_m(cfg, 5.0, 3.0) == pytest.approx(9.0)   # near: the cone
    assert rtl_return_height_m(cfg, 5.0, 0.5) == 5.0             # never lower than now
    assert rtl_return_height_m(cfg, 20.0, 100.0) == 20.0         # above RTL_ALT: stays there
    climb = GuidanceConfig(rtl_alt_m=15.0, rtl_cone_slope=3.0, rtl_climb_min_m=4.0)
    assert rtl_return_height_m(climb, 20.0, 100.0) == 24.0
    no_cone = GuidanceConfig(rtl_alt_m=15.0, rtl_cone_slope=0.0)
    assert rtl_return_height_m(no_cone, 5.0, 1.0) == 15.0


def _item(seq, command, p1=0.0, p2=0.0):
    return MissionItem(seq=seq, command=int(command), frame=int(MavFrame.GLOBAL_RELATIVE_ALT),
                       param1=p1, param2=p2)


def test_do_jump_sequencing_as_ap_mission():
    assert is_nav_command(MissionCommand.NAV_DELAY) and is_nav_command(MissionCommand.NAV_SCRIPT_TIME)
    assert not is_nav_command(MissionCommand.CONDITION_DELAY)
    core = FlightCore(ParameterStore(PARAM_SPECS))
    wp, jump = MissionCommand.NAV_WAYPOINT, MissionCommand.DO_JUMP
    core.mission_changed((_item(1, wp), _item(2, wp), _item(3, jump, 1, 2), _item(4, wp),
                          _item(5, jump, 9, 1), _item(6, jump, 4, -1)))
    follow = [core._next_command(2, increment_jumps=True) for _ in range(3)]
    assert follow == [0, 0, 3]                                  # twice to item 1, then on
    texts = [t for _, t in core.drain_texts()]
    assert "Mission: 3 Jump 1/2" in texts and "Mission: 3 Jump 2/2" in texts
    assert core._next_command(4, increment_jumps=True) is None  # a target outside the mission
    assert core._next_command(5, increment_jumps=False) == 3    # for ever, uncounted
    core.close()


def test_spline_leg_is_a_smooth_curve_through_the_waypoints():
    pts = [np.array(p, dtype=float) for p in ((0, 0, 5), (0, 10, 5), (10, 10, 5), (10, 20, 5))]
    leg = np.array(spline_samples(pts, 2))                       # into (10, 10)
    assert len(leg) == 4                                         # 10 m chord: 2 m apart
    # an S between the two corners: it leaves (0, 10) and enters (10, 10) heading north-east
    assert leg[0][1] > 10.0 and leg[-1][1] < 10.0
    assert np.all(np.diff(leg[:, 0]) > 0) and np.allclose(leg[:, 2], 5.0)
    # joins the next spline leg without a corner: equal tangents at the shared waypoint (finely
    # sampled: 100 m legs)
    big = [p * np.array([10.0, 10.0, 1.0]) for p in pts]
    into = (big[2] - np.array(spline_samples(big, 2))[-1])[:2]
    out = (np.array(spline_samples(big, 3))[0] - big[2])[:2]
    cos = float(into @ out / np.linalg.norm(into) / np.linalg.norm(out))
    assert cos > 0.95
    assert spline_samples(pts[:2] + [np.array((0.0, 11.0, 5.0))], 2) == []   # too short to bend


def test_do_set_home_in_a_mission_here_or_at_the_location():
    core = FlightCore(ParameterStore(PARAM_SPECS))
    core._home = np.zeros(3)
    lat, lon = core.geo.to_geodetic(10.0, 20.0)
    at = MissionItem(seq=1, command=int(MissionCommand.DO_SET_HOME),
                     frame=int(MavFrame.GLOBAL_RELATIVE_ALT), lat_e7=round(lat * 1e7),
                     lon_e7=round(lon * 1e7), alt_m=5.0)
    core._start_do(at, nav_state(position=(3.0, 4.0, 12.0)))
    assert np.allclose(core.home_enu_m, (10.0, 20.0, 5.0), atol=0.02)
    here = MissionItem(seq=1, command=int(MissionCommand.DO_SET_HOME),
                       frame=int(MavFrame.GLOBAL_RELATIVE_ALT), param1=1.0)
    core._start_do(here, nav_state(position=(3.0, 4.0, 12.0)))
    assert np.allclose(core.home_enu_m, (3.0, 4.0, 12.0))
    core.close()
