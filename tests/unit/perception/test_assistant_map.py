"""Assistant map: patches, lookup, binary, save/load, PNG legend, offline builder."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from perception.assistant_map import (
    GREY_FALSE,
    GREY_TRUE,
    GREY_UNVISITED,
    RGB_UNVISITED_CONTINUOUS,
    AssistantMap,
    Cell,
    RenderMode,
    build_assistant_map,
)
from scenenav.core.errors import UserError


def make_map() -> AssistantMap:
    return AssistantMap(40, 30, 0.53, world_name="test-world", method="cnn", model_id="m1")


def test_new_map_is_unvisited():
    am = make_map()
    assert am.probability.shape == (30, 40) and am.probability.dtype == np.float32
    assert am.coverage() == 0.0
    assert math.isnan(am.lookup(10.0, 10.0))
    assert math.isnan(am.lookup(-1.0, 5.0)) and math.isnan(am.lookup(40.0, 5.0))
    assert math.isnan(am.lookup(float("nan"), 5.0))
    assert np.all(am.binary() == Cell.UNVISITED)


def test_write_patch_and_lookup():
    am = make_map()
    am.write_patch(10.5, 20.5, 5, 0.8)                 # pixel (10, 20): columns 8..12, rows 18..22
    p = am.probability
    assert np.all(p[18:23, 8:13] == np.float32(0.8))
    assert np.count_nonzero(~np.isnan(p)) == 25
    assert am.coverage() == pytest.approx(25 / (40 * 30))
    assert am.lookup(12.9, 22.1) == pytest.approx(0.8)
    assert math.isnan(am.lookup(13.0, 20.0))
    am.write_patch(3.2, 3.7, 0.2, 0.1)                 # below 1 px -> 1 px
    assert am.lookup(3.0, 3.0) == pytest.approx(0.1) and np.count_nonzero(~np.isnan(p)) == 26
    am.write_patch(39.9, 0.1, 4, 0.3)                  # clipped at the corner
    assert np.count_nonzero(p == np.float32(0.3)) == 2 * 3
    am.write_patch(10.5, 20.5, 1, 0.2)                 # overwrite (a newer classification)
    assert am.lookup(10.5, 20.5) == pytest.approx(0.2)
    with pytest.raises(ValueError):
        am.write_patch(5, 5, 3, 1.5)


def test_binary_threshold():
    am = make_map()
    am.write_patch(1.5, 1.5, 1, 0.49)
    am.write_patch(2.5, 1.5, 1, 0.5)
    b = am.binary()
    assert b.dtype == np.int8
    assert b[1, 1] == Cell.FALSE and b[1, 2] == Cell.TRUE and b[0, 0] == Cell.UNVISITED


def test_save_load_round_trip(tmp_path):
    am = make_map()
    am.write_patch(5.5, 5.5, 3, 0.25)
    am.write_patch(30.5, 20.5, 4, 0.75)
    path = am.save(tmp_path / "amap.npz")
    back = AssistantMap.load(path, width_px=40, height_px=30, m_per_px=0.53)
    np.testing.assert_array_equal(back.probability, am.probability)   # NaNs in the same places
    assert (back.world_name, back.method, back.model_id, back.stride_px) == ("test-world", "cnn", "m1", 0)
    assert back.created_utc == am.created_utc and back.m_per_px == 0.53
    with np.load(path) as data:
        assert {"probability", "world_name", "width_px", "height_px", "m_per_px", "created_utc",
                "method", "stride_px", "model_id"} <= set(data.files)


def _one_line_user_error(excinfo) -> None:
    msg = str(excinfo.value)
    assert "\n" not in msg and msg


def test_load_errors(tmp_path):
    path = make_map().save(tmp_path / "a.npz")
    with pytest.raises(UserError) as e:
        AssistantMap.load(path, width_px=41, height_px=30)
    _one_line_user_error(e)
    assert "41x30" in str(e.value)
    with pytest.raises(UserError) as e:
        AssistantMap.load(path, m_per_px=1.0)
    _one_line_user_error(e)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(UserError) as e:
        AssistantMap.load(junk)
    _one_line_user_error(e)
    other = tmp_path / "other.npz"
    np.savez(other, something=np.zeros(3))
    with pytest.raises(UserError) as e:
        AssistantMap.load(other)
    _one_line_user_error(e)
    with pytest.raises(UserError):
        AssistantMap.load(tmp_path / "missing.npz")


def test_png_legend(tmp_path):
    am = make_map()
    am.write_patch(5.5, 5.5, 1, 0.1)     # false match expected -> black
    am.write_patch(6.5, 5.5, 1, 0.9)     # true -> white
    png = am.render_png(tmp_path / "amap.png")
    img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    assert img.shape == (30, 40)
    assert img[5, 5] == GREY_FALSE == 0
    assert img[5, 6] == GREY_TRUE == 255
    assert img[0, 0] == GREY_UNVISITED == 128
    png2 = am.render_png(tmp_path / "amap_cont.png", mode=RenderMode.CONTINUOUS)
    rgb = cv2.cvtColor(cv2.imread(str(png2), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert tuple(rgb[5, 6]) == (230, 230, 230)
    assert tuple(rgb[5, 5]) == (26, 26, 26)
    assert tuple(rgb[0, 0]) == RGB_UNVISITED_CONTINUOUS


def _variance_classifier(batch: np.ndarray) -> np.ndarray:
    """Fake CNN: a flat crop (low variance) is a bad matching area."""
    assert batch.ndim == 3 and batch.dtype == np.float32 and batch.shape[1:] == (20, 20)
    var = batch.reshape(batch.shape[0], -1).var(axis=1)
    return (var < 1e-3).astype(np.float32)


def test_builder_fills_the_map():
    rng = np.random.default_rng(0)
    ref = np.full((120, 160), 128, np.uint8)
    ref[:, 80:] = rng.integers(0, 256, (120, 80), dtype=np.uint8)      # textured east half
    calls = []
    # Footprint 2 * 10 * tan(30 deg) / 0.5 = 23.09 -> 23 px.
    am = build_assistant_map(ref, _variance_classifier, 0.5, altitude_m=10.0, fov_deg=60.0,
                             stride_px=4, batch_size=16, progress=lambda d, t: calls.append((d, t)),
                             cnn_input_px=20, world_name="w")
    p = am.probability
    assert am.stride_px == 4 and am.world_name == "w"
    assert calls and calls[-1][0] == calls[-1][1] > 0
    # Edges (half a footprint) stay unvisited; the inside is filled.
    assert np.isnan(p[0, 0]) and np.isnan(p[-1, -1])
    assert np.all(~np.isnan(p[16:104, 16:144]))
    assert np.all(p[20:100, 20:60] == 0.0)        # flat: false match expected
    assert np.all(p[20:100, 104:140] == 1.0)      # textured: true match expected
    assert 0.4 < am.coverage() < 0.9
    # Nearest fill of the edge band; (N, 4) softmax outputs are accepted too.
    am2 = build_assistant_map(ref, lambda b: np.stack([_variance_classifier(b)] + [np.zeros(len(b))] * 3, 1),
                              0.5, altitude_m=10.0, stride_px=4, cnn_input_px=20, fill_edges=True)
    assert am2.coverage() == 1.0
    assert am2.probability[0, 0] == 0.0 and am2.probability[-1, -1] == 1.0
