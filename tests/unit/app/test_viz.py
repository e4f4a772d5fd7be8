"""The view channels (scenenav/app/viz.py) that bus.mcap records and the live view streams."""

from __future__ import annotations

import base64
import json
import math

import numpy as np

from scenenav.app.viz import (
    PATH_STEP_S,
    POSE_STEP_S,
    T_CAMERA,
    T_FIXES,
    T_ROUTE,
    T_TRUTH_PATH,
    T_TRUTH_POSE,
    VizState,
    bus_schema,
    map_grid,
)
from scenenav.core.contracts import CameraFrame, Event, Severity, TruthPose, VisionFix

NAN4 = (math.nan,) * 4


def _truth(t_s: float, x: float) -> TruthPose:
    return TruthPose(int(t_s * 1e6), (x, 2.0, 100.0), (0, 0, 0), (1.0, 0.0, 0.0, 0.0), (0, 0, 0), 0.0)


def _fix(seq: int, valid: bool, accepted: bool) -> VisionFix:
    return VisionFix(seq * 100_000, seq, "my_node", "cnn", valid, accepted,
                     (10.0, -5.0) if valid else (math.nan, math.nan), (1, 0, 0, 1), 0.9, NAN4,
                     0.5, 10.0, 0.5, 1, 1, 1, 1, 4)


def _json(v) -> dict:
    return json.loads(v.payload)


