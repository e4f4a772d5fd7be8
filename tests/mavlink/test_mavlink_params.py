"""Parameter store and the MAVLink parameter protocol over real TCP."""

from __future__ import annotations

import json
import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from support import REPO_ROOT
from support.fake_vehicle import gcs_connection, running_server, wait_for

from autopilot_bridge.params import DEFAULT_PARAM_SPECS, ParameterStore, ParamType
from scenenav.core.errors import UserError

REQUIRED = ("WPNAV_SPEED", "WPNAV_SPEED_UP", "WPNAV_SPEED_DN", "WPNAV_ACCEL", "WPNAV_RADIUS",
            "RTL_ALT", "LAND_SPEED", "PILOT_SPEED_UP", "ANGLE_MAX", "FS_GCS_ENABLE",
            "FS_GCS_TIMEOUT", "EK3_SRC1_POSXY", "EK3_SRC1_VELXY", "EK3_SRC1_POSZ",
            "FS_EKF_ACTION", "VISO_TYPE", "SYSID_THISMAV", "SYSID_MYGCS", "ARMING_CHECK",
            "FRAME_CLASS", "FRAME_TYPE", "BATT_MONITOR")


# ----------------------------------------------------------------------------- store


def test_required_parameters_and_arducopter_defaults():
    store = ParameterStore()
    for name in REQUIRED:
        assert name in store, name
    assert store.get("WPNAV_SPEED") == 1000.0
    assert store.get("RTL_ALT") == 1500
    assert store.spec("WPNAV_SPEED").ptype == ParamType.REAL32
    assert store.spec("FRAME_CLASS").ptype == ParamType.INT8
    assert store.names() == [s.name for s in DEFAULT_PARAM_SPECS]


def test_param_type_values_match_mavlink():
    assert ParamType.INT8 == mavlink2.MAV_PARAM_TYPE_INT8
    assert ParamType.INT16 == mavlink2.MAV_PARAM_TYPE_INT16
    assert ParamType.INT32 == mavlink2.MAV_PARAM_TYPE_INT32
    assert ParamType.REAL32 == mavlink2.MAV_PARAM_TYPE_REAL32


@pytest.mark.parametrize("name,value", [("FS_GCS_ENABLE", 2), ("FS_GCS_ENABLE", 6),
                                        ("FRAME_CLASS", 2), ("RTL_ALT", math.nan),
                                        ("WPNAV_SPEED", math.inf), ("WPNAV_SPEED", 1e39),
                                        ("DISARM_DELAY", 128), ("RTL_ALT", 2 ** 31)])
def test_not_implemented_or_not_of_the_type_refused_and_old_value_kept(name, value):
    store = ParameterStore()
    before = store.get(name)
    result = store.set(name, value)
    assert not result.ok and result.reason
    assert result.value == before == store.get(name)


@pytest.mark.parametrize("name,value", [("WPNAV_SPEED", 2500.0), ("ARMING_CHECK", -5),
                                        ("FS_EKF_THRESH", 3.0), ("RTL_LOIT_TIME", 600000),
                                        ("BATT_CAPACITY", 5_000_000)])
def test_any_value_of_the_type_is_stored_as_arducopter(name, value):
    """The documented range is ground-station metadata (ArduPilot's @Range): beyond it, within the
    type and the safe limits, the value is stored as sent."""
    store = ParameterStore()
    spec = store.spec(name)
    assert not spec.min_value <= value <= spec.max_value
    result = store.set(name, value)
    assert result.ok and not result.reason and store.get(name) == pytest.approx(value)


@pytest.mark.parametrize("name,value,stored", [("WPNAV_SPEED", 5.0, 20.0), ("ANGLE_MAX", 9000, 8000),
                                               ("SYSID_THISMAV", 0, 1), ("LAND_SPEED", 0, 30),
                                               ("RTL_ALT", -100, 30), ("WPNAV_RADIUS", 1.0, 5.0)])
def test_unsafe_values_are_clamped_and_say_so(name, value, stored):
    store = ParameterStore()
    result = store.set(name, value)
    assert result.ok and store.get(name) == stored == result.value
    assert "clamped" in result.reason and name in result.reason


def test_integer_parameters_convert_like_arducopter_and_observers_fire():
    store = ParameterStore()
    seen = []
    store.add_observer(lambda n, v: seen.append((n, v)))
    assert store.set("RTL_ALT", 2000.995).value == 2001   # +0.01 then truncation
    assert store.set("RTL_ALT", 2000.4).value == 2000
    assert store.set("RTL_ALT", 2000.0).ok                # no change: no notification
    assert seen == [("RTL_ALT", 2001.0), ("RTL_ALT", 2000.0)]
    assert not store.set("NO_SUCH_PARAM", 1).ok


def test_persistence_round_trip(tmp_path):
    path = tmp_path / "params.json"
    store = ParameterStore(path=path)
    store.set("WPNAV_SPEED", 1234.5)
    store.set("FS_GCS_ENABLE", 5)
    again = ParameterStore(path=path)
    assert again.get("WPNAV_SPEED") == pytest.approx(1234.5)
    assert again.get("FS_GCS_ENABLE") == 5
    assert json.loads(path.read_text())["FS_GCS_ENABLE"] == 5


