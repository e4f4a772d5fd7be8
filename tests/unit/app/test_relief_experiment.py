"""``scenenav experiment relief`` on a tiny 3-D world: it runs, writes the table and the JSON, and
its figures are in range (issue 11: flat vs 3-D capture, ortho vs perspective reference)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest

from scenenav.app.relief_experiment import Comparison, run_relief, sample_positions
from scenenav.core.formats.world_manifest import ReferenceInfo
from worlds.world import World

N = 8
CLI = ("-m", "scenenav.app.cli")


@pytest.fixture(scope="module")
def tiny_city(tmp_path_factory):
    """A 700 x 700 px generated 3-D city: its DSM, both references and its stated misregistration."""
    from worlds.generator import CityConfig, generate_world
    world = generate_world(CityConfig(seed=3, width_px=700, height_px=700))
    assert world.dsm_m is not None and world.reference_perspective is not None
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
    assert flat["rms_up_to_threshold_m"] < 1.0           # the misregistration is undone
    for res in doc["comparisons"].values():
        o = res["overall"]
        assert sum(b["n"] for b in res["bins"]) == N
        assert 0.0 <= o["share_over_gross"] <= o["share_over_threshold"] <= 1.0
    assert 0.0 < doc["mean_footprint_height_m"] < 30.0 and doc["misregistration_max_m"] > 0.5


def test_a_flat_world_runs_the_flat_comparison_only(small_world, tmp_path):
    w = small_world
    man = dataclasses.replace(w.manifest, has_dsm=False, has_landcover=False, has_junctions=False,
                              reference=ReferenceInfo())
    World(manifest=man, orthophoto=w.orthophoto, reference=w.reference).save(tmp_path / "flat")
    doc = run_relief(str(tmp_path / "flat"), None, positions=2, progress=False)
    assert list(doc["comparisons"]) == ["flat-ortho"]
    assert set(doc["skipped"]) == {"relief-ortho", "relief-perspective"}


def test_a_windowed_search_cannot_land_further_than_its_window(tiny_city):
    doc = run_relief(str(tiny_city), None, positions=4, progress=False, window_px=10)
    assert doc["window_px"] == 10 and "window of the template + 10 px" in doc["matcher"]
    for res in doc["comparisons"].values():
        assert res["overall"]["share_over_gross"] == 0.0          # 10 px = 5.3 m at most
