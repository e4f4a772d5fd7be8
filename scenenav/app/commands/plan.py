"""``scenenav plan``: plan a route over an assistant map and write ROUTE.json (+ .png, .waypoints).

    scenenav plan --world DIR --assistant-map FILE --start X,Y --goal X,Y --out ROUTE.json
                  [--format {json,wpl}] [--end {none,land,rtl}] [--altitude-m 100] [--speed-m-s 10]
                  [--footprint-m W] [--clearance-m 10] [--unvisited-weight 0.5] [--home-alt-m 0]
                  [--keep-footprint-on-map]
                  [--spacing-m 50] [--set KEY=VALUE ...]

``register(subparsers)`` adds the command to the ``scenenav`` parser; ``main(argv)`` runs it
stand-alone (``python -m scenenav.app.commands.plan plan ...``) with the same error handling as scenenav:
a ``UserError`` prints ``error: <one line>`` on stderr and exits 2.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

from guidance.config import PlannerConfig, RouteEnd, RouteFormat
from guidance.planner import plan_route
from guidance.route import mission_items, route_to_dict, write_route_png
from scenenav.core.config import apply_overrides, load_config
from scenenav.core.errors import UserError, run_command
from scenenav.core.formats.assistant_map_file import check_map_matches_world, read_probability_map
from scenenav.core.formats.route_file import write_route_json, write_wpl
from scenenav.core.formats.world_manifest import read_manifest

log = logging.getLogger(__name__)


def parse_xy(text: str, flag: str) -> tuple[float, float]:
    """'X,Y' (metres east, north of the map centre) -> (x, y), or a one-line UserError."""
    parts = str(text).split(",")
    try:
        if len(parts) != 2:
            raise ValueError(text)
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        raise UserError(f"{flag} {text!r}: expected X,Y in metres east,north of the map centre, "
                        f"e.g. {flag} -120.5,40") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise UserError(f"{flag} {text!r}: expected finite X,Y in metres")
    return x, y


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", required=True, metavar="DIR", help="world directory (manifest.json)")
    p.add_argument("--assistant-map", required=True, metavar="FILE", help="assistant map .npz")
    p.add_argument("--start", required=True, metavar="X,Y", help="start, metres east,north of the map centre")
    p.add_argument("--goal", required=True, metavar="X,Y", help="goal, metres east,north of the map centre")
    p.add_argument("--out", required=True, metavar="ROUTE.json", help="route file (.png written beside it)")
    p.add_argument("--format", choices=[f.value for f in RouteFormat], default=RouteFormat.JSON.value,
                   help="wpl also writes ROUTE.waypoints (QGC WPL 110, MAVProxy 'wp load')")
    p.add_argument("--end", choices=[e.value for e in RouteEnd], default=RouteEnd.NONE.value,
                   help="mission item after the last waypoint in the .waypoints file")
    p.add_argument("--altitude-m", type=float, default=None, help="flight altitude above home (default 100)")
    p.add_argument("--speed-m-s", type=float, default=None, help="cruise speed for the turn radius (default 10)")
    p.add_argument("--footprint-m", type=float, default=None,
                   help="camera footprint width (default 2*altitude*tan(30 deg), 115.5 m at 100 m)")
    p.add_argument("--clearance-m", type=float, default=None,
                   help="distance kept between footprint edge and bad cells (default 10)")
    p.add_argument("--unvisited-weight", type=float, default=None,
                   help="unvisited cells as obstacles: 0 free .. 1 hard (default 0.5)")
    p.add_argument("--keep-footprint-on-map", action="store_true", default=None,
                   help="keep the whole camera footprint (from --altitude-m and the 60 deg FOV) on the "
                        "map: the edge becomes an obstacle (default off)")
    p.add_argument("--spacing-m", type=float, default=None, help="max distance between waypoints (default 50)")
    p.add_argument("--home-alt-m", type=float, default=0.0, help="home altitude AMSL for the WPL home item")
    p.add_argument("--set", action="append", default=None, metavar="KEY=VALUE",
                   help="any other PlannerConfig key (see docs/guidance.md), repeatable")


def register(subparsers) -> None:
    """Add ``plan`` to the scenenav sub-command parsers."""
    p = subparsers.add_parser("plan", help="plan a route avoiding bad matching areas",
                              description="Plan a route over an assistant map that keeps the camera "
                                          "footprint clear of bad matching areas (docs/guidance.md).")
    add_arguments(p)
    p.set_defaults(func=run_plan)


def planner_config_from_args(args: argparse.Namespace) -> PlannerConfig:
    mapping = {}
    for flag, key in (("altitude_m", "altitude_m"), ("speed_m_s", "cruise_speed_m_s"),
                      ("footprint_m", "footprint_m"), ("clearance_m", "clearance_m"),
                      ("unvisited_weight", "unvisited_weight"), ("spacing_m", "waypoint_spacing_m"),
                      ("keep_footprint_on_map", "keep_footprint_on_map")):
        value = getattr(args, flag, None)
        if value is not None:
            mapping[key] = value
    mapping = apply_overrides(mapping, tuple(args.set or ()))
    return load_config(PlannerConfig, mapping, source="scenenav plan")


def run_plan(args: argparse.Namespace) -> int:
    """Handler of ``scenenav plan``; returns the exit code (UserError propagates to the CLI)."""
    start = parse_xy(args.start, "--start")
    goal = parse_xy(args.goal, "--goal")
    cfg = planner_config_from_args(args)
    world = read_manifest(args.world)
    amap = read_probability_map(args.assistant_map)
    check_map_matches_world(amap, world, args.assistant_map)
    route = plan_route(amap.probability, world.m_per_px, start, goal, cfg, names=("--start", "--goal"))
    out = Path(args.out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_route_json(out, route_to_dict(route, world, args.home_alt_m))
        write_route_png(out.with_suffix(".png"), route, amap.probability, world.m_per_px)
        if RouteFormat(args.format) is RouteFormat.WPL:
            write_wpl(out.with_suffix(".waypoints"), mission_items(route, world, args.home_alt_m,
                                                                   RouteEnd(args.end)))
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write: {exc.strerror or exc}") from None
    clear = f"{route.min_clearance_m:.1f} m" if math.isfinite(route.min_clearance_m) else "n/a (no bad cell)"
    print(f"{out}: {len(route.waypoints_xy_m)} waypoints, {route.length_m:.0f} m "
          f"({route.length_ratio:.2f}x the shortest free path of {route.shortest_free_length_m:.0f} m), "
          f"min clearance {clear}, {route.method.value}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point: ``python -m scenenav.app.commands.plan plan ...`` (and ``bench plan``)."""
    from scenenav.app.bench.plan import register_bench

    parser = argparse.ArgumentParser(prog="scenenav")
    sub = parser.add_subparsers(dest="command", required=True)
    register(sub)
    bench = sub.add_parser("bench", help="benchmarks")
    register_bench(bench.add_subparsers(dest="bench_command", required=True))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    return run_command(args)


if __name__ == "__main__":
    sys.exit(main())
