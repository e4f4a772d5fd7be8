"""OPTICAL_FLOW, DISTANCE_SENSOR and RANGEFINDER from the flow module, through the flight core's
telemetry and real MAVLink bytes; nothing without the sensor (FLOW_TYPE 0 or no sample)."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from autopilot_bridge.config import FlightCoreConfig
from autopilot_bridge.flight_core import FlightCore
from autopilot_bridge.fusion import FlowReading
from autopilot_bridge.param_specs import PARAM_SPECS
from autopilot_bridge.params import ParameterStore
from autopilot_bridge.telemetry import EncodeContext, encode
from autopilot_bridge.vehicle_interface import SensorFlag

M = mavlink2
CTX = EncodeContext(mission_item_count=0, battery_monitor=4, unix_time_us=0)
FLOW_IDS = (M.MAVLINK_MSG_ID_OPTICAL_FLOW, M.MAVLINK_MSG_ID_DISTANCE_SENSOR, M.MAVLINK_MSG_ID_RANGEFINDER)


def _core(flow_type: int) -> FlightCore:
    return FlightCore(ParameterStore(PARAM_SPECS, defaults={"FLOW_TYPE": flow_type}),
                      FlightCoreConfig(origin_lat_deg=48.1, origin_lon_deg=11.5))


def _wire(msg):
    """Pack to bytes and parse them back, as a ground station receives it."""
    mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
    return mav.parse_char(msg.pack(mav))


def test_flow_messages_carry_the_last_sample_in_body_frd():
    core = _core(10)
    # 2 m/s forward over 20 m: flow y +0.1 rad/s (FLU); rolling at 0.05 rad/s shows as -0.05 on x
    core.on_flow(FlowReading(12.5, (-0.05, 0.1), (0.05, 0.0), 20.0, 200))
    tel = core.telemetry()
    flow = _wire(encode(M.MAVLINK_MSG_ID_OPTICAL_FLOW, tel, CTX))
    assert flow.get_type() == "OPTICAL_FLOW"
    assert flow.time_usec == 12_500_000 and flow.quality == 200
    assert (flow.flow_rate_x, flow.flow_rate_y) == pytest.approx((-0.05, -0.1))      # FRD: y negated
    assert (flow.flow_comp_m_x, flow.flow_comp_m_y) == pytest.approx((0.0, -2.0))
    assert flow.ground_distance == pytest.approx(20.0)
    dist = _wire(encode(M.MAVLINK_MSG_ID_DISTANCE_SENSOR, tel, CTX))
    assert dist.current_distance == 2000 and dist.orientation == M.MAV_SENSOR_ROTATION_PITCH_270
    assert (dist.min_distance, dist.max_distance) == (10, 3000)     # RNGFND1_MIN_CM / _MAX_CM defaults
    assert _wire(encode(M.MAVLINK_MSG_ID_RANGEFINDER, tel, CTX)).distance == pytest.approx(20.0)
    assert tel.sensors_present & SensorFlag.OPTICAL_FLOW


def test_out_of_range_is_reported_as_unknown():
    core = _core(10)
    core.on_flow(FlowReading(1.0, (math.nan, math.nan), (0.0, 0.0), math.nan, 0))
    tel = core.telemetry()
    assert encode(M.MAVLINK_MSG_ID_OPTICAL_FLOW, tel, CTX).ground_distance == -1.0
    assert encode(M.MAVLINK_MSG_ID_DISTANCE_SENSOR, tel, CTX).current_distance == 0
    assert encode(M.MAVLINK_MSG_ID_RANGEFINDER, tel, CTX).distance == 0.0


@pytest.mark.parametrize("flow_type, sample", [(0, True), (10, False)])
def test_nothing_is_sent_without_the_sensor(flow_type, sample):
    core = _core(flow_type)
    if sample:
        core.on_flow(FlowReading(1.0, (0.0, 0.0), (0.0, 0.0), 5.0, 255))
    tel = core.telemetry()
    assert all(encode(i, tel, CTX) is None for i in FLOW_IDS)
    assert not tel.sensors_present & SensorFlag.OPTICAL_FLOW


def test_distance_sensor_limits_follow_the_rngfnd_parameters():
    core = _core(10)
    assert core.params.set("RNGFND1_MIN_CM", 50).ok and core.params.set("RNGFND1_MAX_CM", 10000).ok
    core.on_flow(FlowReading(2.0, (0.0, 0.0), (0.0, 0.0), 85.0, 150))
    dist = _wire(encode(M.MAVLINK_MSG_ID_DISTANCE_SENSOR, core.telemetry(), CTX))
    assert (dist.min_distance, dist.max_distance, dist.current_distance) == (50, 10000, 8500)
