"""Draw what the Foxglove layout (docs/foxglove-layout.json) shows of a recorded run, at one moment.

Not a screenshot of Foxglove (no Foxglove app runs here): a matplotlib picture of the same panels
drawn from the same channels, read from the run's ``bus.mcap`` (the view channels ``viz/...`` the
live view streams): the 3-D panel seen from above (reference map grid, planned route, truth and
estimate paths and poses, fixes green accepted / red rejected), the position plot, the camera
image, the autopilot status and the last events.

    PYTHONPATH=. .venv/bin/python tools/live_view_picture.py RUN_DIR OUT.png [--at-s T]
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from scenenav.app import viz  # noqa: E402


def _read(run_dir: Path) -> dict[str, list[tuple[float, dict]]]:
    from mcap.reader import make_reader
    out: dict[str, list[tuple[float, dict]]] = {}
    with (run_dir / "bus.mcap").open("rb") as f:
        for _s, ch, m in make_reader(f).iter_messages():
            if ch.topic.startswith("viz/"):
                out.setdefault(ch.topic, []).append((m.log_time * 1e-9, json.loads(m.data)))
    for v in out.values():
        v.sort(key=lambda tm: tm[0])
    return out


def _upto(msgs, t):
    return [d for tt, d in msgs if tt <= t]


def _grid_image(g: dict) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    cols = g["column_count"]
    data = np.frombuffer(base64.b64decode(g["data"]), np.uint8)
    rows = len(data) // g["row_stride"]
    img = data.reshape(rows, cols, 4)[::-1, :, :3]              # grid row 0 south -> image top north
    x0, y0 = g["pose"]["position"]["x"], g["pose"]["position"]["y"]
    return img, (x0, x0 + cols * g["cell_size"]["x"], y0, y0 + rows * g["cell_size"]["y"])


def draw(run_dir: Path, out: Path, at_s: float | None) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ch = _read(run_dir)
    t_end = max(v[-1][0] for v in ch.values())
    t = t_end if at_s is None else at_s
    fig = plt.figure(figsize=(15, 8.5))
    gs = fig.add_gridspec(4, 3, width_ratios=[1, 1, 1])
    ax3d = fig.add_subplot(gs[:3, :2])
    axplot = fig.add_subplot(gs[3, :2])
    axcam = fig.add_subplot(gs[:2, 2])
    axstat = fig.add_subplot(gs[2, 2])
    axlog = fig.add_subplot(gs[3, 2])

    ref = _upto(ch.get(viz.T_MAP_REFERENCE, []), t)
    if ref:
        img, extent = _grid_image(ref[-1])
        ax3d.imshow(img, extent=extent, origin="upper")
    for d in _upto(ch.get(viz.T_ROUTE, []), t):
        for e in d["entities"]:
            for line in e["lines"]:
                xy = np.array([(p["x"], p["y"]) for p in line["points"]])
                ax3d.plot(xy[:, 0], xy[:, 1], "--", c="magenta", lw=1.5, label="planned route",
                         zorder=5)
    for topic, colour, label in ((viz.T_TRUTH_PATH, "k", "truth"), (viz.T_EST_PATH, "#1f5fff", "estimate")):
        paths = _upto(ch.get(topic, []), t)
        if paths:
            xy = np.array([(p["position"]["x"], p["position"]["y"]) for p in paths[-1]["poses"]])
            ax3d.plot(xy[:, 0], xy[:, 1], c=colour, lw=1.0, label=f"{label} path", zorder=3)
    fixes = [e for d in _upto(ch.get(viz.T_FIXES, []), t) for e in d["entities"]]
    for accepted, colour, label in ((True, "lime", "fix accepted"), (False, "red", "fix rejected")):
        pts = np.array([(s["pose"]["position"]["x"], s["pose"]["position"]["y"]) for e in fixes
                        for s in e["spheres"] if (s["color"]["g"] > s["color"]["r"]) == accepted])
        if len(pts):
            ax3d.scatter(pts[:, 0], pts[:, 1], s=6, c=colour, edgecolors="none", label=label,
                         zorder=4)
    for topic, colour in ((viz.T_TRUTH_POSE, "k"), (viz.T_EST_POSE, "#1f5fff")):
        poses = _upto(ch.get(topic, []), t)
        if poses:
            p, q = poses[-1]["pose"]["position"], poses[-1]["pose"]["orientation"]
            yaw = np.arctan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]), 1 - 2 * (q["y"] ** 2 + q["z"] ** 2))
            ax3d.arrow(p["x"], p["y"], 25 * np.cos(yaw), 25 * np.sin(yaw), width=3, color=colour,
                      zorder=6)
    handles, labels = ax3d.get_legend_handles_labels()
    keep = dict(zip(labels, handles, strict=True))
    ax3d.legend(keep.values(), keep.keys(), loc="upper right", fontsize=8)
    ax3d.set_title("world (ENU m) - 3-D panel seen from above", fontsize=10)
    ax3d.set_xlabel("x east (m)")
    ax3d.set_ylabel("y north (m)")

    for topic, colour, name in ((viz.T_TRUTH_POSE, "k", "truth"), (viz.T_EST_POSE, "#1f5fff", "estimate")):
        msgs = [(tt, d) for tt, d in ch.get(topic, []) if tt <= t]
        if msgs:
            tt = np.array([m[0] for m in msgs])
            for axis, style in (("x", "-"), ("y", ":")):
                axplot.plot(tt, [m[1]["pose"]["position"][axis] for m in msgs], style, c=colour,
                            lw=1.2, label=f"{name} {axis}")
    axplot.set_title("position: truth vs estimate (m, x east / y north)", fontsize=10)
    axplot.set_xlabel("time (s)")
    axplot.legend(fontsize=7, ncol=4)
    axplot.grid(True, alpha=0.3)

    cams = _upto(ch.get(viz.T_CAMERA, []), t)
    if cams:
        c = cams[-1]
        px = np.frombuffer(base64.b64decode(c["data"]), np.uint8)
        shape = (c["height"], c["width"], 3) if c["encoding"] == "rgb8" else (c["height"], c["width"])
        axcam.imshow(px.reshape(shape), cmap="gray")
    axcam.set_title("camera (viz/camera)", fontsize=10)
    axcam.axis("off")

    status = _upto(ch.get(viz.T_STATUS, []), t)
    axstat.axis("off")
    axstat.set_title("autopilot status", fontsize=10)
    if status:
        s = status[-1]
        text = "\n".join(f"{k}: {s[k]}" for k in ("armed", "mode", "landed", "mission_seq",
                                                  "mission_count", "mission_complete", "gps_used"))
        axstat.text(0.02, 0.95, text, va="top", family="monospace", fontsize=8)
    logs = _upto(ch.get(viz.T_EVENTS, []), t)[-9:]
    axlog.axis("off")
    axlog.set_title("events", fontsize=10)
    axlog.text(0.0, 0.98, "\n".join(f"{d['timestamp']['sec']:>4d} s {d['name']}: {d['message'][:58]}"
                                    for d in logs), va="top", family="monospace", fontsize=6.5)
    fig.suptitle(f"{run_dir.name}: the Foxglove layout's panels drawn from bus.mcap at t = {t:.0f} s "
                 "(matplotlib, not a Foxglove screenshot)", fontsize=11)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("run_dir", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--at-s", type=float, help="the moment drawn (default: the end of the run)")
    a = p.parse_args()
    draw(a.run_dir, a.out, a.at_s)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
