#!/usr/bin/env python3
"""Behaviour check for refactors: fly the shipped deterministic scenarios and compare run outputs.

  tools/behaviour_check.py record OUT_DIR [--scenario NAME ...] [--python PY]
      flies each scenario (``scenarios/NAME.yaml``, lockstep) with ``PY -m scenenav.cli run`` into
      ``OUT_DIR/NAME`` and writes ``OUT_DIR/digests.json`` (sha256 of truth.csv, fixes.csv without
      its wall-clock columns, estimates.csv).
  tools/behaviour_check.py compare DIR_A DIR_B
      compares two recordings file by file; exit 0 only if every digest matches.

Record with the old checkout (``PYTHONPATH=/path/to/old/checkout``) and with the new one, then
compare. The wall-clock columns of fixes.csv (``time_*_ms``: processing times measured in flight)
differ between any two runs and are left out; every other byte is compared.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import os
import subprocess
import sys
from pathlib import Path

DETERMINISTIC = ("logging_flight", "scripted_loop", "paper_experiment", "gps_denied", "guided_route")
ROOT = Path(__file__).resolve().parent.parent


def _digest_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _fixes_without_wall_clock(path: Path) -> bytes:
    rows = list(csv.reader(path.read_text().splitlines()))
    if not rows:
        return b""
    keep = [i for i, name in enumerate(rows[0]) if not name.startswith("time_")]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    for row in rows:
        w.writerow([row[i] for i in keep if i < len(row)])
    return out.getvalue().encode()


def digests(run_dir: Path) -> dict[str, str]:
    out: dict[str, str] = {}
    for name in ("truth.csv", "estimates.csv"):
        p = run_dir / name
        out[name] = _digest_bytes(p.read_bytes()) if p.is_file() else "missing"
    p = run_dir / "fixes.csv"
    out["fixes.csv (no time_* columns)"] = (_digest_bytes(_fixes_without_wall_clock(p))
                                            if p.is_file() else "missing")
    return out


def _cli_module(python: str) -> str:
    """The CLI module of the checkout ``python`` imports (``scenenav.app.cli``, or ``scenenav.cli``
    before the two-layer layout)."""
    probe = "import importlib.util as u; print('scenenav.app.cli' if u.find_spec('scenenav.app') else 'scenenav.cli')"
    return subprocess.run([python, "-c", probe], capture_output=True, text=True, check=True,
                          env=dict(os.environ)).stdout.strip()


def record(out_dir: Path, scenarios: list[str], python: str, overrides: list[str]) -> int:
    out_dir.mkdir(parents=True, exist_ok=True)
    result: dict[str, dict[str, str]] = {}
    for name in scenarios:
        run_dir = out_dir / name
        cmd = [python, "-m", _cli_module(python), "run", str(ROOT / "scenarios" / f"{name}.yaml"),
               "--out", str(run_dir), "--quiet"] + [a for kv in overrides for a in ("--set", kv)]
        print(f"flying {name} ...", file=sys.stderr, flush=True)
        proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              env=dict(os.environ), check=False)
        if proc.returncode != 0:
            print(f"{name}: exit {proc.returncode}: {proc.stderr.strip()[-400:]}", file=sys.stderr)
        result[name] = digests(run_dir)
    (out_dir / "digests.json").write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))
    return 0


def compare(a: Path, b: Path) -> int:
    da = json.loads((a / "digests.json").read_text())
    db = json.loads((b / "digests.json").read_text())
    same = True
    for name in sorted(set(da) | set(db)):
        for f in sorted(set(da.get(name, {})) | set(db.get(name, {}))):
            x, y = da.get(name, {}).get(f), db.get(name, {}).get(f)
            ok = x == y and x not in (None, "missing")
            same &= ok
            print(f"{'same' if ok else 'DIFFERENT'}  {name}/{f}")
    return 0 if same else 1


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="fly the scenarios and write digests.json")
    r.add_argument("out", type=Path)
    r.add_argument("--scenario", action="append", help=f"scenario name (default: {', '.join(DETERMINISTIC)})")
    r.add_argument("--python", default=sys.executable, help="interpreter with scenenav installed")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="scenario override for every flight, e.g. autopilot.mavlink_tcp_port=57000 when "
                        "another run holds 5760 (ports are not in the digests)")
    c = sub.add_parser("compare", help="compare two recordings")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    args = p.parse_args()
    if args.cmd == "record":
        return record(args.out, args.scenario or list(DETERMINISTIC), args.python, args.set)
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
