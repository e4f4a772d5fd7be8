"""Foxglove channels of a run: one definition for ``bus.mcap`` (the recorder) and the live view.

Two kinds of channel, both JSON with a JSON schema:

* the bus itself: every bus message on its own key (``scenenav/<ns>/...``), schema
  ``scenenav.<Type>`` (:func:`bus_schema`), the payload as it travelled;
* the view (:class:`VizState`), on topics without the namespace so one layout
  (``docs/foxglove-layout.json``) opens every run, recorded or live: ``viz/camera``
  (``foxglove.RawImage``, every ``recorder.camera_every_n``-th frame), ``viz/truth/pose`` and
  ``viz/estimate/pose`` (``foxglove.PoseInFrame``, at most every :data:`POSE_STEP_S`), ``viz/truth/path`` and ``viz/estimate/path``
  (``foxglove.PosesInFrame``, one pose per :data:`PATH_STEP_S` of simulated time, thinned past
  :data:`PATH_MAX_POSES` so a message stays bounded however long the flight), ``viz/fixes``
  (``foxglove.SceneUpdate``: a sphere per valid fix, green accepted, red rejected),
  ``viz/route`` (``foxglove.SceneUpdate``: the planned route, one line per route file),
  ``viz/map/reference`` and ``viz/map/assistant`` (``foxglove.Grid``, frame ``world``),
  ``viz/events`` (``foxglove.Log``) and ``viz/autopilot/status`` (``scenenav.AutopilotStatus``).

Frame ``world`` is the world ENU frame in metres (origin at the map centre, see
``scenenav.core.frames``); Foxglove's 3-D panel draws it as x east, y north, z up.
"""

from __future__ import annotations

import base64
import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from scenenav.core.contracts import (
    AutopilotStatus,
    CameraFrame,
    Event,
    NavEstimate,
    Severity,
    TruthPose,
    VisionFix,
    encode,
    message_type,
    schema_of,
)

FRAME_ID = "world"
#: Simulated seconds between two poses sent on a pose channel (10 Hz: the truth comes every tick).
POSE_STEP_S = 0.1
#: Simulated seconds between two poses of a path (a 600 s flight: 600 poses per path).
PATH_STEP_S = 1.0
#: Most poses a path message holds. Every path message carries the whole path, so an unbounded path
#: made ``bus.mcap`` grow with the square of the flight time and the recorder's memory with it (a
#: 30-minute soak: +0.3-0.7 MB a minute). Past this, every other pose is dropped and the step doubles:
#: the path still spans the whole flight, at 1 s resolution up to ~17 minutes, 2 s up to ~33, ...
PATH_MAX_POSES = 1000
#: Largest side of a map grid in cells (the reference map is downsampled to it).
MAP_MAX_CELLS = 512
#: Height above the ground of the drawn maps and fixes (m): the assistant map above the reference.
MAP_Z_M = {"reference": 0.0, "assistant": 0.5}
FIX_SPHERE_M = 4.0

T_CAMERA = "viz/camera"
T_TRUTH_POSE, T_TRUTH_PATH = "viz/truth/pose", "viz/truth/path"
T_EST_POSE, T_EST_PATH = "viz/estimate/pose", "viz/estimate/path"
T_FIXES, T_ROUTE, T_EVENTS = "viz/fixes", "viz/route", "viz/events"
T_MAP_REFERENCE, T_MAP_ASSISTANT = "viz/map/reference", "viz/map/assistant"
T_STATUS = "viz/autopilot/status"

_JSON_TYPES = {"float": "number", "int": "integer", "bool": "boolean", "str": "string"}


@functools.lru_cache(maxsize=None)
def bus_schema(type_name: str) -> tuple[str, bytes]:
    """Schema name and JSON schema of a bus message type as recorded (``scenenav.<Type>``)."""
    cls = message_type(type_name)
    props: dict[str, Any] = {"type": {"type": "string"}, "version": {"type": "integer"}}
    for name, tp in schema_of(cls):
        if name == "pixels":
            continue
        props[name] = ({"type": "array", "items": {"type": "number"}} if tp.startswith("tuple[float")
                       else {"type": _JSON_TYPES[tp]})
    return f"scenenav.{type_name}", json.dumps(
        {"type": "object", "title": cls.__name__, "properties": props}).encode()


# ------------------------------------------------------------------ foxglove schemas (JSON)
def _obj(**props: Any) -> dict:
    return {"type": "object", "properties": props}


