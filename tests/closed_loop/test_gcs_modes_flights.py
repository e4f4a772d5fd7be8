"""Ground-station modes, missions, guided commands and flying by hand on the in-process flight
(``CoreFlight``: the flight core on the simulator's core, GPS navigation), in three short flights
shared by the checks (module-scoped):

* ``guided_flight``: take-off in LOITER, GUIDED go-to with DO_PAUSE_CONTINUE and CONDITION_YAW,
  CIRCLE (radius, centre ahead, nose on the centre), SMART_RTL back along the path to a landing
  at home;
* ``mission_flight``: an AUTO mission with a spline waypoint, DO_JUMP (repeat 1), DO_SET_ROI_LOCATION, NAV_LOITER_TIME,
  CONDITION_YAW, NAV_DELAY, NAV_LOITER_TURNS, a stored-and-skipped IMAGE_START_CAPTURE and a
  terrain-frame waypoint (the terrain failsafe);
* ``pilot_flight``: ALT_HOLD take-off on the throttle, ``rc 3 1500`` holding the altitude, pitch
  forward, LOITER moved by the roll stick, then the overrides stop: radio failsafe, RTL.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.sim_flight import CoreFlight

from autopilot_bridge.auto_mission import AutoStage
from autopilot_bridge.modes import CopterMode
from autopilot_bridge.vehicle_interface import AltFrame, MavFrame, MissionCommand, MissionItem

MC = MissionCommand
REL = int(MavFrame.GLOBAL_RELATIVE_ALT)
RELEASED = (65535,) * 4 + (0,) * 10


class GpsFlight(CoreFlight):
    """CoreFlight navigating on the simulator's GPS, the vision failsafe off, a quick landing."""

    def __init__(self, seed: int, **params) -> None:
        super().__init__(seed, gps=True, SN_VIS_TIMEOUT=0, EK3_SRC1_POSXY=3, EK3_SRC1_VELXY=3,
                         LAND_SPEED=150, WPNAV_SPEED_DN=300, RTL_LOIT_TIME=0, **params)
        self.texts: list[str] = []
        self.run(3.0)                                    # align at rest

    def tick(self) -> None:
        super().tick()
        self.texts += [t for _, t in self.core.drain_texts()]

    def until(self, cond, timeout_s: float, what: str) -> None:
        assert self.run(timeout_s, until=cond), f"{what} (t = {self.t:.1f} s)"

    def heading_deg(self) -> float:
        return math.degrees(float(self.core.estimate().heading_rad)) % 360.0

    def latlon(self, e: float, n: float) -> tuple[int, int]:
        lat, lon = self.core.geo.to_geodetic(e, n)
        return int(round(lat * 1e7)), int(round(lon * 1e7))


def _heading_error_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


# ----------------------------------------------------------------------------- GUIDED, CIRCLE, SMART_RTL
@pytest.fixture(scope="module")
def guided_flight():
    f = GpsFlight(5, CIRCLE_RADIUS=800)
    c = f.core
    r: dict = {}
    assert c.set_mode(CopterMode.LOITER).ok and c.arm(False).ok
    r["althold_takeoff_refused"] = not c.set_mode(CopterMode.ALT_HOLD).ok or not c.takeoff(8.0).ok
    assert c.set_mode(CopterMode.LOITER).ok
    assert c.takeoff(8.0).ok                                   # ArduCopter: LOITER takes off
    f.until(lambda: f.p[2] > 7.6, 15, "LOITER takeoff")
    assert c.set_mode(CopterMode.GUIDED).ok
    lat, lon = c.geo.to_geodetic(0.0, 30.0)
    assert c.reposition(lat, lon, 8.0, AltFrame.RELATIVE_HOME, None, None).ok
    f.run(3.0)
    assert c.pause_continue(True).ok                           # DO_PAUSE_CONTINUE 0
    f.run(5.0)
    r["paused_speed"] = float(np.linalg.norm(f.v[:2]))
    r["paused_at"] = f.p.copy()
    f.run(1.5)
    r["paused_drift"] = float(np.linalg.norm(f.p[:2] - r["paused_at"][:2]))
    assert c.pause_continue(False).ok
    f.until(lambda: f.p[1] > 28.0, 20, "continue to the GUIDED destination")
    assert c.condition_yaw(90.0, 0.0, 1, False).ok
    f.run(3.0)
    r["yaw_deg"] = f.heading_deg()
    r["circle_start"] = f.p.copy()
    r["circle_heading"] = f.heading_deg()
    assert c.set_mode(CopterMode.CIRCLE).ok
    track = []
    for _ in range(8):
        f.run(1.0)
        track.append((f.p.copy(), f.heading_deg()))
    r["circle_track"] = track
    assert c.set_mode(CopterMode.SMART_RTL).ok
    smart = []
    f.until(lambda: (smart.append(f.p.copy()) or not c.armed), 60, "SMART_RTL landing")
    r["smart_track"] = np.array(smart)
    r["end"] = f.p.copy()
    r["texts"] = f.texts
    yield r
    f.close()


