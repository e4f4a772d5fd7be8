"""Mixer, cascaded controller and guidance law: small hand-checked cases.

Sign conventions checked here (body FLU): a positive roll torque (about +x, forward) lifts the left side
(right wing down); a positive pitch torque (about +y, left) lowers the nose; a positive yaw torque turns
the nose left (counter-clockwise seen from above).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.nav import nav_state

from autopilot_bridge.airframe import Airframe
from autopilot_bridge.config import ControlConfig, GuidanceConfig, YawBehaviour
from autopilot_bridge.control import (
    FlightController,
    LandState,
    PositionTarget,
    VerticalMode,
    sqrt_controller,
    stopping_point,
)
from autopilot_bridge.ekf import NavState
from autopilot_bridge.guidance_law import (
    GuidanceEventKind,
    Lander,
    ReturnToLaunch,
    RtlPhase,
    Waypoint,
    WaypointTracker,
    make_takeoff,
)
from autopilot_bridge.mixer import QuadXMixer
from scenenav.core.config import ConfigError
from scenenav.core.rotations import aviation_euler_from_quat, quat_from_aviation_euler, quat_to_rotation_matrix

VEH = Airframe()
HOVER_THRUST = VEH.mass_kg * VEH.gravity_m_s2
DT = 0.01


def _torque_from_thrusts(thrusts: np.ndarray) -> np.ndarray:
    """Independent r x F + reaction-torque sum over the rotors of the airframe model."""
    total = np.zeros(3)
    for (x, y), d, t in zip(VEH.rotor_positions_flu_m, VEH.rotor_spins, thrusts, strict=False):
        total += np.cross([x, y, 0.0], [0.0, 0.0, t])
        total += np.array([0.0, 0.0, -int(d) * VEH.moment_constant_m * t])
    return total


_nav = nav_state



# ------------------------------------------------------------------------------------------ mixer

def test_mixer_hover_gives_four_equal_hover_commands():
    mixer = QuadXMixer()
    # Hand value: sqrt(1.5 * 9.80665 / (4 * 5.84e-6)) / 1100 = 793.54 / 1100.
    assert mixer.hover_command == pytest.approx(0.72140, abs=1e-4)
    out = mixer.mix(HOVER_THRUST, np.zeros(3))
    assert np.allclose(out.commands, mixer.hover_command, atol=1e-9)
    assert out.thrust_n == pytest.approx(HOVER_THRUST)
    assert not out.limits.any


def test_mixer_roll_pitch_yaw_signs():
    mixer = QuadXMixer()
    hover = mixer.hover_command
    # Positive roll torque: left rotors (rotor_1 back-left, rotor_2 front-left) speed up.
    out = mixer.mix(HOVER_THRUST, np.array([0.2, 0.0, 0.0]))
    c = out.commands
    assert c[1] > hover and c[2] > hover and c[0] < hover and c[3] < hover
    assert np.allclose(_torque_from_thrusts(out.rotor_thrusts_n), [0.2, 0.0, 0.0], atol=1e-9)
    # Positive pitch torque (nose down): back rotors (rotor_1, rotor_3) speed up.
    c = mixer.mix(HOVER_THRUST, np.array([0.0, 0.2, 0.0])).commands
    assert c[1] > hover and c[3] > hover and c[0] < hover and c[2] < hover
    # Positive yaw torque (CCW): the CW rotors (rotor_2, rotor_3) speed up, their reaction is CCW.
    out = mixer.mix(HOVER_THRUST, np.array([0.0, 0.0, 0.1]))
    c = out.commands
    assert c[2] > hover and c[3] > hover and c[0] < hover and c[1] < hover
    assert np.allclose(_torque_from_thrusts(out.rotor_thrusts_n), [0.0, 0.0, 0.1], atol=1e-9)
    assert out.thrust_n == pytest.approx(HOVER_THRUST)
    # Commands map to thrust through k (w_max c)^2.
    t = VEH.thrust_coefficient_n_per_rad2_s2 * (c * VEH.max_rotor_speed_rad_s) ** 2
    assert np.allclose(t, out.rotor_thrusts_n)


def test_mixer_saturation_priority_roll_pitch_then_thrust_then_yaw():
    mixer = QuadXMixer()
    t_min, t_max = mixer.rotor_thrust_limits_n
    # Full thrust plus roll: roll is met exactly, collective thrust gives way.
    out = mixer.mix(4.0 * t_max, np.array([0.3, 0.0, 0.0]))
    assert out.limits.thrust_upper and not out.limits.roll_pitch
    assert out.torque_flu_n_m[0] == pytest.approx(0.3)
    assert out.thrust_n < 4.0 * t_max
    assert np.all(out.commands <= 1.0 + 1e-12)
    # Hover plus roll plus an impossible yaw: roll and thrust met, yaw scaled down.
    out = mixer.mix(HOVER_THRUST, np.array([0.3, 0.0, 3.0]))
    assert out.limits.yaw and not out.limits.roll_pitch and not out.limits.thrust_upper
    assert out.torque_flu_n_m[0] == pytest.approx(0.3)
    assert out.thrust_n == pytest.approx(HOVER_THRUST)
    assert 0.0 < out.torque_flu_n_m[2] < 3.0
    # Roll/pitch beyond the whole range: scaled together, direction kept.
    out = mixer.mix(HOVER_THRUST, np.array([10.0, -5.0, 0.0]))
    assert out.limits.roll_pitch
    assert out.torque_flu_n_m[0] / out.torque_flu_n_m[1] == pytest.approx(-2.0)
    assert np.all((out.commands >= 0.0) & (out.commands <= 1.0))
    # Zero thrust with a roll demand: the roll is produced (thrust raised), never negative thrust.
    out = mixer.mix(0.0, np.array([0.1, 0.0, 0.0]))
    assert out.limits.thrust_lower and out.torque_flu_n_m[0] == pytest.approx(0.1)
    assert np.all(out.rotor_thrusts_n >= t_min - 1e-12)


def test_mixer_min_command_floor():
    mixer = QuadXMixer(Airframe(spin_min=0.1))
    out = mixer.mix(0.0, np.zeros(3))
    assert np.allclose(out.commands, 0.1)


# ------------------------------------------------------------------------------------------ controller

def test_sqrt_controller_linear_then_braking_curve():
    assert sqrt_controller(0.5, 1.0, 2.0) == pytest.approx(0.5)
    # Beyond a/p^2 = 2 m: sqrt(2 a (e - a/(2 p^2))) = sqrt(4 * (10 - 1)) = 6.
    assert sqrt_controller(10.0, 1.0, 2.0) == pytest.approx(6.0)
    assert sqrt_controller(-10.0, 1.0, 2.0) == pytest.approx(-6.0)
    assert sqrt_controller(2.0 - 1e-9, 1.0, 2.0) == pytest.approx(sqrt_controller(2.0 + 1e-9, 1.0, 2.0))
    assert np.allclose(stopping_point([0, 0, 5], [4.0, 0.0, 0.0], 2.0), [4.0, 0.0, 5.0])


def _airborne(fc: FlightController, nav: NavState) -> None:
    fc.reset(nav, landed=False)


def test_hover_at_target_gives_weight_and_no_torque():
    fc = FlightController()
    nav = _nav()
    _airborne(fc, nav)
    out = fc.update_position(nav, np.zeros(3), PositionTarget((0.0, 0.0, 10.0)), DT)
    assert out.thrust_n == pytest.approx(HOVER_THRUST, rel=1e-6)
    assert np.allclose(out.torque_flu_n_m, 0.0, atol=1e-9)
    assert out.land_state == LandState.AIRBORNE


def test_position_error_east_tilts_towards_east():
    fc = FlightController()
    nav = _nav(q=quat_from_aviation_euler(0.0, 0.0, 0.0))   # nose north: east is to the right
    _airborne(fc, nav)
    out = fc.update_position(nav, np.zeros(3), PositionTarget((3.0, 0.0, 10.0)), DT)
    assert out.velocity_target_enu_m_s[0] > 0.0 and out.accel_target_enu_m_s2[0] > 0.0
    z_target = quat_to_rotation_matrix(out.q_target_wxyz) @ [0.0, 0.0, 1.0]
    assert z_target[0] > 0.05 and abs(z_target[1]) < 1e-9
    roll, pitch, heading = aviation_euler_from_quat(out.q_target_wxyz)
    assert roll > 0.0 and abs(pitch) < 1e-9                 # right wing down
    assert out.rate_target_flu_rad_s[0] > 0.0                # roll right = +x body rate
    assert out.torque_flu_n_m[0] > 0.0
    # Facing east, the same error pitches the nose down.
    fc = FlightController()
    nav = _nav(q=quat_from_aviation_euler(0.0, 0.0, math.pi / 2))
    _airborne(fc, nav)
    out = fc.update_position(nav, np.zeros(3), PositionTarget((3.0, 0.0, 10.0)), DT)
    roll, pitch, heading = aviation_euler_from_quat(out.q_target_wxyz)
    assert pitch < 0.0 and abs(roll) < 1e-9
    assert heading == pytest.approx(math.pi / 2)


def test_limits_lean_speed_climb_descent():
    cfg = ControlConfig()
    fc = FlightController(cfg)
    nav = _nav()
    _airborne(fc, nav)
    out = fc.update_position(nav, np.zeros(3), PositionTarget((500.0, 300.0, 200.0)), DT)
    speed = math.hypot(*out.velocity_target_enu_m_s[:2])
    assert speed == pytest.approx(cfg.max_speed_xy_m_s)
    assert out.velocity_target_enu_m_s[2] == pytest.approx(cfg.max_climb_m_s)
    z_target = quat_to_rotation_matrix(out.q_target_wxyz) @ [0.0, 0.0, 1.0]
    assert math.degrees(math.acos(z_target[2])) <= cfg.max_lean_angle_deg + 1e-6
    out = fc.update_position(nav, np.zeros(3), PositionTarget((0.0, 0.0, -100.0)), DT)
    assert out.velocity_target_enu_m_s[2] == pytest.approx(-cfg.max_descent_m_s)
    # Velocity command capped at max speed.
    out = fc.update_velocity(nav, np.zeros(3), (30.0, 0.0, 0.0), DT)
    assert out.velocity_target_enu_m_s[0] == pytest.approx(cfg.max_speed_xy_m_s)


def test_attitude_errors_give_correcting_rates():
    fc = FlightController()
    # Rolled 10 deg right, target level: roll back left (-x rate).
    nav = _nav(q=quat_from_aviation_euler(math.radians(10.0), 0.0, 0.0))
    _airborne(fc, nav)
    out = fc.update_attitude(nav, np.zeros(3), quat_from_aviation_euler(0.0, 0.0, 0.0), HOVER_THRUST, DT)
    assert out.rate_target_flu_rad_s[0] == pytest.approx(-ControlConfig().ang_rp_p_1_s * math.radians(10.0), rel=1e-3)
    assert abs(out.rate_target_flu_rad_s[1]) < 1e-6
    # Heading target 20 deg east of the current heading: turn clockwise (negative body z rate), capped.
    nav = _nav(q=quat_from_aviation_euler(0.0, 0.0, 0.0))
    _airborne(fc, nav)
    out = fc.update_attitude(nav, np.zeros(3), quat_from_aviation_euler(0.0, 0.0, math.radians(20.0)),
                             HOVER_THRUST, DT)
    assert out.rate_target_flu_rad_s[2] == pytest.approx(-math.radians(ControlConfig().max_rate_yaw_deg_s))
    assert np.allclose(out.rate_target_flu_rad_s[:2], 0.0, atol=1e-9)
    assert out.torque_flu_n_m[2] < 0.0
    # A 40 deg attitude request is limited to the 30 deg lean angle.
    out = fc.update_attitude(nav, np.zeros(3), quat_from_aviation_euler(math.radians(40.0), 0.0, 0.0),
                             HOVER_THRUST, DT)
    roll, _, _ = aviation_euler_from_quat(out.q_target_wxyz)
    assert math.degrees(roll) == pytest.approx(30.0, abs=1e-6)


def test_integrators_bounded_and_frozen_when_limited():
    cfg = ControlConfig()
    fc = FlightController(cfg)
    nav = _nav()
    _airborne(fc, nav)
    # The vehicle never moves: a persistent 10 m/s velocity error for 100 s.
    for _ in range(10000):
        out = fc.update_velocity(nav, np.zeros(3), (10.0, 0.0, 2.5), DT)
    assert math.hypot(*fc._vel_xy_i) <= cfg.vel_xy_imax_m_s2 + 1e-9
    assert abs(fc._vel_z_i) <= cfg.vel_z_imax_m_s2 + 1e-9
    assert out.lean_limited
    # Lean-limited from the first tick: the xy integrator must not have grown beyond one step.
    fc2 = FlightController(cfg)
    _airborne(fc2, nav)
    for _ in range(500):
        fc2.update_velocity(nav, np.zeros(3), (10.0, 0.0, 0.0), DT)
    assert math.hypot(*fc2._vel_xy_i) <= cfg.vel_xy_i_1_s2 * 10.0 * DT + 1e-9


def test_land_detector_and_takeoff():
    cfg = ControlConfig()
    fc = FlightController(cfg)
    ground = _nav(position=(0.0, 0.0, 0.0))
    fc.reset(ground, landed=True)
    # Landed, holding the ground position: idle (zero thrust).
    out = fc.update_position(ground, np.zeros(3), PositionTarget((0.0, 0.0, 0.0)), DT)
    assert out.land_state == LandState.LANDED and out.thrust_n == 0.0
    # A climb target leaves the landed state and asks for more than hover thrust.
    out = fc.update_position(ground, np.zeros(3), PositionTarget((0.0, 0.0, 0.0), velocity_enu_m_s=(0.0, 0.0, 1.0)), DT)
    assert out.land_state == LandState.AIRBORNE and out.thrust_n > HOVER_THRUST
    # Descending steadily at LAND_SPEED: no touchdown.
    descending = _nav(position=(0.0, 0.0, 3.0), velocity=(0.0, 0.0, -0.5))
    land = PositionTarget((0.0, 0.0, 3.0), velocity_enu_m_s=(0.0, 0.0, -0.5), vertical_mode=VerticalMode.VELOCITY)
    for _ in range(300):
        out = fc.update_position(descending, np.zeros(3), land, DT)
        assert not out.touchdown
    # On the ground (vertical speed 0 while descending is commanded): thrust drops, touchdown after ~1 s.
    ticks = []
    for k in range(400):
        out = fc.update_position(ground, np.zeros(3), land, DT)
        if out.touchdown:
            ticks.append(k)
    assert len(ticks) == 1
    assert cfg.land_detect_time_s / DT <= ticks[0] + 1 < 3.0 / DT
    assert fc.landed and out.thrust_n == 0.0


def test_stabilize_passes_thrust_and_attitude():
    fc = FlightController()
    nav = _nav()
    _airborne(fc, nav)
    frac = 0.6
    out = fc.update_stabilize(nav, np.zeros(3), math.radians(10.0), math.radians(-5.0), 0.0, frac, DT)
    assert out.thrust_n == pytest.approx(frac * VEH.max_thrust_n)
    roll, pitch, _ = aviation_euler_from_quat(out.q_target_wxyz)
    assert (math.degrees(roll), math.degrees(pitch)) == pytest.approx((10.0, -5.0))


def test_config_range_checks():
    with pytest.raises(ConfigError):
        ControlConfig(max_lean_angle_deg=80.0)
    with pytest.raises(ConfigError):
        GuidanceConfig(wp_speed_m_s=-1.0)
    with pytest.raises(ConfigError):
        Airframe(spin_min=1.5)


# ------------------------------------------------------------------------------------------ guidance

def _follow(law, seconds: float, start, dt=DT, lag=0.0):
    """Drive a guidance law with a point mass that sits on the target (optionally lagging it)."""
    p = np.array(start, dtype=float)
    v = np.zeros(3)
    out = []
    events = []
    for _ in range(int(seconds / dt)):
        nav = _nav(position=p, velocity=v)
        tgt = law.update(nav, dt)
        new_p = np.array(tgt.position_enu_m) - lag * np.array(tgt.velocity_enu_m_s)
        if tgt.vertical_mode == VerticalMode.VELOCITY:
            new_p[2] = p[2] + tgt.velocity_enu_m_s[2] * dt
        v = (new_p - p) / dt
        p = new_p
        out.append((tgt, p.copy()))
        events += law.pop_events()
    return out, events


def test_waypoint_speed_profile_and_reached_events():
    cfg = GuidanceConfig()
    tracker = WaypointTracker(cfg, [Waypoint((200.0, 0.0, 20.0))], (0.0, 0.0, 20.0))
    out, events = _follow(tracker, 40.0, (0.0, 0.0, 20.0))
    speeds = np.array([np.linalg.norm(t.velocity_enu_m_s) for t, _ in out])
    assert speeds.max() == pytest.approx(cfg.wp_speed_m_s, rel=1e-6)
    accel = np.diff(speeds) / DT
    assert accel.max() <= cfg.wp_accel_m_s2 + 1e-6
    # Braking at WPNAV_ACCEL; only the final stopping tick may drop by up to 2 a dt (5 cm/s).
    stop = int(np.argmax(speeds[1:] == 0.0))
    assert accel[:stop].min() >= -cfg.wp_accel_m_s2 * 1.0001
    assert speeds[stop] <= 2.0 * cfg.wp_accel_m_s2 * DT + 1e-9
    assert out[-1][0].position_enu_m == pytest.approx((200.0, 0.0, 20.0))
    assert speeds[-1] == 0.0
    assert [e.kind for e in events] == [GuidanceEventKind.WAYPOINT_REACHED, GuidanceEventKind.MISSION_COMPLETE]
    assert tracker.complete
    assert out[10][0].heading_rad == pytest.approx(math.pi / 2)   # facing east


def test_intermediate_waypoint_and_climb_limits():
    cfg = GuidanceConfig()
    wps = [Waypoint((50.0, 0.0, 10.0)), Waypoint((50.0, 50.0, 40.0), speed_m_s=5.0)]
    tracker = WaypointTracker(cfg, wps, (0.0, 0.0, 10.0))
    out, events = _follow(tracker, 60.0, (0.0, 0.0, 10.0))
    reached = [e.index for e in events if e.kind == GuidanceEventKind.WAYPOINT_REACHED]
    assert reached == [0, 1] and tracker.complete
    vz = np.array([t.velocity_enu_m_s[2] for t, _ in out])
    vxy = np.array([math.hypot(*t.velocity_enu_m_s[:2]) for t, _ in out])
    assert vz.max() <= cfg.wp_speed_up_m_s + 1e-9
    assert vxy[len(out) // 2:].max() <= 5.0 + 1e-9
    # 90 degree corner: the carrot comes to rest at the corner.
    i_corner = next(i for i, (t, _) in enumerate(out) if t.position_enu_m[1] > 0.0)
    assert np.linalg.norm(out[i_corner - 1][0].velocity_enu_m_s) < 0.5
    headings = {round(t.heading_rad, 6) for t, _ in out}
    assert headings == {round(math.pi / 2, 6), 0.0}


@pytest.mark.parametrize("offset_m", [0.0, 1e-9, 1e-7, 1e-6, 1e-5])
def test_a_leg_shorter_than_the_tolerance_ends_at_once(offset_m):
    """Generated world 10006, `realistic` (session 20): the NAV_LAND after the last waypoint started
    1e-7 m from that waypoint's target (rounding); the leg had no direction and never ended, and the
    vehicle hovered over home until the run's end."""
    tracker = WaypointTracker(GuidanceConfig(), [Waypoint((0.0, 0.0, 100.0))], (offset_m, 0.0, 100.0))
    nav = _nav(position=(0.3, 0.2, 100.1))
    for _ in range(5):
        tracker.update(nav, DT)
    assert tracker.complete
    assert [e.kind for e in tracker.pop_events()] == [GuidanceEventKind.WAYPOINT_REACHED,
                                                      GuidanceEventKind.MISSION_COMPLETE]


