"""Failsafes: the pure state machines (autopilot_bridge.failsafe), then end to end on ``scenenav sitl``.

* GCS heartbeat loss with FS_GCS_ENABLE = 1: STATUSTEXT, RTL, landing at home (truth.csv).
* Vision loss in GPS-denied flight (the perception node is stopped while the vehicle hovers at
  45 m): STATUSTEXT "holding", then "Land", LAND, disarmed; all of it also on the bus (events.csv).
"""

from __future__ import annotations

import math
import os
import signal

import pytest
from support.sitl_session import SitlSession, final_position

from autopilot_bridge.failsafe import (
    FailsafeAction,
    FailsafeInputs,
    FailsafeKind,
    FailsafeMonitor,
    FailsafeSettings,
    VisionFailsafeState,
    gcs_action_of,
)


# ------------------------------------------------------------------------------ pure
def inputs(now: float, **kw) -> FailsafeInputs:
    base = dict(now_s=now, armed=True, flying=True, position_mode=True, landing=False,
                gcs_last_heartbeat_s=None, vision_required=False, vision_height_ok=True,
                last_vision_fix_s=None)
    base.update(kw)
    return FailsafeInputs(**base)


def test_fs_gcs_enable_values_follow_arducopter():
    assert gcs_action_of(0) is None
    assert gcs_action_of(1) == FailsafeAction.RTL
    assert gcs_action_of(3) == FailsafeAction.RTL      # SmartRTL or RTL: no SmartRTL here
    assert gcs_action_of(4) == FailsafeAction.LAND     # SmartRTL or Land
    assert gcs_action_of(5) == FailsafeAction.LAND
    assert gcs_action_of(7) is None


def test_gcs_failsafe_needs_a_seen_gcs_and_flight_and_clears():
    fs = FailsafeMonitor()
    s = FailsafeSettings(gcs_action=1, gcs_timeout_s=5.0, vision_timeout_s=0.0)
    assert fs.update(inputs(100.0), s) == []                                  # no GCS ever seen
    assert fs.update(inputs(100.0, gcs_last_heartbeat_s=90.0, flying=False), s) == []  # on ground
    ev = fs.update(inputs(100.0, gcs_last_heartbeat_s=94.0), s)
    assert [(e.kind, e.action) for e in ev] == [(FailsafeKind.GCS, FailsafeAction.RTL)]
    assert "GCS Failsafe" in ev[0].text and fs.gcs_active
    assert fs.update(inputs(101.0, gcs_last_heartbeat_s=94.0), s) == []       # announced once
    ev = fs.update(inputs(102.0, gcs_last_heartbeat_s=101.9), s)
    assert [e.action for e in ev] == [FailsafeAction.CLEARED] and not fs.gcs_active
    assert fs.update(inputs(103.0, gcs_last_heartbeat_s=90.0),
                     FailsafeSettings(gcs_action=0)) == []                    # disabled
    ev = fs.update(inputs(200.0, gcs_last_heartbeat_s=150.0), FailsafeSettings(gcs_action=5))
    assert [e.action for e in ev] == [FailsafeAction.LAND]
    fs.update(inputs(201.0, armed=False), s)
    assert not fs.any_active


def test_vision_failsafe_ignores_the_take_off_climb_above_the_height():
    """A take-off climb (AUTO NAV_TAKEOFF, GUIDED takeoff) above SN_VIS_MIN_ALT without fixes does
    not trip it (perception may rate captures only from higher up); the clock starts when it ends."""
    fs = FailsafeMonitor()
    s = FailsafeSettings(vision_timeout_s=2.0, vision_land_after_s=3.0)
    for t in range(0, 20):
        assert fs.update(inputs(float(t), vision_required=True, taking_off=True), s) == []
    assert fs.update(inputs(20.0, vision_required=True), s) == []
    ev = fs.update(inputs(22.5, vision_required=True), s)
    assert [e.action for e in ev] == [FailsafeAction.HOLD]


def test_vision_failsafe_holds_then_lands_and_ignores_the_climb():
    fs = FailsafeMonitor()
    s = FailsafeSettings(vision_timeout_s=2.0, vision_land_after_s=3.0)
    # take-off climb below the scene-matching height: never trips, however long
    for t in range(0, 20):
        assert fs.update(inputs(float(t), vision_required=True, vision_height_ok=False), s) == []
    # high enough from t=20 s, no fix yet: the clock starts now
    assert fs.update(inputs(20.0, vision_required=True), s) == []
    assert fs.update(inputs(22.0, vision_required=True), s) == []
    ev = fs.update(inputs(22.5, vision_required=True), s)
    assert [e.action for e in ev] == [FailsafeAction.HOLD]
    assert fs.vision_state == VisionFailsafeState.HOLD
    ev = fs.update(inputs(23.0, vision_required=True, last_vision_fix_s=22.9), s)
    assert [e.action for e in ev] == [FailsafeAction.RESUME]
    assert fs.update(inputs(24.0, vision_required=True, last_vision_fix_s=23.9), s) == []
    ev = fs.update(inputs(26.5, vision_required=True, last_vision_fix_s=24.0), s)
    assert [e.action for e in ev] == [FailsafeAction.HOLD]
    assert fs.update(inputs(29.0, vision_required=True, last_vision_fix_s=24.0), s) == []
    ev = fs.update(inputs(29.6, vision_required=True, last_vision_fix_s=24.0), s)
    assert [e.action for e in ev] == [FailsafeAction.LAND] and "Land" in ev[0].text
    assert fs.update(inputs(40.0, vision_required=True, last_vision_fix_s=24.0), s) == []