def test_loiter_takeoff_and_althold_needs_pilot_navigation(guided_flight):
    assert guided_flight["althold_takeoff_refused"]


def test_pause_stops_and_holds_then_continue(guided_flight):
    r = guided_flight
    assert r["paused_speed"] < 0.5 and r["paused_drift"] < 1.0    # GPS noise: as LOITER holds
    assert 3.0 < r["paused_at"][1] < 28.0                      # stopped short of the destination


def test_condition_yaw_in_guided(guided_flight):
    assert _heading_error_deg(guided_flight["yaw_deg"], 90.0) < 5.0


def test_circle_centre_ahead_radius_and_nose_on_centre(guided_flight):
    r = guided_flight
    h = math.radians(r["circle_heading"])
    centre = r["circle_start"][:2] + 8.0 * np.array([math.sin(h), math.cos(h)])
    later = r["circle_track"][3:]
    for p, heading in later:
        assert abs(float(np.linalg.norm(p[:2] - centre)) - 8.0) < 1.0
        to_centre = math.degrees(math.atan2(centre[0] - p[0], centre[1] - p[1])) % 360.0
        assert _heading_error_deg(heading, to_centre) < 15.0
    swept = [math.atan2(p[0] - centre[0], p[1] - centre[1]) for p, _ in r["circle_track"]]
    assert np.ptp(np.unwrap(swept)) > math.radians(60)


def test_smart_rtl_retraces_the_path_and_lands_home(guided_flight):
    r = guided_flight
    track = r["smart_track"]
    # back along the flown line x = 0 (the GUIDED leg north), not straight home from the circle
    leg = track[(track[:, 1] > 5.0) & (track[:, 1] < 20.0)]
    assert len(leg) > 0 and np.max(np.abs(leg[:, 0])) < 3.0
    assert math.hypot(r["end"][0], r["end"][1]) < 2.0 and r["end"][2] < 0.3
    assert "mode LAND (failsafe)" in r["texts"] or any("LAND" in t for t in r["texts"])


# ----------------------------------------------------------------------------- AUTO mission
@pytest.fixture(scope="module")
def mission_flight():
    f = GpsFlight(6, WPNAV_ACCEL=500)
    c = f.core

    def item(seq, cmd, e=None, n=None, alt=0.0, p=(0.0, 0.0, 0.0, 0.0), frame=REL):
        lat, lon = f.latlon(e, n) if e is not None else (0, 0)
        return MissionItem(seq=seq, command=int(cmd), frame=frame, param1=p[0], param2=p[1],
                           param3=p[2], param4=p[3], lat_e7=lat, lon_e7=lon, alt_m=alt)

    mission = (
        item(1, MC.NAV_TAKEOFF, alt=4.0),
        item(2, MC.DO_SET_ROI_LOCATION, 30.0, 30.0, 0.0),
        item(3, MC.NAV_WAYPOINT, 0.0, 7.0, 4.0),
        item(4, MC.NAV_SPLINE_WAYPOINT, 7.0, 7.0, 4.0),
        item(5, MC.DO_JUMP, p=(3.0, 1.0, 0.0, 0.0)),
        item(6, MC.NAV_LOITER_TIME, 7.0, 0.0, 4.0, p=(1.5, 0.0, 0.0, 0.0)),
        item(7, MC.DO_SET_ROI_NONE),
        item(8, MC.CONDITION_DELAY, p=(0.5, 0.0, 0.0, 0.0)),
        item(9, MC.CONDITION_YAW, p=(270.0, 0.0, 1.0, 0.0)),
        item(10, MC.IMAGE_START_CAPTURE, p=(0.0, 1.0, 0.0, 0.0)),
        item(11, MC.NAV_DELAY, p=(1.0, 0.0, 0.0, 0.0)),
        item(12, MC.NAV_LOITER_TURNS, 7.0, 0.0, 4.0, p=(1.0, 0.0, 2.0, 0.0)),
        item(13, MC.NAV_WAYPOINT, 0.0, 0.0, 4.0, frame=int(MavFrame.GLOBAL_TERRAIN_ALT)),
    )
    assert c.mission_changed(mission).ok
    assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok and c.set_mode(CopterMode.AUTO).ok
    log = []
    f.until(lambda: log.append((f.t, c.mission_state, c._mission_index + 1, c._auto_stage,
                                f.p.copy(), f.heading_deg(), c.mode)) or c.mode != CopterMode.AUTO,
            120, "the mission until the terrain failsafe")
    r = {"log": log, "texts": list(f.texts)}
    yield r
    f.close()


