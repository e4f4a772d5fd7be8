"""``scenenav experiment relief`` on a tiny 3-D world: it runs, writes the table and the JSON, and
its figures are in range (issue 11: flat vs 3-D capture, ortho vs perspective reference)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from scenenav.app.relief_experiment import Comparison, run_relief, sample_positions
from scenenav.core.formats.world_manifest import ReferenceInfo, WarpTerm
from worlds.landcover import LandCover
from worlds.world import World

N = 8
CLI = ("-m", "scenenav.app.cli")


@pytest.fixture(scope="module")
def tiny_city(tmp_path_factory):
    """A 700 x 700 px generated city whose buildings stand 15 m tall, with a misregistered
    reference (shift + warp, drawn as the manifest states it) used as both references."""
    from worlds.generator import CityConfig, generate_world
    w = generate_world(CityConfig(seed=3, width_px=700, height_px=700))
    built = np.isin(w.landcover, [int(LandCover.BUILDING_UNIFORM), int(LandCover.BUILDING_TEXTURED)])
    heights = np.where(built, 15.0, 0.0).astype(np.float32)
    info = ReferenceInfo(camera_height_m=500.0, shift_east_m=1.0, shift_north_m=0.5,
                         warp=(WarpTerm(0.6, 0.3, 1 / 120.0, 1 / 200.0, 0.2),))
    hh, ww = heights.shape
    uu, vv = np.meshgrid(np.arange(ww) + 0.5, np.arange(hh) + 0.5)
    x, y = w.pixel_to_world(uu, vv)
    dx, dy = info.offset_m(x, y)        # the reference pixel at p shows the ground at p - offset(p)
    mx = ((x - dx) / w.m_per_px + ww / 2 - 0.5).astype(np.float32)
    my = (hh / 2 - (y - dy) / w.m_per_px - 0.5).astype(np.float32)
    ref = cv2.remap(w.reference, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
    world = World(manifest=dataclasses.replace(w.manifest, has_dsm=True, reference=info),
                  orthophoto=w.orthophoto, reference=ref, landcover=w.landcover, junctions=w.junctions,
                  dsm_m=heights, reference_perspective=ref)
    folder = tmp_path_factory.mktemp("city") / "world"
    world.save(folder)
    return folder


def test_positions_are_seeded_and_away_from_the_edge(small_world):
    a, b = sample_positions(small_world, 50, 1), sample_positions(small_world, 50, 1)
    assert a == b and a != sample_positions(small_world, 50, 2)
    margin = (115.47 / 2 ** 0.5 + 10.0) / small_world.m_per_px
    assert all(margin <= p.u_px <= small_world.width_px - margin for p in a)


def test_relief_comparison_on_a_tiny_city(tiny_city, tmp_path):
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, *CLI, "experiment", "relief", "--world",
                        str(tiny_city), "--positions", str(N), "--out", str(out), "--json", "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(r.stdout)                                # stdout is the JSON document alone
    assert json.loads((out / "relief.json").read_text()) == doc
    md = (out / "relief.md").read_text()
    assert "3-D capture vs perspective reference" in md and "| >= 20 m |" in md
    assert set(doc["comparisons"]) == {c.value for c in Comparison} and doc["skipped"] == {}
    flat = doc["comparisons"]["flat-ortho"]["overall"]
    assert flat["n"] == N and flat["median_m"] < 2.0 and flat["share_over_threshold"] <= 0.25
    assert flat["rms_up_to_threshold_m"] < 2.0           # the misregistration (up to 1.8 m) is undone
    for res in doc["comparisons"].values():
        o = res["overall"]
        assert sum(b["n"] for b in res["bins"]) == N
        assert 0.0 <= o["share_over_gross"] <= o["share_over_threshold"] <= 1.0
    assert 0.0 < doc["mean_footprint_height_m"] < 15.0 and doc["misregistration_max_m"] > 1.0


def test_a_flat_world_runs_the_flat_comparison_only(small_world, tmp_path):
    small_world.save(tmp_path / "flat")
    doc = run_relief(str(tmp_path / "flat"), None, positions=2, progress=False)
    assert list(doc["comparisons"]) == ["flat-ortho"]
    assert set(doc["skipped"]) == {"relief-ortho", "relief-perspective"}