def test_vision_failsafe_off_with_gps_landing_or_zero_timeout():
    s = FailsafeSettings(vision_timeout_s=2.0, vision_land_after_s=3.0)
    for kw in (dict(vision_required=False), dict(vision_required=True, landing=True),
               dict(vision_required=True, position_mode=False)):
        fs = FailsafeMonitor()
        assert all(fs.update(inputs(float(t), **kw), s) == [] for t in range(30))
    fs = FailsafeMonitor()
    off = FailsafeSettings(vision_timeout_s=0.0)
    assert all(fs.update(inputs(float(t), vision_required=True), off) == [] for t in range(30))


def test_vision_failsafe_dead_reckons_on_while_the_estimate_allows():
    """SN_VIS_DR_MAX > 0: past SN_VIS_TIMEOUT the vehicle flies on (announced, no action) while the
    EKF's horizontal 1-sigma stays within it; fixes end it; once the 1-sigma passes it, HOLD, then LAND."""
    fs = FailsafeMonitor()
    s = FailsafeSettings(vision_timeout_s=2.0, vision_land_after_s=3.0, vision_dr_max_m=8.0)
    assert fs.update(inputs(10.0, vision_required=True, last_vision_fix_s=10.0, position_std_m=1.0), s) == []
    ev = fs.update(inputs(12.5, vision_required=True, last_vision_fix_s=10.0, position_std_m=2.0), s)
    assert [e.action for e in ev] == [FailsafeAction.REPORT] and "dead reckoning" in ev[0].text
    assert fs.vision_state == VisionFailsafeState.DEAD_RECKONING and not fs.any_active
    # flying on: nothing more while the uncertainty grows within the bound
    for t in range(13, 20):
        assert fs.update(inputs(float(t), vision_required=True, last_vision_fix_s=10.0,
                                position_std_m=2.0 + 0.5 * (t - 13)), s) == []
    # a fix ends it
    ev = fs.update(inputs(20.0, vision_required=True, last_vision_fix_s=19.9, position_std_m=5.0), s)
    assert [e.action for e in ev] == [FailsafeAction.REPORT] and "ended" in ev[0].text
    assert fs.vision_state == VisionFailsafeState.NORMAL
    # lost again; the 1-sigma passes the bound -> HOLD at once, then LAND
    ev = fs.update(inputs(22.5, vision_required=True, last_vision_fix_s=20.0, position_std_m=7.0), s)
    assert [e.action for e in ev] == [FailsafeAction.REPORT]
    ev = fs.update(inputs(23.0, vision_required=True, last_vision_fix_s=20.0, position_std_m=8.5), s)
    assert [e.action for e in ev] == [FailsafeAction.HOLD] and "8.5m > 8m" in ev[0].text
    assert fs.any_active
    ev = fs.update(inputs(26.5, vision_required=True, last_vision_fix_s=20.0, position_std_m=9.0), s)
    assert [e.action for e in ev] == [FailsafeAction.LAND]


def test_vision_failsafe_holds_at_the_timeout_when_the_estimate_is_already_too_uncertain():
    fs = FailsafeMonitor()
    s = FailsafeSettings(vision_timeout_s=2.0, vision_land_after_s=3.0, vision_dr_max_m=8.0)
    assert fs.update(inputs(10.0, vision_required=True, last_vision_fix_s=10.0, position_std_m=9.0), s) == []
    ev = fs.update(inputs(12.5, vision_required=True, last_vision_fix_s=10.0, position_std_m=9.0), s)
    assert [e.action for e in ev] == [FailsafeAction.HOLD]


def test_dead_reckoning_state_ends_quietly_when_vision_is_no_longer_expected():
    fs = FailsafeMonitor()
    s = FailsafeSettings(vision_timeout_s=2.0, vision_dr_max_m=8.0)
    fs.update(inputs(10.0, vision_required=True, last_vision_fix_s=10.0, position_std_m=1.0), s)
    fs.update(inputs(12.5, vision_required=True, last_vision_fix_s=10.0, position_std_m=1.0), s)
    assert fs.vision_state == VisionFailsafeState.DEAD_RECKONING
    # the landing descent: no longer expected, no event, and no hold however long
    for t in range(13, 40):
        assert fs.update(inputs(float(t), vision_required=True, landing=True, last_vision_fix_s=10.0,
                                position_std_m=20.0), s) == []
    assert fs.vision_state == VisionFailsafeState.NORMAL


# ------------------------------------------------------------------------------ end to end
from support.sitl_session import (  # noqa: F401
    COPTER_GUIDED,
    COPTER_LAND,
    COPTER_RTL,
    MAV_MODE_FLAG_SAFETY_ARMED,
    Gcs,
    arm_in_guided_and_take_off,
    statustext,
    write_params,
)