_NUM, _INT, _STR = {"type": "number"}, {"type": "integer"}, {"type": "string"}
_TIME = _obj(sec=_INT, nsec=_INT)
_VEC3 = _obj(x=_NUM, y=_NUM, z=_NUM)
_QUAT = _obj(x=_NUM, y=_NUM, z=_NUM, w=_NUM)
_POSE = _obj(position=_VEC3, orientation=_QUAT)
_COLOR = _obj(r=_NUM, g=_NUM, b=_NUM, a=_NUM)
_BYTES = {"type": "string", "contentEncoding": "base64"}
_BOOL = {"type": "boolean"}


def _array(items: dict) -> dict:
    return {"type": "array", "items": items}


#: The parts of the Foxglove message schemas (docs.foxglove.dev, "Message schemas") the view sends.
#: Every array names its items: Lichtblick's JSON-schema reader rejects an array without them.
_SPHERE = _obj(pose=_POSE, size=_VEC3, color=_COLOR)
_LINE = _obj(type=_INT, pose=_POSE, thickness=_NUM, scale_invariant=_BOOL, points=_array(_VEC3),
             color=_COLOR, colors=_array(_COLOR), indices=_array({"type": "integer", "minimum": 0}))
_ENTITY = _obj(timestamp=_TIME, frame_id=_STR, id=_STR, lifetime=_TIME, frame_locked=_BOOL,
               metadata=_array(_obj(key=_STR, value=_STR)), spheres=_array(_SPHERE),
               lines=_array(_LINE))
_DELETION = _obj(timestamp=_TIME, type=_INT, id=_STR)
_GRID_FIELD = _obj(name=_STR, offset=_INT, type=_INT)

FOXGLOVE_SCHEMAS: dict[str, dict] = {
    "foxglove.RawImage": _obj(timestamp=_TIME, frame_id=_STR, width=_INT, height=_INT,
                              encoding=_STR, step=_INT, data=_BYTES),
    "foxglove.PoseInFrame": _obj(timestamp=_TIME, frame_id=_STR, pose=_POSE),
    "foxglove.PosesInFrame": _obj(timestamp=_TIME, frame_id=_STR, poses=_array(_POSE)),
    "foxglove.SceneUpdate": _obj(deletions=_array(_DELETION), entities=_array(_ENTITY)),
    "foxglove.Grid": _obj(timestamp=_TIME, frame_id=_STR, pose=_POSE, column_count=_INT,
                          cell_size=_obj(x=_NUM, y=_NUM), row_stride=_INT, cell_stride=_INT,
                          fields=_array(_GRID_FIELD), data=_BYTES),
    "foxglove.Log": _obj(timestamp=_TIME, level=_INT, message=_STR, name=_STR, file=_STR,
                         line=_INT),
}


@functools.lru_cache(maxsize=None)
def foxglove_schema(name: str) -> bytes:
    return json.dumps({"title": name, **FOXGLOVE_SCHEMAS[name]}).encode()


@dataclass(frozen=True)
class VizMessage:
    """One message of a view channel: the topic, its schema (name, JSON schema) and the JSON payload."""

    topic: str
    schema_name: str
    schema: bytes
    payload: bytes
    log_time_ns: int


def _msg(topic: str, schema_name: str, obj: Any, t_us: int) -> VizMessage:
    schema = bus_schema(schema_name.removeprefix("scenenav."))[1] if schema_name.startswith(
        "scenenav.") else foxglove_schema(schema_name)
    return VizMessage(topic, schema_name, schema, json.dumps(obj).encode(), int(t_us) * 1000)