def _stage_rows(log, seq, stage=None):
    return [row for row in log if row[2] == seq and (stage is None or row[3] == stage)]


def test_do_jump_repeats_the_waypoints_once(mission_flight):
    texts = mission_flight["texts"]
    assert "Mission: 5 Jump 1/1" in texts
    assert texts.count("Reached command #3") == 2 and texts.count("Reached command #4") == 2


def test_roi_points_the_nose_at_the_location(mission_flight):
    rows = _stage_rows(mission_flight["log"], 4, AutoStage.WAYPOINTS)
    late = rows[len(rows) // 2:]
    for _, _, _, _, p, heading, _ in late:
        to_roi = math.degrees(math.atan2(30.0 - p[0], 30.0 - p[1])) % 360.0
        assert _heading_error_deg(heading, to_roi) < 12.0


def test_loiter_time_condition_yaw_and_nav_delay(mission_flight):
    log = mission_flight["log"]
    held = _stage_rows(log, 6, AutoStage.WP_DELAY)
    assert held and held[-1][0] - held[0][0] == pytest.approx(1.5, abs=0.2)
    assert np.linalg.norm(held[-1][4][:2] - (7.0, 0.0)) < 1.0
    delay = _stage_rows(log, 11, AutoStage.WP_DELAY)
    assert delay and delay[-1][0] - delay[0][0] == pytest.approx(1.0, abs=0.2)
    assert _heading_error_deg(delay[-1][5], 270.0) < 5.0       # CONDITION_YAW 270 reached
    texts = mission_flight["texts"]
    assert "mission: item 10 skipped (IMAGE_START_CAPTURE)" not in texts   # a do command: run, no effect
    assert "Reached command #12" in texts


def test_loiter_turns_circles_once_around_the_item(mission_flight):
    rows = _stage_rows(mission_flight["log"], 12, AutoStage.CIRCLE)
    pts = np.array([row[4][:2] for row in rows])
    dist = np.linalg.norm(pts - (7.0, 0.0), axis=1)
    assert np.median(dist) == pytest.approx(2.0, abs=0.6)
    angles = np.unwrap(np.arctan2(pts[:, 0] - 7.0, pts[:, 1]))
    assert np.ptp(angles) > 1.7 * math.pi


def test_terrain_frame_waypoint_without_terrain_data_is_the_terrain_failsafe(mission_flight):
    texts = mission_flight["texts"]
    assert "Failsafe: Terrain data missing" in texts
    assert mission_flight["log"][-1][6] == CopterMode.RTL


# ----------------------------------------------------------------------------- flying by hand
@pytest.fixture(scope="module")
def pilot_flight():
    f = GpsFlight(7, FS_THR_ENABLE=1)
    c = f.core
    r: dict = {}

    def hold(seconds, roll=1500, pitch=1500, throttle=1500, yaw=1500):
        for _ in range(int(seconds * 100)):
            c.rc_channels_override((roll, pitch, throttle, yaw) + RELEASED)
            f.tick()

    assert c.set_mode(CopterMode.ALT_HOLD).ok and c.arm(False).ok
    hold(1.0, throttle=1100)
    r["idle_on_ground"] = c.landed
    hold(2.5, throttle=1900)                                   # climb (takeoff on the throttle)
    r["climbed_to"] = float(f.p[2])
    hold(0.5)
    z0 = float(f.p[2])
    for _ in range(200):                                       # MAVProxy `rc 3 1500`
        c.rc_channels_override((0, 0, 1500, 0) + RELEASED)
        f.tick()
    r["hold_dz"] = float(f.p[2]) - z0
    hold(2.0, pitch=1250)                                      # stick forward: nose down
    r["forward_velocity"] = f.v.copy()
    r["forward_heading"] = f.heading_deg()
    hold(1.0)
    assert c.set_mode(CopterMode.LOITER).ok
    p0 = f.p.copy()
    hold(2.0, roll=1750)
    r["loiter_moved"] = f.p - p0
    hold(3.0)
    p1 = f.p.copy()
    hold(1.5)
    r["loiter_drift"] = float(np.linalg.norm(f.p[:2] - p1[:2]))
    f.until(lambda: c.mode == CopterMode.RTL, 5.0, "radio failsafe after RC_OVERRIDE_TIME")
    r["failsafe_t"] = f.t
    r["texts"] = f.texts
    yield r
    f.close()


def test_althold_throttle_takeoff_and_mid_stick_hold(pilot_flight):
    r = pilot_flight
    assert r["idle_on_ground"]
    assert r["climbed_to"] > 2.0
    assert abs(r["hold_dz"]) < 0.3


def test_pitch_forward_flies_forward_in_althold(pilot_flight):
    r = pilot_flight
    h = math.radians(r["forward_heading"])
    forward = r["forward_velocity"][0] * math.sin(h) + r["forward_velocity"][1] * math.cos(h)
    assert forward > 2.0


def test_loiter_roll_stick_moves_right_and_centred_holds(pilot_flight):
    r = pilot_flight
    assert np.linalg.norm(r["loiter_moved"][:2]) > 3.0
    assert r["loiter_drift"] < 1.0


def test_radio_failsafe_when_overrides_stop(pilot_flight):
    assert "Radio Failsafe" in pilot_flight["texts"]


# ----------------------------------------------------------------------------- landing sequence (AUTO_RTL)
@pytest.fixture(scope="module")
def land_start_flight():
    """An AUTO mission with two landing sequences; the RC overrides stop on the first leg and the
    radio failsafe (FS_THR_ENABLE 6, "Auto DO_LAND_START or RTL") jumps to the nearer one."""
    f = GpsFlight(8, WPNAV_ACCEL=500, FS_THR_ENABLE=6)
    c = f.core

    def item(seq, cmd, e=None, n=None, alt=0.0):
        lat, lon = f.latlon(e, n) if e is not None else (0, 0)
        return MissionItem(seq=seq, command=int(cmd), frame=REL, lat_e7=lat, lon_e7=lon, alt_m=alt)

    r: dict = {"no_mission": c.jump_to_landing_sequence()}
    assert c.mission_changed((item(1, MC.NAV_TAKEOFF, alt=4.0), item(2, MC.NAV_WAYPOINT, 0.0, 30.0, 4.0))).ok
    r["no_land_start"] = c.jump_to_landing_sequence()
    mission = (
        item(1, MC.NAV_TAKEOFF, alt=4.0),
        item(2, MC.NAV_WAYPOINT, 0.0, 40.0, 4.0),
        item(3, MC.NAV_WAYPOINT, 40.0, 40.0, 4.0),
        item(4, MC.DO_LAND_START, -60.0, 40.0),       # the far landing sequence
        item(5, MC.NAV_WAYPOINT, -60.0, 40.0, 4.0),
        item(6, MC.NAV_LAND, -60.0, 40.0),
        item(7, MC.DO_LAND_START, 12.0, 12.0),        # the near one
        item(8, MC.NAV_WAYPOINT, 12.0, 12.0, 4.0),
        item(9, MC.NAV_LAND, 12.0, 12.0),
    )
    assert c.mission_changed(mission).ok
    assert c.set_mode(CopterMode.GUIDED).ok and c.arm(False).ok and c.set_mode(CopterMode.AUTO).ok
    for _ in range(3000):                             # the pilot's sticks centred until the first leg
        if c._mission_index == 1 and f.p[1] > 8.0:
            break
        c.rc_channels_override((1500, 1500, 1500, 1500) + RELEASED)
        f.tick()
    assert c._mission_index == 1 and c.mode == CopterMode.AUTO, (f.t, c._mission_index, c.mode)
    f.until(lambda: c.mode != CopterMode.AUTO, 6.0, "radio failsafe after RC_OVERRIDE_TIME")
    r["failsafe_at"] = f.p.copy()
    r["mode_after_failsafe"] = c.mode
    r["seq_after_failsafe"] = c._mission_index + 1
    f.run(2.0)
    r["auto_again"] = (c.set_mode(CopterMode.AUTO).ok, c.mode)
    r["auto_rtl_again"] = (c.set_mode(CopterMode.AUTO_RTL).ok, c.mode)
    modes = []
    f.until(lambda: modes.append(c.mode) or not c.armed, 60, "landing of the landing sequence")
    r["modes_to_landing"] = set(modes)
    r["end"] = f.p.copy()
    r["texts"] = list(f.texts)
    yield r
    f.close()


def test_no_landing_sequence_is_refused_as_arducopter(land_start_flight):
    for key in ("no_mission", "no_land_start"):
        outcome = land_start_flight[key]
        assert not outcome.ok and outcome.reason == "Mode change to AUTO RTL failed: No landing sequence found"
    assert "Unable to start landing sequence" in land_start_flight["texts"]


def test_radio_failsafe_6_flies_the_nearest_landing_sequence_as_auto_rtl(land_start_flight):
    r = land_start_flight
    assert "Radio Failsafe" in r["texts"] and "Landing sequence start" in r["texts"]
    assert r["mode_after_failsafe"] == CopterMode.AUTO_RTL
    assert r["seq_after_failsafe"] in (7, 8)                 # the near DO_LAND_START, not item 4
    assert r["auto_again"] == (True, CopterMode.AUTO)        # asking for AUTO: the mission goes on as AUTO
    assert r["auto_rtl_again"] == (True, CopterMode.AUTO_RTL)
    assert r["modes_to_landing"] == {CopterMode.AUTO_RTL}    # reported until it landed and disarmed
    assert np.linalg.norm(r["end"][:2] - (12.0, 12.0)) < 1.5
    assert r["end"][2] < 0.5
