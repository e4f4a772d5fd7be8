"""The bottom layer's assistant-map and route file formats: round trips and one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from scenenav.core.errors import UserError
from scenenav.core.formats.assistant_map_file import (
    AssistantMapFile,
    check_map_matches_world,
    read_assistant_map_file,
    read_probability_map,
    write_assistant_map_file,
)
from scenenav.core.formats.route_file import (
    WPL_HEADER,
    MavCmd,
    MavFrame,
    MissionItem,
    read_route_file,
    round_or_none,
    wpl_lines,
    write_route_json,
)
from scenenav.core.formats.world_manifest import WorldManifest


def _world(w=40, h=30, m_per_px=0.5) -> WorldManifest:
    return WorldManifest(1, "w", w, h, m_per_px, 48.0, 11.0, "generated", None, False, False)


def test_assistant_map_file_round_trip(tmp_path):
    prob = np.full((30, 40), np.nan, np.float32)
    prob[5:10, 5:10] = 0.25
    f = AssistantMapFile(prob, 0.5, world_name="w", method="cnn", stride_px=5, model_id="m",
                         created_utc="2026-01-01T00:00:00+00:00")
    path = write_assistant_map_file(tmp_path / "map", f)
    assert path.name == "map.npz"
    back = read_assistant_map_file(path, width_px=40, height_px=30, m_per_px=0.5)
    assert np.array_equal(back.probability, prob, equal_nan=True)
    assert (back.world_name, back.method, back.stride_px, back.model_id, back.created_utc) == (
        "w", "cnn", 5, "m", "2026-01-01T00:00:00+00:00")
    with pytest.raises(UserError, match="expected 41x30 px"):
        read_assistant_map_file(path, width_px=41, height_px=30)
    # the planner's reader takes the same file, and any npz holding a probability grid
    grid = read_probability_map(path)
    assert grid.metadata["world_name"] == "w" and grid.probability.shape == (30, 40)
    check_map_matches_world(grid, _world(), path)
    with pytest.raises(UserError, match="m_per_px"):
        check_map_matches_world(grid, _world(m_per_px=1.0), path)


def test_bare_probability_grid_and_bad_files(tmp_path):
    bare = tmp_path / "bare.npz"
    np.savez(bare, probability=np.zeros((30, 40), np.float32))
    assert read_probability_map(bare).metadata == {}
    with pytest.raises(UserError, match="not an assistant map"):
        read_assistant_map_file(bare)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"no zip")
    for reader in (read_probability_map, read_assistant_map_file):
        with pytest.raises(UserError):
            reader(junk)


def test_route_file_round_trip_and_wpl(tmp_path):
    doc = {"format_version": 1, "length_m": 12.5, "min_clearance_m": round_or_none(float("inf")),
           "waypoints": [{"x_m": 0.0, "y_m": 1.0, "lat": 48.0, "lon": 11.0},
                         {"x_m": 3.0, "y_m": 4.0, "lat": 48.1, "lon": 11.1}]}
    write_route_json(tmp_path / "route.json", doc)
    assert json.loads((tmp_path / "route.json").read_text()) == doc
    r = read_route_file(tmp_path / "route.json")
    assert r.waypoints_xy_m == ((0.0, 1.0), (3.0, 4.0)) and r.length_m == 12.5
    assert r.min_clearance_m is None
    (tmp_path / "bad.json").write_text("[1, 2]")
    with pytest.raises(UserError, match="not a route file"):
        read_route_file(tmp_path / "bad.json")
    lines = wpl_lines([MissionItem(MavFrame.GLOBAL, MavCmd.NAV_WAYPOINT, 48.0, 11.0, 500.0),
                       MissionItem(MavFrame.GLOBAL_RELATIVE_ALT, MavCmd.NAV_TAKEOFF, 48.0, 11.0, 100.0)])
    assert lines[0] == WPL_HEADER
    assert lines[1].split("\t")[:4] == ["0", "1", "0", "16"]
    assert lines[2].split("\t")[:4] == ["1", "0", "3", "22"]
    assert lines[2].split("\t")[10] == "100.000"
