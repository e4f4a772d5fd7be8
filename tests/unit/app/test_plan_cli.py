"""``scenenav plan`` end to end on a small synthetic world: files, formats, one-line errors."""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support import REPO_ROOT

from scenenav.app.bench.plan import run_bench
from scenenav.app.commands.plan import main, parse_xy
from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import WorldManifest
from scenenav.core.frames import enu_to_geodetic, pixel_to_world

W, H, M_PER_PX = 200, 160, 2.0          # 400 m x 320 m
LAT0, LON0 = 47.3977, 8.5456
REPO = REPO_ROOT


@pytest.fixture()
def world(tmp_path: Path) -> dict:
    """A world directory with manifest.json and an assistant map with one lake."""
    wdir = tmp_path / "world"
    wdir.mkdir()
    (wdir / "manifest.json").write_text(WorldManifest(
        format_version=1, name="testworld", width_px=W, height_px=H, m_per_px=M_PER_PX,
        origin_lat_deg=LAT0, origin_lon_deg=LON0, source="generated", seed=None,
        has_landcover=False, has_junctions=False).to_json())
    prob = np.full((H, W), 0.9, dtype=np.float32)
    v, u = np.mgrid[0:H, 0:W]
    x, y = pixel_to_world(u + 0.5, v + 0.5, W, H, M_PER_PX)
    prob[np.hypot(x, y) <= 40.0] = 0.1
    prob[:, :10] = np.nan                # an unvisited strip on the west edge
    amap = tmp_path / "assistant.npz"
    np.savez(amap, probability=prob, width=W, height=H, m_per_px=M_PER_PX, world_name="testworld")
    return {"dir": wdir, "map": amap, "tmp": tmp_path, "prob": prob}


def plan_args(world: dict, *extra: str, out: str = "route.json") -> list[str]:
    return ["plan", "--world", str(world["dir"]), "--assistant-map", str(world["map"]),
            "--start=-150,0", "--goal=150,0", "--out", str(world["tmp"] / out),
            "--footprint-m", "40", "--clearance-m", "5", *extra]


def test_plan_writes_route_json_png_and_wpl(world, capsys):
    rc = main(plan_args(world, "--format", "wpl", "--end", "land", "--home-alt-m", "412"))
    assert rc == 0
    out = world["tmp"] / "route.json"
    doc = json.loads(out.read_text())
    for key in ("format_version", "world", "waypoints", "length_m", "min_clearance_m", "shortest_free_length_m",
                "length_ratio", "straight_line_bad_fraction", "route_bad_fraction", "planner", "fallback_used"):
        assert key in doc, key
    assert doc["format_version"] == 1 and doc["world"] == "testworld"
    assert doc["min_clearance_m"] >= 5.0 - 1e-6
    assert doc["straight_line_bad_fraction"] > 0.2 and doc["route_bad_fraction"] == 0.0
    assert doc["planner"]["footprint_m"] == 40.0 and doc["planner"]["clearance_m"] == 5.0
    wps = doc["waypoints"]
    assert [wps[0]["x_m"], wps[0]["y_m"]] == [-150.0, 0.0] and [wps[-1]["x_m"], wps[-1]["y_m"]] == [150.0, 0.0]
    for wp in wps:
        assert set(wp) == {"x_m", "y_m", "lat", "lon", "alt_m"} and wp["alt_m"] == 100.0
        lat, lon = enu_to_geodetic(wp["x_m"], wp["y_m"], LAT0, LON0)
        assert wp["lat"] == pytest.approx(lat, abs=1e-8) and wp["lon"] == pytest.approx(lon, abs=1e-8)
    assert out.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    lines = out.with_suffix(".waypoints").read_text().splitlines()
    assert lines[0] == "QGC WPL 110"
    rows = [line.split("\t") for line in lines[1:]]
    assert all(len(r) == 12 for r in rows)
    assert [int(r[0]) for r in rows] == list(range(len(rows)))
    assert rows[0][1:4] == ["1", "0", "16"] and float(rows[0][10]) == 412.0          # home, absolute alt
    assert rows[1][1:4] == ["0", "3", "22"] and float(rows[1][10]) == 100.0          # takeoff
    assert all(r[1:4] == ["0", "3", "16"] for r in rows[2:-1])                       # waypoints
    assert rows[-1][2:4] == ["3", "21"]                                              # land at the goal
    assert len(rows) == 1 + 1 + (len(wps) - 1) + 1
    assert float(rows[2][8]) == pytest.approx(wps[1]["lat"], abs=1e-8)
    assert "waypoints" in capsys.readouterr().out


def test_wpl_loads_in_pymavlink(world):
    mavwp = pytest.importorskip("pymavlink.mavwp")
    assert main(plan_args(world, "--format", "wpl", "--end", "rtl")) == 0
    loader = mavwp.MAVWPLoader()
    n = loader.load(str(world["tmp"] / "route.waypoints"))
    assert n >= 4
    assert loader.wp(1).command == 22 and loader.wp(n - 1).command == 20
    assert loader.wp(2).frame == 3


