"""``scenenav assistant-map``: build, render and inspect assistant maps.

``build`` precomputes a whole map for a world with the CNN at a stride (batched inference, progress
bar); ``render`` draws it like the paper's Figure 6; ``info`` prints its metadata and coverage.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import cv2

from scenenav.core.errors import UserError

log = logging.getLogger(__name__)


def build(world_dir: str, out: str, stride_px: int = 5, altitude_m: float = 100.0,
          fov_deg: float = 60.0, weights: str | None = None, batch_size: int = 256,
          progress: bool = True, png: bool = True):
    from perception.assistant_map import RenderMode, build_assistant_map
    from perception.cnn import MatchClassifier
    from worlds.world import load_world
    if stride_px < 1:
        raise UserError(f"--stride-px {stride_px}: expected a positive integer")
    if not (5.0 <= altitude_m <= 1000.0):
        raise UserError(f"--altitude-m {altitude_m}: expected 5 to 1000 m")
    out_path = Path(out)
    if out_path.suffix != ".npz":
        raise UserError(f"--out {out}: expected a .npz file name")
    world = load_world(world_dir)
    clf = MatchClassifier.from_file(weights) if weights else MatchClassifier.default()
    gray = cv2.cvtColor(world.reference, cv2.COLOR_RGB2GRAY)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(unit="crop", desc="assistant map")

    def on_progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()
    t0 = time.perf_counter()
    amap = build_assistant_map(gray, clf.predict_proba, world.m_per_px, altitude_m=altitude_m,
                               fov_deg=fov_deg, stride_px=stride_px, batch_size=batch_size,
                               progress=on_progress, cnn_input_px=clf.input_px,
                               world_name=world.manifest.name,
                               model_id=str(getattr(clf.meta, "training_record_id", "")))
    elapsed = time.perf_counter() - t0
    if bar is not None:
        bar.close()
    out_path.parent.mkdir(parents=True, exist_ok=True)
    amap.save(out_path)
    if png:
        amap.render_png(out_path.with_suffix(".png"), RenderMode.BINARY)
    return amap, elapsed


def _build(args: argparse.Namespace) -> int:
    amap, elapsed = build(args.world, args.out, args.stride_px, args.altitude_m, args.fov_deg,
                          args.weights, args.batch_size, progress=not args.quiet, png=not args.no_png)
    print(f"assistant map {amap.width_px}x{amap.height_px} px, stride {args.stride_px} px, "
          f"coverage {amap.coverage():.1%}, built in {elapsed:.1f} s -> {args.out}")
    return 0


def _render(args: argparse.Namespace) -> int:
    from perception.assistant_map import AssistantMap, RenderMode
    amap = AssistantMap.load(args.map)
    path = amap.render_png(args.out, RenderMode(args.mode))
    print(f"wrote {path}")
    return 0


def _info(args: argparse.Namespace) -> int:
    import numpy as np
    from perception.assistant_map import AssistantMap
    amap = AssistantMap.load(args.map)
    p = amap.probability
    known = ~np.isnan(p)
    print(f"file: {args.map}\nworld: {amap.world_name}\nsize: {amap.width_px}x{amap.height_px} px "
          f"at {amap.m_per_px} m/px\nmethod: {amap.method}  stride: {amap.stride_px} px  "
          f"model: {amap.model_id}\ncoverage: {known.mean():.1%}\n"
          f"true-match expected (p >= 0.5): {(p[known] >= 0.5).mean() if known.any() else 0:.1%} of known pixels")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "assistant-map", help="build, render or inspect an assistant map",
        description="The assistant map holds, per reference-map pixel, the probability that a scene "
                    "match taken with the drone over that pixel is true (NaN: unvisited). Flights "
                    "build it online (methods cnn and assistant-map) or reuse one built here.")
    sub = p.add_subparsers(dest="map_command", metavar="ACTION")
    sub.required = True
    b = sub.add_parser("build", help="precompute a whole map for a world with the CNN",
                       description="Slide a camera-footprint crop over the world's reference map with "
                                   "a stride, classify the crops in batches with the CNN and write "
                                   "FILE.npz (probability float32 HxW, NaN = unvisited, + metadata) "
                                   "and a Figure-6 style PNG beside it.")
    b.add_argument("--world", required=True, help="world folder (scenenav world generate/import)")
    b.add_argument("--out", required=True, metavar="FILE.npz")
    b.add_argument("--stride-px", type=int, default=5, help="cell side in map pixels (default 5)")
    b.add_argument("--altitude-m", type=float, default=100.0, help="flight altitude the footprint is cut for (default 100)")
    b.add_argument("--fov-deg", type=float, default=60.0, help="camera field of view (default 60)")
    b.add_argument("--weights", help="CNN weights .pt (default: the shipped perception/weights/default.pt)")
    b.add_argument("--batch-size", type=int, default=256, help="crops per CNN batch (default 256)")
    b.add_argument("--no-png", action="store_true", help="do not write the PNG")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    b.set_defaults(func=_build)
    r = sub.add_parser("render", help="draw a map as a PNG (paper Figure 6)")
    r.add_argument("map", metavar="FILE.npz")
    r.add_argument("--out", required=True, metavar="FILE.png")
    r.add_argument("--mode", choices=["binary", "continuous"], default="binary",
                   help="binary: black false / white true / grey unvisited; continuous: grey levels")
    r.set_defaults(func=_render)
    i = sub.add_parser("info", help="print a map's metadata and coverage")
    i.add_argument("map", metavar="FILE.npz")
    i.set_defaults(func=_info)
