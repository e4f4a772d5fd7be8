"""The Foxglove layout of a run (``docs/foxglove-layout.json``), built with foxglove-sdk's layout API.

One layout for the live view (``scenenav run --live``) and for a recorded ``bus.mcap``: it names
only the view channels of ``scenenav.app.viz``, whose topics carry no run namespace. Panels: the
3-D scene (reference map, assistant map, planned route, truth and estimate poses and paths, fixes
green accepted / red rejected), the camera image, the autopilot status, the events, and a plot of
the estimate against the truth (east and north).

Lichtblick (the open-source fork of Foxglove Studio) reads layouts in Studio's older format, a
binary split tree over ``configById``; :func:`lichtblick_layout` writes the same layout in it
(``docs/lichtblick-layout.json``, for *Layouts > Import from file* in Lichtblick).

Regenerate: ``python -m scenenav.app.foxglove_layout > docs/foxglove-layout.json`` and
``python -m scenenav.app.foxglove_layout --lichtblick > docs/lichtblick-layout.json``
(tests/unit/app/test_viz.py checks that the shipped files are these).
"""

from __future__ import annotations

import json
import sys

import foxglove.layouts as fl

from scenenav.app import viz

TRUTH_COLOUR = "#111111"
ESTIMATE_COLOUR = "#1f5fff"
ROUTE_COLOUR = "#ff00ff"
#: The 3-D panel's camera: looking down on the map centre from this far (m), a little tilted.
VIEW_DISTANCE_M = 700.0
VIEW_TILT_DEG = 20.0


def scene_topics() -> dict:
    """The 3-D panel's topics and how each is drawn."""
    return {
        viz.T_MAP_REFERENCE: fl.BaseRendererGridTopicSettings(
            visible=True, color_mode="rgba-fields", draw_behind=True, frame_locked=False),
        viz.T_MAP_ASSISTANT: fl.BaseRendererGridTopicSettings(
            visible=False, color_mode="colormap", color_field="p_bad", color_map="turbo",
            explicit_alpha=0.6, min_value=0.0, max_value=1.0, frame_locked=False),
        viz.T_ROUTE: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
        viz.T_FIXES: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
        viz.T_TRUTH_PATH: fl.BaseRendererPosesTopicSettings(visible=True, type="line", line_width=2.0,
                                                            gradient=(TRUTH_COLOUR, TRUTH_COLOUR)),
        viz.T_EST_PATH: fl.BaseRendererPosesTopicSettings(
            visible=True, type="line", line_width=2.0, gradient=(ESTIMATE_COLOUR, ESTIMATE_COLOUR)),
        viz.T_TRUTH_POSE: fl.BaseRendererPoseTopicSettings(visible=True, type="arrow",
                                                           arrow_scale=(12.0, 3.0, 3.0),
                                                           color=TRUTH_COLOUR),
        viz.T_EST_POSE: fl.BaseRendererPoseTopicSettings(visible=True, type="arrow",
                                                         arrow_scale=(12.0, 3.0, 3.0),
                                                         color=ESTIMATE_COLOUR),
    }


def _position_plot() -> fl.PlotPanel:
    series = [fl.PlotSeries(value=f"{topic}.pose.position.{axis}", id=f"{name}-{axis}", enabled=True,
                            timestamp_method="receiveTime")
              for axis in ("x", "y")
              for topic, name in ((viz.T_TRUTH_POSE, "truth"), (viz.T_EST_POSE, "estimate"))]
    return fl.PlotPanel(title="position: truth vs estimate (m, x east / y north)",
                        config=fl.PlotConfig(paths=series, show_legend=True, x_axis_val="timestamp"))


def build_layout() -> fl.Layout:
    scene = fl.ThreeDeePanel(title="world (ENU m)", config=fl.ThreeDeeConfig(
        follow_tf=viz.FRAME_ID, fixed_frame=viz.FRAME_ID, topics=scene_topics(),
        camera_state=fl.ThreeDeeCameraState(distance=VIEW_DISTANCE_M, perspective=True,
                                            phi=VIEW_TILT_DEG, target=(0.0, 0.0, 0.0),
                                            theta_offset=0.0)))
    camera = fl.ImagePanel(title="camera", config=fl.ImageConfig(
        image_mode=fl.ImageModeConfig(image_topic=viz.T_CAMERA)))
    status = fl.RawMessagesPanel(title="autopilot status", config=fl.RawMessagesConfig(
        topic_path=viz.T_STATUS, expansion="all"))
    events = fl.LogPanel(title="events", config=fl.LogConfig(topic_to_render=viz.T_EVENTS,
                                                              show_name=True, search_terms=[],
                                                              min_log_level=1))
    side = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=camera),
        fl.SplitItem(proportion=1, content=status),
        fl.SplitItem(proportion=1, content=events),
    ])
    left = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=3, content=scene),
        fl.SplitItem(proportion=1, content=_position_plot()),
    ])
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=2, content=left), fl.SplitItem(proportion=1, content=side)]))


def layout_json() -> str:
    """The layout file's text (indented JSON, newline-terminated)."""
    return json.dumps(json.loads(build_layout().to_json()), indent=2) + "\n"


#: Panel type names that differ between the Foxglove layout format and Studio's older one.
_LEGACY_PANEL_TYPE = {"ThreeDee": "3D", "Log": "RosOut"}


def lichtblick_layout(layout: dict) -> dict:
    """``layout`` (the Foxglove layout format: n-ary splits with proportions) as Studio's older
    ``LayoutData`` that Lichtblick imports: every panel's config under ``configById`` (id
    ``<type>!<n>``, its title as ``foxglovePanelTitle``) and ``layout`` a binary split tree
    (``first``, ``second``, ``direction``, ``splitPercentage`` of the first)."""
    config_by_id: dict[str, dict] = {}

    def node(content: dict):
        if content["type"] == "panel":
            kind = _LEGACY_PANEL_TYPE.get(content["panelType"], content["panelType"])
            panel_id = f"{kind}!{len(config_by_id) + 1}"
            config = dict(content.get("config", {}))
            if content.get("title"):
                config["foxglovePanelTitle"] = content["title"]
            config_by_id[panel_id] = config
            return panel_id
        items = content["items"]
        return split(content["direction"], [(i["proportion"], node(i["content"])) for i in items])

    def split(direction: str, items: list[tuple[float, object]]):
        if len(items) == 1:
            return items[0][1]
        total = sum(p for p, _ in items)
        return {"direction": direction, "first": items[0][1], "second": split(direction, items[1:]),
                "splitPercentage": round(100.0 * items[0][0] / total, 3)}

    tree = node(layout["content"])
    return {"configById": config_by_id, "globalVariables": {}, "userNodes": {},
            "playbackConfig": {"speed": 1.0}, "layout": tree}


def lichtblick_layout_json() -> str:
    """The Lichtblick layout file's text (indented JSON, newline-terminated)."""
    return json.dumps(lichtblick_layout(json.loads(layout_json())), indent=2) + "\n"


if __name__ == "__main__":
    print(lichtblick_layout_json() if "--lichtblick" in sys.argv[1:] else layout_json(), end="")
