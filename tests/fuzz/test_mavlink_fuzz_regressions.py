"""Regressions for what fuzzing the autopilot found (tests/test_autopilot_fuzz_flight.py and an
in-process fuzz of FlightCore behind the MAVLink server with GUIDED targets, external navigation
and DO_CHANGE_SPEED allowed): valid-CRC messages with absurd but finite values.

1. SET_POSITION_TARGET_LOCAL_NED with x = 3.4e38 m was accepted: the vehicle flew off towards it
   (a position target nowhere on Earth); now rejected and counted like an out-of-range latitude.
2. A GUIDED acceleration target of 999 m/s^2 down (the MAVLink sanity limit is 1000) went straight
   into the controller's feed-forward: thrust at the minimum, the vehicle fell 10 m in 3 s. The
   feed-forward is now limited to the controller's acceleration limits.
3. DO_CHANGE_SPEED with 3.4e38 m/s was ACCEPTED (and capped at 50 m/s only for commands, not for
   mission items); now DENIED above the range of the parameter it overrides, and mission items are
   capped at that range.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support.fake_vehicle import command_ack, gcs_connection, running_server
from support.nav import nav_state as _nav

from autopilot_bridge.config import ControlConfig, FlightCoreConfig
from autopilot_bridge.control import FlightController
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.setpoints import local_position_target
from autopilot_bridge.vehicle_interface import MissionCommand, MissionItem, SpeedType

M = mavlink2
POSITION_ONLY = 0b110111111000


def _local(x: float, y: float, z: float) -> mavlink2.MAVLink_message:
    return M.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, M.MAV_FRAME_LOCAL_NED, POSITION_ONLY, x, y, z, 0, 0, 0, 0, 0, 0, 0, 0)


def test_local_position_target_nowhere_on_earth_is_rejected():
    assert local_position_target(_local(20.0, -5.0, -10.0)) is not None
    assert local_position_target(_local(1.0e6, 0.0, -10.0)) is not None      # far, but on Earth
    for x, y, z in ((3.4e38, 0.0, -10.0), (0.0, -3.4e38, -10.0), (0.0, 0.0, -3.4e38),
                    (2.1e7, 0.0, -10.0), (0.0, 0.0, 90_000.0)):
        assert local_position_target(_local(x, y, z)) is None, (x, y, z)


def test_acceleration_feed_forward_is_limited():
    cfg = ControlConfig()
    fc = FlightController(cfg)
    nav = _nav()
    fc.reset(nav, landed=False)
    out = fc.update_velocity(nav, np.zeros(3), (0.0, 0.0, 0.0), 0.01, accel_enu_m_s2=(0.0, 0.0, -999.0))
    assert out.accel_target_enu_m_s2[2] >= -cfg.max_accel_z_m_s2 - 1e-9
    assert out.thrust_n > 0.5 * fc.hover_thrust_n            # not the thrust floor: no free fall
    out = fc.update_velocity(nav, np.zeros(3), (0.0, 0.0, 0.0), 0.01, accel_enu_m_s2=(999.0, 999.0, 0.0))
    assert math.hypot(*out.accel_target_enu_m_s2[:2]) <= cfg.max_accel_xy_m_s2 + 1e-9


def test_change_speed_above_the_parameter_range_is_denied():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            for kind, speed, result in ((1, 3.4e38, M.MAV_RESULT_DENIED),
                                        (1, 20.5, M.MAV_RESULT_DENIED),
                                        (1, 20.0, M.MAV_RESULT_ACCEPTED),
                                        (2, 10.5, M.MAV_RESULT_DENIED),
                                        (3, 5.0, M.MAV_RESULT_ACCEPTED),
                                        (3, 5.5, M.MAV_RESULT_DENIED)):
                conn.mav.command_long_send(1, 1, M.MAV_CMD_DO_CHANGE_SPEED, 0, kind, speed,
                                           -1, 0, 0, 0, 0)
                ack = command_ack(conn, M.MAV_CMD_DO_CHANGE_SPEED)
                assert ack is not None and ack.result == result, (kind, speed)
        finally:
            conn.close()
    assert [c[1] for c in vehicle.moving_calls()] == [(SpeedType.GROUNDSPEED, 20.0),
                                                      (SpeedType.DESCENT_SPEED, 5.0)]


def test_core_caps_mission_and_command_speeds_at_the_parameter_range():
    core = FlightCore(ParameterStore(PARAM_SPECS), FlightCoreConfig())
    assert core.change_speed(SpeedType.GROUNDSPEED, 3.4e38).ok
    assert core.change_speed(SpeedType.CLIMB_SPEED, 1e9).ok
    texts = [t for _, t in core.drain_texts()]
    assert "speed groundspeed 20.0 m/s" in texts and "speed climb_speed 10.0 m/s" in texts
    item = MissionItem(seq=1, command=MissionCommand.DO_CHANGE_SPEED, frame=M.MAV_FRAME_MISSION,
                       param1=1.0, param2=3.4e38)
    assert core.mission_changed((item,)).ok
    assert core._speed_after(-1, None) == 20.0     # the speed a waypoint group after it flies at
