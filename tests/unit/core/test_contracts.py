"""Encode/decode round trips for every bus message, and garbage handling."""

import dataclasses
import json
import math
import typing

import numpy as np
import pytest

from scenenav.core import contracts as c


def _sample_value(tp, i):
    if tp is float:
        return 0.5 + i
    if tp is int:
        return 3 + i
    if tp is bool:
        return i % 2 == 0
    if tp is str:
        return f"s{i}"
    if typing.get_origin(tp) is tuple:
        return tuple(_sample_value(a, i + k) for k, a in enumerate(typing.get_args(tp)))
    raise AssertionError(tp)


def sample(cls):
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for i, f in enumerate(dataclasses.fields(cls)):
        if f.name == "pixels":
            kwargs["pixels"] = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
        else:
            kwargs[f.name] = _sample_value(hints[f.name], i)
    if cls is c.CameraFrame:
        kwargs.update(width_px=5, height_px=4, encoding="rgb8")
    return cls(**kwargs)


@pytest.mark.parametrize("cls", c.MESSAGE_TYPES, ids=lambda k: k.__name__)
def test_round_trip(cls):
    msg = sample(cls)
    out = c.decode(cls, c.encode(msg))
    assert out == msg
    if cls is c.CameraFrame:
        np.testing.assert_array_equal(out.pixels, msg.pixels)


def test_every_message_has_version_and_timestamp():
    for cls in c.MESSAGE_TYPES:
        assert isinstance(cls.VERSION, int)
        names = [f.name for f in dataclasses.fields(cls)]
        assert names[0] == "timestamp_us", cls


def test_nan_travels_as_null():
    fix = sample(c.VisionFix)
    fix = dataclasses.replace(fix, p_true=math.nan, valid=False)
    raw = c.encode(fix)
    assert json.loads(raw)["p_true"] is None
    assert math.isnan(c.decode(c.VisionFix, raw).p_true)


@pytest.mark.parametrize("payload", [
    b"", b"\x00\xff\xfe", b"[1,2]", b'{"type":"ImuSample","version":1}',
    b'{"type":"ImuSample","version":99,"timestamp_us":1}',
    b'{"type":"BaroSample","version":1,"timestamp_us":1,"altitude_m":1,"pressure_pa":1}',
])
def test_garbage_raises_decode_error_only(payload):
    with pytest.raises(c.DecodeError):
        c.decode(c.ImuSample, payload)


def test_wrong_field_types_rejected():
    obj = json.loads(c.encode(sample(c.ImuSample)))
    obj["accel_flu_m_s2"] = [1, 2]
    with pytest.raises(c.DecodeError):
        c.decode(c.ImuSample, json.dumps(obj).encode())
    obj = json.loads(c.encode(sample(c.MotorCommand)))
    obj["armed"] = "yes"
    with pytest.raises(c.DecodeError):
        c.decode(c.MotorCommand, json.dumps(obj).encode())


def test_truncated_camera_frame():
    raw = c.encode(sample(c.CameraFrame))
    for cut in (0, 3, 10, len(raw) - 1):
        with pytest.raises(c.DecodeError):
            c.decode(c.CameraFrame, raw[:cut])
    bad = bytearray(raw)
    bad[0:4] = (10**9).to_bytes(4, "little")
    with pytest.raises(c.DecodeError):
        c.decode(c.CameraFrame, bytes(bad))


def test_camera_header_states_shape_and_encoding():
    raw = c.encode(sample(c.CameraFrame))
    n = int.from_bytes(raw[:4], "little")
    header = json.loads(raw[4:4 + n])
    assert header["width_px"] == 5 and header["height_px"] == 4 and header["encoding"] == "rgb8"
    assert len(raw) - 4 - n == 4 * 5 * 3


def test_vision_fix_versions_1_and_2_are_still_read():
    """VisionFix version 2 added the measured heading, version 3 the camera flow; a message of an
    older version (an outside node written against the earlier interface) decodes with NaN (and a
    0 flow interval) there. Other versions, and a message missing a field its own version has, are
    refused."""
    fix = sample(c.VisionFix)
    obj = json.loads(c.encode(fix))
    assert obj["version"] == 3 and obj["heading_rad"] == fix.heading_rad
    flow_fields = ("flow_flu_rad_s", "flow_interval_us", "flow_quality")
    v2 = {k: v for k, v in obj.items() if k not in flow_fields}
    v2["version"] = 2
    old2 = c.decode(c.VisionFix, json.dumps(v2).encode())
    assert old2.heading_rad == fix.heading_rad and old2.flow_interval_us == 0
    assert all(math.isnan(v) for v in (*old2.flow_flu_rad_s, old2.flow_quality))
    v1 = {k: v for k, v in v2.items() if k not in ("heading_rad", "heading_std_rad")}
    v1["version"] = 1
    old = c.decode(c.VisionFix, json.dumps(v1).encode())
    assert math.isnan(old.heading_rad) and math.isnan(old.heading_std_rad)
    assert old.position_xy_enu_m == fix.position_xy_enu_m and old.frame_seq == fix.frame_seq
    for bad in (dict(v1, version=2), dict(v1, version=3), dict(v2, version=3), dict(v1, version=4),
                dict(v1, version=True), dict(v1, version="1")):
        with pytest.raises(c.DecodeError):
            c.decode(c.VisionFix, json.dumps(bad).encode())
    # a version-1 message still has to carry every version-1 field
    with pytest.raises(c.DecodeError, match="missing field 'ncc_peak'"):
        c.decode(c.VisionFix, json.dumps({k: v for k, v in v1.items() if k != "ncc_peak"}).encode())
