"""``scenenav assistant-map``: build, render and inspect assistant maps.

``build`` precomputes a whole map for a world with the CNN at a stride in metres of ground (whole
pixels of that world; batched inference, progress bar; on a world with a DSM the cells' nadir
captures rendered with relief, unless --no-relief);
``render`` draws it like the paper's Figure 6; ``info`` prints its metadata and coverage.
"""

from __future__ import annotations

import argparse
import logging

from perception.map_cache import build_world_map
from scenenav.core.formats.assistant_map_file import BUILD_STRIDE_M

log = logging.getLogger(__name__)


def _build(args: argparse.Namespace) -> int:
    amap, elapsed = build_world_map(args.world, args.out, args.stride_m, args.altitude_m, args.fov_deg,
                          args.weights, args.batch_size, progress=not args.quiet, png=not args.no_png,
                          relief=not args.no_relief, reference=args.reference)
    print(f"assistant map {amap.width_px}x{amap.height_px} px at {amap.m_per_px:g} m/px, "
          f"stride {args.stride_m:g} m = {amap.stride_px} px, "
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
          f"at {amap.m_per_px} m/px\nmethod: {amap.method}  "
          f"stride: {amap.stride_px} px ({amap.stride_px * amap.m_per_px:.3g} m)  "
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
                                   "a stride (metres of ground), classify the crops in batches with the "
                                   "CNN and write FILE.npz (probability float32 HxW, NaN = unvisited, + "
                                   "metadata) and a Figure-6 style PNG beside it.")
    b.add_argument("--world", required=True, help="world folder (scenenav world generate/import)")
    b.add_argument("--out", required=True, metavar="FILE.npz")
    b.add_argument("--stride-m", type=float, default=BUILD_STRIDE_M, metavar="M",
                   help="spacing of the rated cells on the ground, rounded to whole pixels of the "
                        f"world (default {BUILD_STRIDE_M:g}: 5 px on the default 0.53 m/px world)")
    b.add_argument("--altitude-m", type=float, default=100.0, help="flight altitude the footprint is cut for (default 100)")
    b.add_argument("--fov-deg", type=float, default=60.0, help="camera field of view (default 60)")
    b.add_argument("--weights", help="CNN weights .pt (default: the shipped perception/weights/default.pt)")
    b.add_argument("--batch-size", type=int, default=256, help="crops per CNN batch (default 256)")
    b.add_argument("--no-relief", action="store_true",
                   help="classify crops of the reference even where the world has a DSM (default: "
                        "there, the nadir captures rendered with relief over each cell)")
    b.add_argument("--reference", choices=["default", "orthophoto", "perspective"], default="default",
                   help="reference map the crops are cut from (default: the one the manifest names)")
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
