"""``scenenav bench autopilot`` runs and reports sane figures (tiny durations; no timing asserts)."""

from __future__ import annotations

import json
import math

from scenenav.app.bench.autopilot import AutopilotBenchConfig, route, run_bench
from scenenav.app.cli import main

KEYS = ("controller_ms_per_sim_s", "ekf_ms_per_sim_s", "models_ms_per_sim_s", "hold_rms_m",
        "hold_max_m", "hold_z_rms_m", "crosstrack_rms_m", "crosstrack_max_m",
        "crosswind_downwind_mean_m", "along_track_mean_offset_m", "cruise_speed_mean_m_s",
        "cruise_s", "sim_s", "seed")


def test_bench_json_from_the_cli(capsys):
    argv = ["bench", "autopilot", "--json", "--hold-s", "1", "--settle-s", "1", "--leg-m", "20",
            "--speed-m-s", "4", "--seed", "3"]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(KEYS) <= set(report)
    assert all(math.isfinite(report[k]) for k in KEYS)
    assert report["seed"] == 3 and report["bench"] == "autopilot"
    assert report["controller_ms_per_sim_s"] > 0 and report["ekf_ms_per_sim_s"] > 0
    assert report["sim_s"] > 2.0
    assert report["hold_rms_m"] < 1.5 and report["hold_z_rms_m"] < 1.0
    assert report["cruise_s"] > 0.5                         # some cruising at 4 m/s was measured
    assert report["crosstrack_rms_m"] < 2.0 and report["crosstrack_max_m"] < 4.0
    assert 2.5 < report["cruise_speed_mean_m_s"] < 5.5


def test_bench_table_and_route():
    from io import StringIO
    out = StringIO()
    cfg = AutopilotBenchConfig(hold_s=0.5, settle_s=0.5, leg_m=10.0, cruise_speed_m_s=3.0)
    report = run_bench(cfg, out=out)
    text = out.getvalue()
    assert "hold RMS" in text and "cross-track RMS" in text and "CPU ms per simulated s" in text
    assert report["hold_s"] == 0.5
    assert route(cfg)[0] == (10.0, 0.0, cfg.altitude_m) and route(cfg)[-1][:2] == (0.0, 0.0)


def test_bench_bad_input_is_one_line_error(capsys):
    assert main(["bench", "autopilot", "--hold-s", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: bench autopilot: hold_s")