def test_poses_are_throttled_and_the_path_grows_one_pose_per_step():
    viz = VizState()
    out = [m for i in range(int(3 / 0.01)) for m in viz.on_message(_truth(i * 0.01, float(i)))]
    poses = [m for m in out if m.topic == T_TRUTH_POSE]
    paths = [m for m in out if m.topic == T_TRUTH_PATH]
    assert len(poses) == round(3 / POSE_STEP_S)
    assert len(paths) == round(3 / PATH_STEP_S)
    last = _json(paths[-1])
    assert last["frame_id"] == "world" and len(last["poses"]) == len(paths)
    p = _json(poses[1])["pose"]
    assert p["position"] == {"x": 10.0, "y": 2.0, "z": 100.0}          # 0.1 s: the 10th sample
    assert p["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    assert poses[1].schema_name == "foxglove.PoseInFrame"
    assert json.loads(poses[1].schema)["title"] == "foxglove.PoseInFrame"


def test_a_long_path_is_thinned_to_a_bounded_size_and_still_spans_the_flight():
    viz = VizState(path_max_poses=10)
    sizes, last = [], None
    for i in range(200):                      # 200 s of truth at 1 Hz (one path step each)
        for m in viz.on_message(_truth(float(i), float(i))):
            if m.topic == T_TRUTH_PATH:
                last = _json(m)
                sizes.append(len(last["poses"]))
    assert max(sizes) <= 10
    xs = [p["position"]["x"] for p in last["poses"]]
    assert xs == sorted(xs) and xs[0] == 0.0 and xs[-1] >= 199.0 - 32.0    # first pose kept, recent end
    assert len(sizes) < 200 / 2               # the step grew: fewer path messages than seconds


def test_fixes_are_spheres_coloured_by_the_verdict_and_invalid_ones_are_not_drawn():
    viz = VizState()
    acc, rej = viz.on_message(_fix(1, True, True)), viz.on_message(_fix(2, True, False))
    assert viz.on_message(_fix(3, False, False)) == []
    (a,), (r,) = acc, rej
    assert a.topic == r.topic == T_FIXES
    ea, er = _json(a)["entities"][0], _json(r)["entities"][0]
    assert ea["id"] == "my_node/1" and er["id"] == "my_node/2"       # one entity per fix, kept
    assert ea["spheres"][0]["color"]["g"] > 0.5 > ea["spheres"][0]["color"]["r"]
    assert er["spheres"][0]["color"]["r"] > 0.5 > er["spheres"][0]["color"]["g"]
    assert ea["spheres"][0]["pose"]["position"]["x"] == 10.0


def test_camera_frames_every_nth_as_raw_image():
    viz = VizState(camera_every_n=2)
    px = np.arange(4 * 3 * 3, dtype=np.uint8).reshape(4, 3, 3)
    frames = [CameraFrame(i * 100_000, i, 3, 4, "rgb8", 60.0, "gimbal", (2.6, 2.6, 1.5, 2.0), (0.0, 0.0, 0.0, 0.0), px)
              for i in range(4)]
    out = [m for f in frames for m in viz.on_message(f)]
    assert [m.topic for m in out] == [T_CAMERA, T_CAMERA]
    img = _json(out[1])
    assert (img["width"], img["height"], img["step"], img["encoding"]) == (3, 4, 9, "rgb8")
    assert base64.b64decode(img["data"]) == px.tobytes()
    assert img["timestamp"] == {"sec": 0, "nsec": 200_000_000}


def test_events_become_log_lines_with_foxglove_levels():
    viz = VizState()
    (m,) = viz.on_message(Event(1_500_000, "autopilot", int(Severity.WARNING), "vision lost"))
    log = _json(m)
    assert m.schema_name == "foxglove.Log"
    assert (log["level"], log["message"], log["name"]) == (3, "vision lost", "autopilot")


def test_a_map_grid_is_north_up_centred_on_the_origin():
    img = np.zeros((4, 6, 3), np.uint8)
    img[0, :, 0] = 255                      # the north row is red
    g = map_grid(img, 2.0, 0, 0.0)
    assert g["pose"]["position"] == {"x": -6.0, "y": -4.0, "z": 0.0}   # 12 m x 8 m
    assert g["column_count"] == 6 and g["cell_size"] == {"x": 2.0, "y": 2.0}
    cells = np.frombuffer(base64.b64decode(g["data"]), np.uint8).reshape(4, 6, 4)
    assert (cells[-1, :, 0] == 255).all() and (cells[0, :, 0] == 0).all()   # grid row 0 is south
    assert [f["name"] for f in g["fields"]] == ["red", "green", "blue", "alpha"]
    prob = np.full((2, 2), np.nan, np.float32)
    prob[1, 0] = 0.25
    gp = map_grid(prob, 1.0, 0, 0.5)
    vals = np.frombuffer(base64.b64decode(gp["data"]), "<f4").reshape(2, 2)
    assert vals[0, 0] == 0.25 and np.isnan(vals[1, 1]) and gp["fields"][0]["name"] == "p_bad"


def test_big_maps_are_downsampled():
    g = map_grid(np.zeros((2000, 1000, 3), np.uint8), 0.5, 0, 0.0)
    assert g["column_count"] == 250 and g["cell_size"]["x"] == 2.0


def test_route_files_are_drawn_once_each(tmp_path):
    from scenenav.core.formats.route_file import write_route_json
    write_route_json(tmp_path / "route.json", {"waypoints": [{"x_m": x, "y_m": y} for x, y in
                                                             ((0, 0), (10, 5), (20, 0))],
                                               "length_m": 22.4, "min_clearance_m": 3.0})
    viz = VizState()
    (m,) = viz.route_messages(tmp_path, 5_000_000)
    line = _json(m)["entities"][0]["lines"][0]
    assert m.topic == T_ROUTE and [(p["x"], p["y"]) for p in line["points"]] == [(0, 0), (10, 5), (20, 0)]
    assert viz.route_messages(tmp_path, 6_000_000) == []


def test_bus_schema_names_the_message_fields():
    name, data = bus_schema("VisionFix")
    props = json.loads(data)["properties"]
    assert name == "scenenav.VisionFix"
    assert props["node_id"] == {"type": "string"} and props["accepted"] == {"type": "boolean"}


def test_the_shipped_layout_is_the_generated_one_and_names_view_channels_only():
    from pathlib import Path

    from scenenav.app import viz
    from scenenav.app.foxglove_layout import layout_json
    shipped = Path(__file__).resolve().parents[3] / "docs" / "foxglove-layout.json"
    assert shipped.read_text() == layout_json(), \
        "regenerate: python -m scenenav.app.foxglove_layout > docs/foxglove-layout.json"
    text = shipped.read_text()
    topics = {v for k, v in vars(viz).items() if k.startswith("T_")}
    assert all(f'"{t}' in text for t in topics)          # every view channel has a place
    assert "scenenav/" not in text                         # no run namespace in the layout


def test_the_lichtblick_layout_is_the_same_layout_in_studios_older_format():
    from pathlib import Path

    from scenenav.app.foxglove_layout import layout_json, lichtblick_layout, lichtblick_layout_json
    shipped = Path(__file__).resolve().parents[3] / "docs" / "lichtblick-layout.json"
    assert shipped.read_text() == lichtblick_layout_json(), \
        "regenerate: python -m scenenav.app.foxglove_layout --lichtblick > docs/lichtblick-layout.json"
    new, old = json.loads(layout_json()), json.loads(shipped.read_text())

    def panels(c):           # the Foxglove format's panels, in order
        return [c] if c["type"] == "panel" else [p for i in c["items"] for p in panels(i["content"])]

    def leaves(t):            # the binary tree's panel ids, in order
        return [t] if isinstance(t, str) else leaves(t["first"]) + leaves(t["second"])

    assert leaves(old["layout"]) == list(old["configById"])
    for panel, pid in zip(panels(new["content"]), leaves(old["layout"]), strict=True):
        kind = {"ThreeDee": "3D", "Log": "RosOut"}.get(panel["panelType"], panel["panelType"])
        assert pid.startswith(kind + "!")
        assert old["configById"][pid] == {**panel["config"], "foxglovePanelTitle": panel["title"]}
    # three items 2:1:1 -> 50 % then 50 % of the rest
    tree = lichtblick_layout({"content": {"type": "split", "direction": "column", "items": [
        {"proportion": p, "content": {"type": "panel", "panelType": "Log", "config": {}}}
        for p in (2, 1, 1)]}})["layout"]
    assert (tree["splitPercentage"], tree["second"]["splitPercentage"]) == (50.0, 50.0)


# --- the schemas are complete enough for viewers that read them (Lichtblick's JSON-schema reader
# --- turns them into datatypes and refuses an array without items or an unknown type)
_SCALARS = {"boolean": bool, "string": str, "number": (int, float), "integer": int}


def _readable(schema: dict, where: str) -> None:
    """The rules of a JSON-schema-to-datatypes reader: objects with properties, scalars, base64
    strings, arrays whose items have one of these types."""
    assert schema.get("type") == "object", f"{where}: not an object"
    for name, field in schema.get("properties", {}).items():
        at = f"{where}.{name}"
        kind = field.get("type")
        if kind == "array":
            items = field.get("items")
            assert isinstance(items, dict) and items.get("type") in (*_SCALARS, "object"), \
                f"{at}: an array needs items of a known type"
            assert "contentEncoding" not in items, at
            if items["type"] == "object":
                _readable(items, at + "[]")
        elif kind == "object":
            _readable(field, at)
        else:
            assert kind in _SCALARS, f"{at}: type {kind!r}"
            assert field.get("contentEncoding") in (None, "base64"), at


def _conforms(value, schema: dict, where: str) -> None:
    """Every field of a payload is declared with its JSON type (null allowed: NaN-free optionals)."""
    if value is None:
        return
    kind = schema["type"]
    if kind == "object":
        assert isinstance(value, dict), where
        undeclared = set(value) - set(schema.get("properties", {}))
        assert not undeclared, f"{where}: undeclared {sorted(undeclared)}"
        for k, v in value.items():
            _conforms(v, schema["properties"][k], f"{where}.{k}")
    elif kind == "array":
        assert isinstance(value, list), where
        for i, v in enumerate(value):
            _conforms(v, schema["items"], f"{where}[{i}]")
    else:
        assert isinstance(value, _SCALARS[kind]) and not (kind != "boolean" and isinstance(value, bool)), \
            f"{where}: {value!r} is not {kind}"


def test_every_schema_is_readable_and_every_view_payload_conforms(tmp_path):
    from scenenav.app.viz import FOXGLOVE_SCHEMAS, foxglove_schema
    from scenenav.core.contracts import MESSAGE_TYPES
    from scenenav.core.formats.route_file import write_route_json
    for name in FOXGLOVE_SCHEMAS:
        _readable(json.loads(foxglove_schema(name)), name)
    for cls in MESSAGE_TYPES:
        _readable(json.loads(bus_schema(cls.__name__)[1]), cls.__name__)
    write_route_json(tmp_path / "route.json", {"waypoints": [{"x_m": 0, "y_m": 0}, {"x_m": 5, "y_m": 5}],
                                               "length_m": 7.1, "min_clearance_m": 3.0})
    viz = VizState()
    px = np.zeros((4, 3, 3), np.uint8)
    out = [*viz.on_message(_truth(0.0, 1.0)), *viz.on_message(_truth(1.0, 2.0)),
           *viz.on_message(_fix(1, True, True)),
           *viz.on_message(CameraFrame(0, 0, 3, 4, "rgb8", 60.0, "gimbal", (2.6, 2.6, 1.5, 2.0),
                                       (0.0, 0.0, 0.0, 0.0), px)),
           *viz.on_message(Event(1, "autopilot", int(Severity.INFO), "hello")),
           *viz.route_messages(tmp_path, 0)]
    grids = [map_grid(np.zeros((4, 4, 3), np.uint8), 1.0, 0, 0.0),
             map_grid(np.full((4, 4), 0.5, np.float32), 1.0, 0, 0.5)]
    kinds = {m.schema_name for m in out}
    assert {"foxglove.PoseInFrame", "foxglove.PosesInFrame", "foxglove.SceneUpdate",
            "foxglove.RawImage", "foxglove.Log"} <= kinds
    for m in out:
        _conforms(_json(m), json.loads(m.schema), m.topic)
    for g in grids:
        _conforms(g, FOXGLOVE_SCHEMAS["foxglove.Grid"], "grid")
