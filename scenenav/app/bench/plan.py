"""``scenenav bench plan``: planning time and route quality on synthetic assistant maps.

Maps are seeded random "lakes" (large ellipses) and "parks" (small ellipses) of bad matching
area over good area, at 0.53 m/px (the seed paper's reference map, section 6.1). The route runs
between opposite corners (x, y = -/+ 0.4 of the map extent); blobs that would put the start or
the goal inside the clearance zone are left out. Sizes are (width, height) in pixels.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from typing import TextIO

import numpy as np

from guidance.config import PlannerConfig
from guidance.planner import NoPathError, plan_route
from scenenav.app.json_output import emit_json

log = logging.getLogger(__name__)

BENCH_M_PER_PX = 0.53          # seed paper, section 6.1
BENCH_SEED = 2
DEFAULT_SIZES = ((900, 1000), (8000, 8000))
_LAKES_PER_KM2 = 3.0
_PARKS_PER_KM2 = 6.0
_LAKE_RADIUS_M = (30.0, 120.0)
_PARK_RADIUS_M = (10.0, 35.0)
_CORNER_FRACTION = 0.4


def corner_points(width_px: int, height_px: int, m_per_px: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """Start (south-west) and goal (north-east) used by the benchmark."""
    hx = _CORNER_FRACTION * width_px * m_per_px
    hy = _CORNER_FRACTION * height_px * m_per_px
    return (-hx, -hy), (hx, hy)


def synthetic_assistant_map(width_px: int, height_px: int, m_per_px: float = BENCH_M_PER_PX,
                            seed: int = BENCH_SEED, keep_clear_m: float = 0.0) -> np.ndarray:
    """Probability map (float32): good area 0.7..1.0 with bad ellipses 0.0..0.3, seeded.

    Blobs whose boundary comes within ``keep_clear_m`` of the benchmark start or goal are skipped.
    """
    rng = np.random.default_rng(seed)
    prob = rng.random((height_px, width_px), dtype=np.float32) * np.float32(0.3) + np.float32(0.7)
    area_km2 = width_px * height_px * m_per_px ** 2 / 1e6
    ends = corner_points(width_px, height_px, m_per_px)
    blobs = []
    for count, (r_lo, r_hi) in ((_LAKES_PER_KM2 * area_km2, _LAKE_RADIUS_M),
                                (_PARKS_PER_KM2 * area_km2, _PARK_RADIUS_M)):
        for _ in range(max(1, int(round(count)))):
            blobs.append((rng.uniform(-0.5, 0.5) * width_px * m_per_px,
                          rng.uniform(-0.5, 0.5) * height_px * m_per_px,
                          rng.uniform(r_lo, r_hi), rng.uniform(r_lo, r_hi), rng.uniform(0, math.pi)))
    for cx, cy, a, b, phi in blobs:
        if any(math.hypot(cx - ex, cy - ey) < max(a, b) + keep_clear_m for ex, ey in ends):
            continue
        r = max(a, b) / m_per_px
        u0, v0 = cx / m_per_px + width_px / 2.0, height_px / 2.0 - cy / m_per_px
        c0, c1 = max(0, int(u0 - r)), min(width_px, int(u0 + r) + 1)
        r0, r1 = max(0, int(v0 - r)), min(height_px, int(v0 + r) + 1)
        if c0 >= c1 or r0 >= r1:
            continue
        vv, uu = np.mgrid[r0:r1, c0:c1]
        dx = (uu + 0.5 - u0) * m_per_px
        dy = (v0 - vv - 0.5) * m_per_px
        ex = dx * math.cos(phi) + dy * math.sin(phi)
        ey = -dx * math.sin(phi) + dy * math.cos(phi)
        inside = (ex / a) ** 2 + (ey / b) ** 2 <= 1.0
        block = prob[r0:r1, c0:c1]
        block[inside] = rng.uniform(0.0, 0.3, size=int(inside.sum())).astype(np.float32)
    return prob


def run_bench(sizes=DEFAULT_SIZES, json_out: bool = False, out: TextIO | None = None,
              seed: int = BENCH_SEED) -> dict:
    """Plan one route per map size; write a table (or the JSON) to ``out``
    (default stdout; with ``--json`` the real stdout, see ``scenenav.app.json_output``) and return the
    results."""
    cfg = PlannerConfig()
    results = []
    for width, height in sizes:
        prob = synthetic_assistant_map(width, height, BENCH_M_PER_PX, seed, keep_clear_m=cfg.required_distance_m)
        start, goal = corner_points(width, height, BENCH_M_PER_PX)
        row = {"width_px": width, "height_px": height, "m_per_px": BENCH_M_PER_PX}
        t0 = time.perf_counter()
        try:
            route = plan_route(prob, BENCH_M_PER_PX, start, goal, cfg)
        except NoPathError as exc:
            row.update(plan_time_s=round(time.perf_counter() - t0, 3), error=str(exc))
            results.append(row)
            continue
        row.update(
            plan_time_s=round(time.perf_counter() - t0, 3),
            grid_cell_m=round(route.grid_cell_m, 3),
            length_m=round(route.length_m, 1),
            shortest_free_length_m=round(route.shortest_free_length_m, 1),
            length_ratio=round(route.length_ratio, 4),
            straight_line_m=round(math.hypot(goal[0] - start[0], goal[1] - start[1]), 1),
            straight_line_bad_fraction=round(route.straight_line_bad_fraction, 4),
            min_clearance_m=round(route.min_clearance_m, 2) if math.isfinite(route.min_clearance_m) else None,
            waypoints=len(route.waypoints_xy_m),
            method=route.method.value,
            fallback_reason=route.fallback_reason.value,
        )
        results.append(row)
        del prob
    report = {"bench": "plan", "seed": seed, "results": results}
    if json_out:
        emit_json(report, out)
    else:
        (out or sys.stdout).write(_table(results))
    return report


def _table(results: list[dict]) -> str:
    head = (f"{'map px':>11} {'cell m':>6} {'time s':>7} {'route m':>8} {'shortest m':>10} "
            f"{'ratio':>6} {'line bad':>8} {'clear m':>7}  method\n")
    lines = [head]
    for r in results:
        size = f"{r['width_px']}x{r['height_px']}"
        if "error" in r:
            lines.append(f"{size:>11} {'':>6} {r['plan_time_s']:>7.2f}  no path: {r['error']}\n")
            continue
        clear = f"{r['min_clearance_m']:.1f}" if r["min_clearance_m"] is not None else "n/a"
        lines.append(f"{size:>11} {r['grid_cell_m']:>6.2f} {r['plan_time_s']:>7.2f} {r['length_m']:>8.0f} "
                     f"{r['shortest_free_length_m']:>10.0f} {r['length_ratio']:>6.3f} "
                     f"{r['straight_line_bad_fraction']:>8.3f} {clear:>7}  {r['method']} ({r['fallback_reason']})\n")
    return "".join(lines)


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected WIDTHxHEIGHT in pixels, e.g. 900x1000") from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"{text!r}: expected at least 16x16 pixels")
    return w, h


def _cmd_bench_plan(args: argparse.Namespace) -> int:
    sizes = tuple(args.size) if args.size else DEFAULT_SIZES
    run_bench(sizes=sizes, json_out=args.json, seed=args.seed)
    return 0


def register_bench(bench_subparsers) -> None:
    """Add ``plan`` to the ``scenenav bench`` sub-commands."""
    p = bench_subparsers.add_parser("plan", help="route planner timing and quality on synthetic maps")
    p.add_argument("--json", action="store_true", help="print only JSON on stdout instead of a table")
    p.add_argument("--size", action="append", type=_parse_size, metavar="WxH",
                   help="map size in pixels (repeatable; default 900x1000 and 8000x8000)")
    p.add_argument("--seed", type=int, default=BENCH_SEED, help="seed of the synthetic maps")
    p.set_defaults(func=_cmd_bench_plan)