def test_leash_holds_the_carrot_for_a_lagging_vehicle():
    cfg = GuidanceConfig(wp_leash_m=3.0)
    tracker = WaypointTracker(cfg, [Waypoint((100.0, 0.0, 10.0))], (0.0, 0.0, 10.0))
    stuck = _nav(position=(0.0, 0.0, 10.0))
    for _ in range(1000):
        tgt = tracker.update(stuck, DT)
    assert tgt.position_enu_m[0] == pytest.approx(3.0, abs=1e-6)


def test_takeoff_lander_and_rtl():
    cfg = GuidanceConfig(yaw_behaviour=YawBehaviour.NEVER_CHANGE)
    takeoff = make_takeoff(cfg, (5.0, 5.0, 0.0), 20.0)
    out, events = _follow(takeoff, 15.0, (5.0, 5.0, 0.0))
    assert takeoff.complete and out[-1][1] == pytest.approx((5.0, 5.0, 20.0))
    assert max(t.velocity_enu_m_s[2] for t, _ in out) == pytest.approx(cfg.takeoff_speed_m_s)
    assert all(t.heading_rad is None for t, _ in out)

    lander = Lander(cfg, (0.0, 0.0, 30.0), ground_z_m=0.0)
    assert lander.descent_speed_m_s(20.0) == cfg.wp_speed_down_m_s
    assert lander.descent_speed_m_s(5.0) == cfg.land_speed_m_s

    home = (0.0, 0.0, 0.0)
    rtl = ReturnToLaunch(cfg, home, _nav(position=(100.0, 0.0, 8.0)))
    phases = []
    p = np.array([100.0, 0.0, 8.0])
    for _ in range(int(120 / DT)):
        tgt = rtl.update(_nav(position=p), DT)
        if tgt.vertical_mode == VerticalMode.VELOCITY:
            p = np.array([tgt.position_enu_m[0], tgt.position_enu_m[1], p[2] + tgt.velocity_enu_m_s[2] * DT])
        else:
            p = np.array(tgt.position_enu_m)
        phases += [e.detail for e in rtl.pop_events()]
        if rtl.phase == RtlPhase.CLIMB:
            assert p[0] == pytest.approx(100.0)
        if p[2] <= 0.0:
            break
    assert phases == ["return", "loiter", "land"]
    assert p[:2] == pytest.approx((0.0, 0.0), abs=1e-6)


def test_config_loads_from_mapping_and_round_trips():
    from autopilot_bridge.config import AutopilotAlgorithmsConfig, PositionSource
    from scenenav.core.config import load_config, to_dict

    cfg = load_config(AutopilotAlgorithmsConfig, {"ekf": {"position_source": 6},
                                                  "control": {"max_lean_angle_deg": 25}})
    assert cfg.ekf.position_source == PositionSource.EXTNAV and cfg.control.max_lean_angle_deg == 25.0
    assert load_config(AutopilotAlgorithmsConfig, to_dict(cfg)) == cfg
    with pytest.raises(ConfigError, match="position_source"):
        load_config(AutopilotAlgorithmsConfig, {"ekf": {"position_source": 4}})