def test_json_format_writes_no_wpl(world):
    assert main(plan_args(world, "--set", "waypoint_spacing_m=20")) == 0
    assert not (world["tmp"] / "route.waypoints").exists()
    doc = json.loads((world["tmp"] / "route.json").read_text())
    xy = np.array([[w["x_m"], w["y_m"]] for w in doc["waypoints"]])
    assert np.hypot(*np.diff(xy, axis=0).T).max() <= 20.0 + 1e-3


@pytest.mark.parametrize("mutate, flag", [
    (lambda a: a.__setitem__(a.index("--start=-150,0"), "--start=abc"), "--start"),
    (lambda a: a.__setitem__(a.index("--goal=150,0"), "--goal=1,2,3"), "--goal"),
    (lambda a: a.__setitem__(a.index("--goal=150,0"), "--goal=900,0"), "--goal"),
    (lambda a: a.__setitem__(a.index("--start=-150,0"), "--start=0,0"), "--start"),
])
def test_bad_points_exit_2_with_one_line(world, capsys, mutate, flag):
    args = plan_args(world)
    mutate(args)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {flag}") and err.count("\n") == 1


def test_wrong_size_map_exit_2(world, capsys):
    np.savez(world["map"], probability=np.full((H, W + 10), 0.9, np.float32))
    assert main(plan_args(world)) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --assistant-map") and "210x160" in err and err.count("\n") == 1


def test_all_nan_map_and_missing_files_exit_2(world, capsys):
    np.savez(world["map"], probability=np.full((H, W), np.nan, np.float32))
    assert main(plan_args(world)) == 2
    assert "NaN" in capsys.readouterr().err
    world["map"].write_bytes(b"not a zip")
    assert main(plan_args(world)) == 2
    assert "cannot read" in capsys.readouterr().err
    (world["dir"] / "manifest.json").unlink()
    assert main(plan_args(world)) == 2
    err = capsys.readouterr().err
    assert "manifest.json" in err and err.count("\n") == 1


def test_no_path_exit_2(world, capsys):
    prob = world["prob"].copy()
    prob[:, 140:150] = 0.1               # a wall from north to south between start and goal
    np.savez(world["map"], probability=prob)
    assert main(plan_args(world)) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no route") and err.count("\n") == 1


def test_cli_subprocess_exit_code(world):
    args = plan_args(world)
    args[args.index("--start=-150,0")] = "--start=1;2"
    code = f"import sys; from scenenav.app.commands.plan import main; sys.exit(main({args!r}))"
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert "--start '1;2': expected X,Y" in proc.stderr and "Traceback" not in proc.stderr


def test_parse_xy():
    assert parse_xy("-12.5, 40", "--start") == (-12.5, 40.0)
    with pytest.raises(UserError, match="finite X,Y"):
        parse_xy("nan,1", "--start")


def test_bench_small_json():
    buf = io.StringIO()
    report = run_bench(sizes=((300, 260),), json_out=True, out=buf)
    assert json.loads(buf.getvalue()) == report
    row = report["results"][0]
    assert row["width_px"] == 300 and row["plan_time_s"] >= 0.0


def test_negative_coordinates_as_separate_arguments(world):
    """`--start -150,0` (no '=') works through the scenenav command, as users type it."""
    args = plan_args(world)
    i = args.index("--start=-150,0")
    args[i:i + 2] = ["--start", "-150,0", "--goal", "150,-0.5"]
    proc = subprocess.run([sys.executable, "-m", "scenenav.app.cli", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((world["tmp"] / "route.json").read_text())
    assert doc["start_xy_m"] == [-150.0, 0.0] and doc["goal_xy_m"] == [150.0, -0.5]


def test_glue_negative_values_only_touches_number_lists():
    from scenenav.app.cli import glue_negative_values
    assert glue_negative_values(["plan", "--start", "-1,2", "--goal", "3,-4"]) == \
        ["plan", "--start=-1,2", "--goal", "3,-4"]
    assert glue_negative_values(["run", "--out", "x", "-h"]) == ["run", "--out", "x", "-h"]
    assert glue_negative_values(["--set", "-1"]) == ["--set", "-1"]


def test_keep_footprint_on_map_flag_reaches_the_planner(world):
    assert main(plan_args(world, out="off.json")) == 0
    assert json.loads((world["tmp"] / "off.json").read_text())["planner"]["keep_footprint_on_map"] is False
    assert main(plan_args(world, "--keep-footprint-on-map", "--altitude-m", "60", out="on.json")) == 0
    doc = json.loads((world["tmp"] / "on.json").read_text())
    assert doc["planner"]["keep_footprint_on_map"] is True
    radius = 60.0 * math.tan(math.radians(30.0))
    for wp in doc["waypoints"]:
        assert min(W * M_PER_PX / 2 - abs(wp["x_m"]), H * M_PER_PX / 2 - abs(wp["y_m"])) >= radius - 1e-6
