"""``scenenav bench campaign``: flights per hour of a campaign with 1 and with 2 local Dask workers,
and Dask's overhead per run.

The campaign: N scripted flights (no autopilot) of ``--duration-s`` simulated seconds over the default
world, statistical detector, each with its own derived seed, flown twice into fresh folders, once per
worker count. Overhead of one run = (task start - the moment its worker was free: submission or the
end of the worker's previous flight) + (task start -> launcher started) + (flight end -> result at the
client): everything that is not the flight itself.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml


def _overheads(out: Path, received: dict[str, float]) -> tuple[list[float], list[float]]:
    from scenenav.app.campaign_run import read_record
    recs = [r for r in (read_record(d) for d in (out / "runs").iterdir() if d.is_dir()) if r]
    by_worker: dict[str, list[dict]] = {}
    for r in recs:
        by_worker.setdefault(r["worker"], []).append(r)
    overheads, walls = [], []
    for items in by_worker.values():
        items.sort(key=lambda r: r["started_unix"])
        prev_end = None
        for r in items:
            ready = r["submitted_unix"] if prev_end is None else max(r["submitted_unix"], prev_end)
            back = received.get(r["run_id"], r["ended_unix"]) - r["ended_unix"]
            overheads.append((r["started_unix"] - ready) + (r["launched_unix"] - r["started_unix"]) + back)
            walls.append(r["wall_s"])
            prev_end = received.get(r["run_id"], r["ended_unix"])
    return overheads, walls


def run_campaign_bench(flights: int = 4, duration_s: float = 20.0, worker_counts: tuple[int, ...] = (1, 2),
                       progress: bool = True) -> dict:
    from scenenav.app.campaign_run import run_campaign
    result: dict = {"flights": flights, "flight_duration_sim_s": duration_s, "mode": "scripted, lockstep",
                    "runs": []}
    with tempfile.TemporaryDirectory(prefix="scenenav-bench-campaign-") as tmp:
        spec = Path(tmp) / "bench.yaml"
        spec.write_text(yaml.safe_dump({
            "name": "bench", "set": {"duration_s": duration_s, "flight.mode": "scripted",
                                     "perception.method": "statistical"},
            "repeat": flights}))
        for n in worker_counts:
            out = Path(tmp) / f"workers-{n}"
            res = run_campaign(str(spec), str(out), workers=n, progress=progress)
            overheads, walls = _overheads(out, res.received_unix)
            med_wall = float(np.median(walls)) if walls else None
            result["runs"].append({
                "workers": n, "flown": res.flown, "failed": res.failed, "makespan_s": round(res.makespan_s, 2),
                "flights_per_hour": round(3600.0 * res.flown / res.makespan_s, 1) if res.makespan_s else None,
                "flight_wall_median_s": None if med_wall is None else round(med_wall, 2),
                "dask_overhead_median_s": round(float(np.median(overheads)), 4) if overheads else None,
                "dask_overhead_max_s": round(float(np.max(overheads)), 4) if overheads else None,
                "dask_overhead_pct_of_flight": (round(100.0 * float(np.median(overheads)) / med_wall, 3)
                                                if overheads and med_wall else None),
            })
    rates = {r["workers"]: r["flights_per_hour"] for r in result["runs"]}
    if 1 in rates and 2 in rates and rates[1]:
        result["speedup_2_over_1"] = round(rates[2] / rates[1], 3)
    return result


def _cmd(args: argparse.Namespace) -> int:
    from scenenav.core.errors import UserError
    if args.flights < 1 or args.duration_s <= 0:
        raise UserError("bench campaign: --flights must be >= 1 and --duration-s > 0")
    result = run_campaign_bench(args.flights, args.duration_s, progress=not args.json)
    if args.json:
        from scenenav.app.json_output import emit_json
        emit_json(result)
        return 0
    print(f"campaign benchmark: {result['flights']} scripted flights of {result['flight_duration_sim_s']:g} "
          "simulated s each")
    print("workers  flights/h  makespan (s)  flight wall (s)  Dask overhead/run median (max) s  % of flight")
    for r in result["runs"]:
        print(f"{r['workers']:>7}  {r['flights_per_hour']:>9}  {r['makespan_s']:>12}  {r['flight_wall_median_s']:>15}  "
              f"{r['dask_overhead_median_s']:>14} ({r['dask_overhead_max_s']})  {r['dask_overhead_pct_of_flight']:>16}")
    if "speedup_2_over_1" in result:
        print(f"speed-up with 2 workers: {result['speedup_2_over_1']:.2f}x")
    sys.stdout.flush()
    return 0


def register_bench(bench_subparsers) -> None:
    """Add ``campaign`` to the ``scenenav bench`` sub-commands."""
    p = bench_subparsers.add_parser(
        "campaign", help="campaign flights per hour with 1 and 2 Dask workers, Dask overhead per run",
        description="Fly N short scripted flights as a campaign with 1 and then 2 local Dask workers (fresh "
                    "folders, nothing skipped); print flights per hour, the speed-up and Dask's overhead "
                    "per run (submit or worker free -> flight start, flight end -> result at the client).")
    p.add_argument("--json", action="store_true", help="print the results as JSON alone")
    p.add_argument("--flights", type=int, default=4, help="flights per worker count (default 4)")
    p.add_argument("--duration-s", type=float, default=20.0, help="simulated seconds per flight (default 20)")
    p.set_defaults(func=_cmd)