#: real-time SITL flights: `make test` runs them after the parallel part, apart from it
pytestmark = pytest.mark.realtime


def test_gcs_heartbeat_loss_triggers_rtl(tmp_path):
    params = write_params(tmp_path, FS_GCS_ENABLE=1, FS_GCS_TIMEOUT=10, RTL_LOIT_TIME=0,
                          LAND_SPEED=200, WPNAV_SPEED_DN=300, DISARM_DELAY=30)
    # 2x real time: at 3x a vehicle sharing the CPU with the lockstep tests fell behind the wall
    # clock and touched down 3 m from home
    sitl = SitlSession(tmp_path, "--speedup", "2", "--perception", "off",
                       "--set", f"autopilot.params_file={params}")
    gcs = None
    try:
        sitl.wait_ready()
        gcs = Gcs(sitl.port)
        m = gcs.m
        arm_in_guided_and_take_off(gcs, 15.0)
        # fly 20 m north (LOCAL_NED from the EKF origin), so that RTL has somewhere to return from
        mask = 0b110111111000   # position only
        gcs.send("set_position_target_local_ned_send", 0, 1, 1, m.MAV_FRAME_LOCAL_NED, mask,
                 20.0, 0.0, -15.0, 0, 0, 0, 0, 0, 0, 0, 0)
        assert gcs.wait("LOCAL_POSITION_NED", lambda p: p.x > 18.0, 60, fresh=True) is not None
        gcs.beating.clear()                                  # the ground station goes silent
        text = statustext(gcs, "GCS Failsafe")
        assert text is not None and text.severity <= m.MAV_SEVERITY_CRITICAL
        assert gcs.wait("HEARTBEAT", lambda h: h.custom_mode == COPTER_RTL, 30,
                        fresh=True) is not None
        assert gcs.wait("HEARTBEAT", lambda h: not h.base_mode & MAV_MODE_FLAG_SAFETY_ARMED,
                        120, fresh=True) is not None, "never landed and disarmed"
    finally:
        if gcs is not None:
            gcs.close()
        sitl.stop()
    end = final_position(sitl.truth())
    assert math.hypot(end[0], end[1]) < 2.0, f"RTL landed at {end}, home is (0, 0)"
    events = sitl.events()
    assert any(e.startswith("GCS Failsafe") for e in events)
    assert "mode RTL (failsafe)" in events


def test_vision_loss_holds_then_lands(tmp_path):
    # SN_VIS_MIN_ALT 35 m (the 3-D default is 50 m): the hover at 45 m must fuse its fixes
    params = write_params(tmp_path, SN_VIS_TIMEOUT=2, SN_VIS_FS_LAND=3, WPNAV_SPEED_UP=500,
                          WPNAV_SPEED_DN=300, LAND_SPEED=200, DISARM_DELAY=30, SN_VIS_MIN_ALT=35)
    sitl = SitlSession(tmp_path, "--lockstep", "--no-gps", "--perception", "none",
                       "--set", "flight.start_enu_m=[60,-60]", "--set", "sim.camera.rate_hz=5",
                       "--set", f"autopilot.params_file={params}")
    gcs = None
    try:
        sitl.wait_ready()
        gcs = Gcs(sitl.port)
        m = gcs.m
        arm_in_guided_and_take_off(gcs, 45.0)
        # hover on scene-matching fixes for a few simulated seconds
        t0 = gcs.wait("GLOBAL_POSITION_INT", fresh=True).time_boot_ms
        assert gcs.wait("GLOBAL_POSITION_INT", lambda p: p.time_boot_ms > t0 + 4000) is not None
        assert statustext(gcs, "Vision Failsafe", timeout_s=0.5) is None
        pid = sitl.child_pid("perception")
        assert pid is not None
        os.kill(pid, signal.SIGINT)                           # the only position source goes away
        hold = statustext(gcs, "holding")
        assert hold is not None and hold.severity <= m.MAV_SEVERITY_CRITICAL
        land = statustext(gcs, "Vision Failsafe")
        assert land is not None and "Land" in land.text
        assert gcs.wait("HEARTBEAT", lambda h: h.custom_mode == COPTER_LAND, 30,
                        fresh=True) is not None
        assert gcs.wait("HEARTBEAT", lambda h: not h.base_mode & MAV_MODE_FLAG_SAFETY_ARMED,
                        120, fresh=True) is not None, "never landed and disarmed"
    finally:
        if gcs is not None:
            gcs.close()
        sitl.stop()
    events = sitl.events()
    assert any("perception node perception left" in e for e in events)
    hold_i = next(i for i, e in enumerate(events) if e.startswith("Vision Failsafe") and "holding" in e)
    land_i = next(i for i, e in enumerate(events) if e.startswith("Vision Failsafe") and "Land" in e)
    assert hold_i < land_i
    assert "mode LAND (failsafe)" in events
    assert any(e.startswith("disarmed") for e in events)
    end = final_position(sitl.truth())
    assert end[2] < 0.5