def _stamp(t_us: int) -> dict:
    return {"sec": int(t_us) // 1_000_000, "nsec": (int(t_us) % 1_000_000) * 1000}


def _pose(xyz, q_wxyz) -> dict:
    w, x, y, z = (float(v) for v in q_wxyz)
    return {"position": {"x": float(xyz[0]), "y": float(xyz[1]), "z": float(xyz[2])},
            "orientation": {"x": x, "y": y, "z": z, "w": w}}


_IDENTITY = (1.0, 0.0, 0.0, 0.0)

#: MAVLink severity -> foxglove.Log level (1 debug, 2 info, 3 warning, 4 error, 5 fatal).
_LOG_LEVEL = {Severity.EMERGENCY: 5, Severity.ALERT: 5, Severity.CRITICAL: 5, Severity.ERROR: 4,
              Severity.WARNING: 3, Severity.NOTICE: 2, Severity.INFO: 2, Severity.DEBUG: 1}


def raw_image(msg: CameraFrame) -> dict:
    """A camera frame as ``foxglove.RawImage`` (JSON; pixels base64)."""
    ch = 3 if msg.encoding == "rgb8" else 1
    return {"timestamp": _stamp(msg.timestamp_us), "frame_id": "camera", "width": msg.width_px,
            "height": msg.height_px, "encoding": msg.encoding, "step": msg.width_px * ch,
            "data": base64.b64encode(msg.pixels.tobytes()).decode()}


def map_grid(image: np.ndarray, m_per_px: float, t_us: int, z_m: float) -> dict:
    """A north-up map image (row 0 north; (H, W, 3) uint8 RGB or (H, W) float in [0, 1], NaN
    unknown) as a ``foxglove.Grid`` in the world frame centred on the origin: RGB maps as
    ``red``/``green``/``blue``/``alpha`` uint8 fields, probability maps as one float32 field
    ``p_bad`` (NaN where unknown)."""
    h, w = image.shape[:2]
    step = max(1, math.ceil(max(h, w) / MAP_MAX_CELLS))
    img = image[::step, ::step][::-1]                    # grid row 0 is the south edge
    rows, cols = img.shape[:2]
    cell = m_per_px * step
    if img.ndim == 2 and img.dtype == np.uint8:            # a grey reference map
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim == 3:
        rgba = np.concatenate([img[..., :3].astype(np.uint8),
                               np.full((rows, cols, 1), 255, np.uint8)], axis=2)
        data = np.ascontiguousarray(rgba).tobytes()
        fields = [{"name": n, "offset": i, "type": 1} for i, n in
                  enumerate(("red", "green", "blue", "alpha"))]   # 1 = UINT8
        cell_stride = 4
    else:
        data = np.ascontiguousarray(img, dtype="<f4").tobytes()
        fields = [{"name": "p_bad", "offset": 0, "type": 7}]      # 7 = FLOAT32
        cell_stride = 4
    origin = (-w * m_per_px / 2, -h * m_per_px / 2, z_m)
    return {"timestamp": _stamp(t_us), "frame_id": FRAME_ID, "pose": _pose(origin, _IDENTITY),
            "column_count": cols, "cell_size": {"x": cell, "y": cell}, "row_stride": cols * cell_stride,
            "cell_stride": cell_stride, "fields": fields, "data": base64.b64encode(data).decode()}


class VizState:
    """Turns bus messages into the view's messages (keeps the paths and what was drawn)."""

    def __init__(self, camera_every_n: int = 1, path_max_poses: int = PATH_MAX_POSES) -> None:
        if path_max_poses < 2:
            raise ValueError(f"path_max_poses = {path_max_poses}: expected at least 2")
        self.camera_every_n = camera_every_n
        self.path_max_poses = path_max_poses
        self._paths: dict[str, list[dict]] = {T_TRUTH_PATH: [], T_EST_PATH: []}
        self._path_next_us: dict[str, int] = {T_TRUTH_PATH: 0, T_EST_PATH: 0}
        self._path_step_us: dict[str, int] = {T_TRUTH_PATH: int(PATH_STEP_S * 1e6),
                                              T_EST_PATH: int(PATH_STEP_S * 1e6)}
        self._pose_next_us: dict[str, int] = {T_TRUTH_POSE: 0, T_EST_POSE: 0}
        self._routes_seen: set[str] = set()

    def on_message(self, msg: Any) -> list[VizMessage]:
        t = int(msg.timestamp_us)
        if isinstance(msg, CameraFrame):
            n = self.camera_every_n
            if n and msg.seq % n == 0:
                return [_msg(T_CAMERA, "foxglove.RawImage", raw_image(msg), t)]
            return []
        if isinstance(msg, TruthPose):
            return self._pose(T_TRUTH_POSE, T_TRUTH_PATH, msg.position_enu_m, msg.q_wxyz, t)
        if isinstance(msg, NavEstimate):
            return self._pose(T_EST_POSE, T_EST_PATH, msg.position_enu_m, msg.q_wxyz, t)
        if isinstance(msg, VisionFix):
            return self._fix(msg)
        if isinstance(msg, Event):
            return [_msg(T_EVENTS, "foxglove.Log", {
                "timestamp": _stamp(t), "level": _LOG_LEVEL.get(Severity(msg.severity), 2)
                if msg.severity in Severity._value2member_map_ else 2,
                "message": msg.text, "name": msg.node_id, "file": "", "line": 0}, t)]
        if isinstance(msg, AutopilotStatus):
            return [_msg(T_STATUS, "scenenav.AutopilotStatus", _status_obj(msg), t)]
        return []

    def _pose(self, pose_topic: str, path_topic: str, xyz, q, t: int) -> list[VizMessage]:
        if t < self._pose_next_us[pose_topic]:
            return []
        self._pose_next_us[pose_topic] = t + int(POSE_STEP_S * 1e6)
        pose = _pose(xyz, q)
        out = [_msg(pose_topic, "foxglove.PoseInFrame",
                    {"timestamp": _stamp(t), "frame_id": FRAME_ID, "pose": pose}, t)]
        if t >= self._path_next_us[path_topic]:
            path = self._paths[path_topic]
            path.append(pose)
            if len(path) > self.path_max_poses:
                path[:] = path[::-2][::-1]            # every other pose, the newest kept
                self._path_step_us[path_topic] *= 2
            self._path_next_us[path_topic] = t + self._path_step_us[path_topic]
            out.append(_msg(path_topic, "foxglove.PosesInFrame", {
                "timestamp": _stamp(t), "frame_id": FRAME_ID, "poses": self._paths[path_topic]}, t))
        return out

    def _fix(self, msg: VisionFix) -> list[VizMessage]:
        if not msg.valid:
            return []
        x, y = msg.position_xy_enu_m
        if not (math.isfinite(x) and math.isfinite(y)):
            return []
        color = {"r": 0.1, "g": 0.9, "b": 0.1, "a": 0.9} if msg.accepted else \
            {"r": 0.95, "g": 0.1, "b": 0.1, "a": 0.9}
        t = int(msg.timestamp_us)
        entity = {"timestamp": _stamp(t), "frame_id": FRAME_ID, "id": f"{msg.node_id}/{msg.frame_seq}",
                  "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
                  "metadata": [{"key": "node", "value": msg.node_id},
                               {"key": "accepted", "value": str(bool(msg.accepted)).lower()}],
                  "spheres": [{"pose": _pose((x, y, 1.0), _IDENTITY),
                               "size": {"x": FIX_SPHERE_M, "y": FIX_SPHERE_M, "z": FIX_SPHERE_M},
                               "color": color}]}
        return [_msg(T_FIXES, "foxglove.SceneUpdate", {"deletions": [], "entities": [entity]}, t)]

    def route_messages(self, run_dir: Path, t_us: int) -> list[VizMessage]:
        """The guidance node's route files (route.json, route-1.json, ...) not drawn yet, each as
        a line strip at the flight altitude's ground (z = 2 m above the maps)."""
        from scenenav.core.errors import UserError
        from scenenav.core.formats.route_file import read_route_file
        out = []
        for path in sorted(Path(run_dir).glob("route*.json")):
            if path.name in self._routes_seen or path.name.endswith(".tmp"):
                continue
            try:
                route = read_route_file(path)
            except (UserError, OSError):
                continue                                # still being written: next time
            self._routes_seen.add(path.name)
            points = [{"x": float(x), "y": float(y), "z": 2.0} for x, y in route.waypoints_xy_m]
            first = path.name == "route.json"
            color = {"r": 1.0, "g": 0.0, "b": 1.0, "a": 1.0} if first else \
                {"r": 0.5, "g": 0.0, "b": 0.6, "a": 1.0}
            entity = {"timestamp": _stamp(t_us), "frame_id": FRAME_ID, "id": path.stem,
                      "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
                      "lines": [{"type": 0, "pose": _pose((0, 0, 0), _IDENTITY), "thickness": 3.0,
                                 "scale_invariant": True, "points": points, "color": color,
                                 "colors": [], "indices": []}]}     # type 0 = LINE_STRIP
            out.append(_msg(T_ROUTE, "foxglove.SceneUpdate", {"deletions": [], "entities": [entity]},
                            t_us))
        return out


def map_messages(world, assistant_map: str | None, t_us: int = 0) -> list[VizMessage]:
    """The reference map and (if the run has one) the assistant map as grids."""
    m = world.manifest
    out = [_msg(T_MAP_REFERENCE, "foxglove.Grid",
                map_grid(np.asarray(world.reference), m.m_per_px, t_us, MAP_Z_M["reference"]), t_us)]
    if assistant_map and Path(assistant_map).is_file():
        from scenenav.core.formats.assistant_map_file import read_probability_map
        amap = read_probability_map(assistant_map)
        prob = np.asarray(amap.probability, dtype=np.float32)
        out.append(_msg(T_MAP_ASSISTANT, "foxglove.Grid",
                        map_grid(prob, m.width_px * m.m_per_px / prob.shape[1], t_us,
                                 MAP_Z_M["assistant"]), t_us))
    return out


def run_assistant_map(cfg) -> str | None:
    """The assistant map a run uses (guidance's, else the perception node's), None if none."""
    for path in (cfg.guidance.assistant_map if cfg.guidance.enabled else "",
                 cfg.perception.assistant_map if cfg.perception.enabled else ""):
        if path:
            return str(path)
    return None


def _status_obj(msg: AutopilotStatus) -> dict:
    """The status as it travels on the bus (the same JSON as its bus channel)."""
    return json.loads(encode(msg))