def test_bad_parameter_file_is_a_user_error(tmp_path):
    path = tmp_path / "params.json"
    path.write_text("{not json")
    with pytest.raises(UserError, match="params.json"):
        ParameterStore(path=path)
    path.write_text(json.dumps({"FS_GCS_ENABLE": 2}))          # not implemented
    with pytest.raises(UserError, match="FS_GCS_ENABLE"):
        ParameterStore(path=path)
    path.write_text(json.dumps({"WPNAV_SPEED": "fast"}))
    with pytest.raises(UserError, match="WPNAV_SPEED"):
        ParameterStore(path=path)
    path.write_text(json.dumps({"WPNAV_SPEED": 1.0}))           # clamped, with a warning
    assert ParameterStore(path=path).get("WPNAV_SPEED") == 20.0


# ----------------------------------------------------------------------------- protocol


def test_param_request_list_yields_all_with_count_and_index():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            conn.mav.param_request_list_send(1, 1)
            store = server.params
            got: dict[int, mavlink2.MAVLink_message] = {}
            while len(got) < store.count:
                msg = wait_for(conn, "PARAM_VALUE", timeout_s=10.0)
                assert msg is not None, f"only {len(got)} of {store.count} parameters"
                assert msg.param_count == store.count
                got[msg.param_index] = msg
            assert sorted(got) == list(range(store.count))
            for index, msg in got.items():
                spec, value = store.by_index(index)
                assert msg.param_id == spec.name
                assert msg.param_type == spec.ptype
                assert msg.param_value == pytest.approx(value)
        finally:
            conn.close()


def test_param_read_by_name_and_index_set_and_refuse():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            conn.mav.param_request_read_send(1, 1, b"WPNAV_SPEED", -1)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "WPNAV_SPEED")
            assert msg is not None and msg.param_value == 1000.0
            assert msg.param_index == server.params.index_of("WPNAV_SPEED")

            index = server.params.index_of("RTL_ALT")
            conn.mav.param_request_read_send(1, 1, b"", index)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_index == index)
            assert msg is not None and msg.param_id == "RTL_ALT" and msg.param_value == 1500

            conn.mav.param_set_send(1, 1, b"WPNAV_SPEED", 1500.0, mavlink2.MAV_PARAM_TYPE_REAL32)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "WPNAV_SPEED")
            assert msg is not None and msg.param_value == 1500.0
            assert server.params.get("WPNAV_SPEED") == 1500.0
            assert vehicle.params_seen["WPNAV_SPEED"] == 1500.0

            # beyond the documented range: stored as sent (ArduPilot's ranges are metadata)
            conn.mav.param_set_send(1, 1, b"WPNAV_SPEED", 2500.0, mavlink2.MAV_PARAM_TYPE_REAL32)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "WPNAV_SPEED"
                           and m.param_value != 1500.0)
            assert msg is not None and msg.param_value == 2500.0
            # beyond the safe limit: clamped, and a STATUSTEXT says so
            conn.mav.param_set_send(1, 1, b"WPNAV_SPEED", 1.0, mavlink2.MAV_PARAM_TYPE_REAL32)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "WPNAV_SPEED"
                           and m.param_value != 2500.0)
            assert msg is not None and msg.param_value == 20.0
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "WPNAV_SPEED" in m.text)
            assert text is not None and "clamped to 20" in text.text
            assert server.stats["param_set_clamped"] == 1
            # not implemented: the unchanged value comes back, with a STATUSTEXT saying why
            conn.mav.param_set_send(1, 1, b"FS_GCS_ENABLE", 2.0, mavlink2.MAV_PARAM_TYPE_INT8)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "FS_GCS_ENABLE")
            assert msg is not None and msg.param_value == 0.0
            text = wait_for(conn, "STATUSTEXT", condition=lambda m: "FS_GCS_ENABLE" in m.text)
            assert text is not None and "not supported" in text.text
            assert server.stats["param_set_refused"] == 1

            # NaN: refused too
            conn.mav.param_set_send(1, 1, b"LAND_SPEED", math.nan, mavlink2.MAV_PARAM_TYPE_INT16)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "LAND_SPEED")
            assert msg is not None and msg.param_value == 50
        finally:
            conn.close()


def test_param_set_for_another_system_is_ignored():
    with running_server() as (server, vehicle):
        conn = gcs_connection(server.tcp_port)
        try:
            conn.mav.param_set_send(7, 1, b"WPNAV_SPEED", 1500.0, mavlink2.MAV_PARAM_TYPE_REAL32)
            conn.mav.param_request_read_send(1, 1, b"WPNAV_SPEED", -1)
            msg = wait_for(conn, "PARAM_VALUE", condition=lambda m: m.param_id == "WPNAV_SPEED")
            assert msg is not None and msg.param_value == 1000.0
            assert server.stats["not_for_us"] >= 1
        finally:
            conn.close()


def test_every_parameter_is_documented():
    doc = (REPO_ROOT / "docs" / "mavlink.md").read_text()
    from autopilot_bridge.mode_param_specs import MODE_PARAM_SPECS
    for spec in DEFAULT_PARAM_SPECS + MODE_PARAM_SPECS:
        assert f"| `{spec.name}` | {spec.ptype.name} |" in doc, spec.name
