"""Evaluation against the true vehicle position: the reference misregistration undone, and the
errors split by the mean building height in the camera footprint (issue 11, item 5)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from scenenav.app.evaluation import evaluate_run, fix_table, hillshade
from scenenav.app.height_split import ErrorStats, footprint_mean_height_m, height_bins, split_by_height
from scenenav.app.scenario import load_scenario
from scenenav.core.formats.world_manifest import FORMAT_VERSION, ReferenceInfo, WarpTerm, WorldManifest
from worlds.world import World

MPP = 0.5
SIZE = 400                      # 200 m x 200 m


def _reference() -> ReferenceInfo:
    return ReferenceInfo(shift_east_m=1.2, shift_north_m=-0.7,
                         warp=(WarpTerm(0.8, 0.5, 1 / 150.0, 1 / 230.0, 0.3),))


def _world(heights: np.ndarray | None, reference: ReferenceInfo | None = None) -> World:
    man = WorldManifest(format_version=FORMAT_VERSION, name="box", width_px=SIZE, height_px=SIZE,
                        m_per_px=MPP, origin_lat_deg=0.0, origin_lon_deg=0.0, source="generated",
                        seed=None, has_landcover=False, has_junctions=False, has_dsm=heights is not None,
                        reference=reference or ReferenceInfo())
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (SIZE, SIZE, 3), dtype=np.uint8)
    facade = None if heights is None else np.zeros_like(img)
    return World(manifest=man, orthophoto=img, reference=img, dsm_m=heights, facade_rgb=facade)


def _write_run(run_dir, truth_xy, fixes_xy, z_m=100.0, accepted=None) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    n = len(truth_xy)
    t = np.arange(n) * 0.1
    rows = ["t_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,heading_deg,qw,qx,qy,qz"]
    rows += [f"{a:.3f},{x:.4f},{y:.4f},{z_m},0,0,0,0,1,0,0,0" for a, (x, y) in zip(t, truth_xy, strict=True)]
    (run_dir / "truth.csv").write_text("\n".join(rows) + "\n")
    acc = np.ones(n, dtype=int) if accepted is None else accepted
    rows = ["t_s,frame_seq,valid,accepted,x_m,y_m,time_total_ms"]
    rows += [f"{a:.3f},{i},1,{acc[i]},{x:.6f},{y:.6f},1.0"
             for i, (a, (x, y)) in enumerate(zip(t, fixes_xy, strict=True))]
    (run_dir / "fixes.csv").write_text("\n".join(rows) + "\n")


def test_a_fix_at_truth_plus_the_stated_offset_has_zero_error(tmp_path):
    ref = _reference()
    truth = np.column_stack([np.linspace(-60, 60, 25), np.linspace(30, -40, 25)])
    ox, oy = ref.offset_m(truth[:, 0], truth[:, 1])
    assert float(np.min(np.hypot(ox, oy))) > 0.3           # the offset is real everywhere here
    _write_run(tmp_path / "run", truth, truth + np.column_stack([ox, oy]))
    fx = fix_table(tmp_path / "run", 5.0, ref)
    np.testing.assert_allclose(fx["error_m"], 0.0, atol=1e-3)
    # Not undoing it (a world without misregistration) leaves exactly the offset as the error.
    raw = fix_table(tmp_path / "run", 5.0, ReferenceInfo())
    np.testing.assert_allclose(raw["error_m"], np.hypot(ox, oy), atol=1e-3)


def test_the_run_folder_names_the_world_whose_offset_is_undone(tmp_path):
    ref = _reference()
    world = _world(None, ref)
    world.save(tmp_path / "world")
    truth = np.column_stack([np.linspace(-20, 20, 10), np.zeros(10)])
    ox, oy = ref.offset_m(truth[:, 0], truth[:, 1])
    _write_run(tmp_path / "run", truth, truth + np.column_stack([ox, oy]))
    (tmp_path / "run" / "scenario.yaml").write_text(f"world: {tmp_path / 'world'}\n")
    np.testing.assert_allclose(fix_table(tmp_path / "run", 5.0)["error_m"], 0.0, atol=1e-3)


def test_footprint_mean_height_of_a_half_raised_world():
    heights = np.zeros((SIZE, SIZE), np.float32)
    heights[:, SIZE // 2:] = 10.0                          # the east half is 10 m high
    # 100 m altitude, 60 deg: a 115.5 m footprint; over x = 0 half of it is raised, at any heading.
    for hdg in (0.0, math.pi / 2, 0.3):
        h = footprint_mean_height_m(heights, MPP, 0.0, 0.0, hdg, 100.0, 60.0)
        assert h[0] == pytest.approx(5.0, abs=0.35)
    assert footprint_mean_height_m(heights, MPP, 60.0, 0.0, 0.0, 50.0, 60.0)[0] == pytest.approx(10.0)
    assert footprint_mean_height_m(heights, MPP, -60.0, 0.0, 0.0, 50.0, 60.0)[0] == pytest.approx(0.0)
    # A 60 m x 60 m box in the middle, seen from 100 m (footprint 115.47 m): share (60/115.47)^2.
    box = np.zeros((SIZE, SIZE), np.float32)
    box[140:260, 140:260] = 20.0
    h = footprint_mean_height_m(box, MPP, 0.0, 0.0, 0.0, 100.0, 60.0)[0]
    assert h == pytest.approx(20.0 * (60.0 / 115.47) ** 2, rel=0.05)
    assert math.isnan(footprint_mean_height_m(box, MPP, 0.0, 0.0, 0.0, float("nan"), 60.0)[0])


def test_error_stats_and_bins():
    e = np.array([0.5, 1.0, 3.0, 7.0, 30.0, np.nan])
    st = ErrorStats.of(e, 5.0)
    assert st.n == 6 and st.share_over_threshold == pytest.approx(3 / 6)   # NaN: no match = far off
    assert st.share_over_gross == pytest.approx(2 / 6)
    assert st.rms_up_to_threshold_m == pytest.approx(math.sqrt((0.25 + 1 + 9) / 3))
    labels = [b.label for b in height_bins()]
    assert labels == ["< 2 m", "2-6 m", "6-12 m", "12-20 m", ">= 20 m"]
    sp = split_by_height(np.array([1.0, 8.0, 2.0]), np.array([0.0, 13.0, 25.0]), 5.0)
    assert [b.stats.n for b in sp.bins] == [1, 0, 0, 1, 1]
    assert sp.bins[3].stats.share_over_threshold == 1.0 and sp.bins[0].stats.median_m == 1.0


def test_summary_splits_fix_errors_by_footprint_height(tmp_path):
    """A world raised only in its east half: fixes over the west are true, over the east false;
    the summary's split puts them in the < 2 m and >= 20 m bins, and the plot shows the DSM."""
    heights = np.zeros((SIZE, SIZE), np.float32)
    heights[:, 300:] = 30.0                               # x > 50 m is 30 m high
    ref = _reference()
    world = _world(heights, ref)
    n = 20
    west = np.column_stack([np.full(n, -70.0), np.linspace(-50, 50, n)])
    east = np.column_stack([np.full(n, 85.0), np.linspace(-50, 50, n)])
    truth = np.vstack([west, east])
    ox, oy = ref.offset_m(truth[:, 0], truth[:, 1])
    fixes = truth + np.column_stack([ox, oy])
    fixes[n:, 0] += 12.0                                  # the east fixes are 12 m off
    _write_run(tmp_path, truth, fixes, z_m=40.0)          # footprint 46 m: all inside its half
    cfg = load_scenario(None, ("sim.camera.fov_deg=60",))
    summary = evaluate_run(tmp_path, cfg, world, wall_time_s=1.0)
    split = summary["fix_errors_by_height"]
    by = {b["label"]: b for b in split["bins"]}
    assert by["< 2 m"]["n"] == n and by["< 2 m"]["share_over_threshold"] == 0.0
    assert by["< 2 m"]["median_m"] == pytest.approx(0.0, abs=1e-3)
    assert by[">= 20 m"]["n"] == n and by[">= 20 m"]["share_over_threshold"] == 1.0
    assert by[">= 20 m"]["median_m"] == pytest.approx(12.0, abs=1e-3)
    assert by[">= 20 m"]["mean_height_m"] == pytest.approx(30.0)
    assert summary["false_fixes"] == n and summary["world_has_dsm"] is True
    assert summary["reference_misregistration_max_m"] > 0.5
    assert json.loads((tmp_path / "summary.json").read_text())["fix_errors_by_height"] == split
    assert (tmp_path / "trajectory.png").stat().st_size > 10_000


def test_hillshade_lights_slopes_facing_the_sun():
    h = np.zeros((50, 50))
    h[:, 25:] = np.arange(25)[None, :] * 1.0             # rises towards the east: faces west
    sh = hillshade(h, 1.0, azimuth_deg=270.0, altitude_deg=45.0)   # sun in the west
    assert sh[25, 40] > sh[25, 5] > 0.5 and hillshade(h, 1.0, azimuth_deg=90.0)[25, 40] < sh[25, 5]


def test_a_run_written_by_another_version_is_still_evaluated_against_its_world(tmp_path):
    """fix_table without a reference reads the world from the run's scenario.yaml; a key that this
    version does not know (a run from a newer scenenav, or an older one's dropped key) must not stop
    it: a campaign's report over 28 finished flights once failed at the end on exactly this."""
    ref = _reference()
    _world(None, ref).save(tmp_path / "world")
    truth = np.column_stack([np.linspace(-60, 60, 25), np.linspace(30, -40, 25)])
    ox, oy = ref.offset_m(truth[:, 0], truth[:, 1])
    run = tmp_path / "run"
    _write_run(run, truth, truth + np.column_stack([ox, oy]))
    (run / "scenario.yaml").write_text(f"world: {tmp_path / 'world'}\nperception:\n  a_key_from_elsewhere: 3\n")
    fx = fix_table(run, 5.0)
    np.testing.assert_allclose(fx["error_m"], 0.0, atol=1e-3)      # the world's misregistration undone


@pytest.mark.parametrize(("text", "what"), [("world: [1, 2]\n", "world = [1, 2]"), ("a: [\n", "is not valid YAML")])
def test_a_broken_run_scenario_is_one_clear_error(tmp_path, text, what):
    from scenenav.core.errors import UserError
    run = tmp_path / "run"
    _write_run(run, np.zeros((3, 2)), np.zeros((3, 2)))
    (run / "scenario.yaml").write_text(text)
    with pytest.raises(UserError, match=re.escape(what)):
        fix_table(run, 5.0)


def test_the_fixes_headings_are_scored_against_the_true_heading(tmp_path):
    """fixes.csv ``heading_deg`` (VisionFix v2) against the true heading at the capture, across
    north (359 against 1 degree is 2 degrees off); a file without the column scores nothing."""
    from scenenav.app.evaluation import fix_metrics
    n = 6
    truth = np.zeros((n, 2))
    _write_run(tmp_path / "old", truth, truth)
    assert fix_metrics(fix_table(tmp_path / "old", 5.0))["fixes_with_heading"] == 0
    run = tmp_path / "run"
    _write_run(run, truth, truth)
    rows = ["t_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,heading_deg,qw,qx,qy,qz"]
    rows += [f"{0.1 * i:.3f},0,0,100,0,0,0,1.0,1,0,0,0" for i in range(n)]
    (run / "truth.csv").write_text("\n".join(rows) + "\n")
    lines = (run / "fixes.csv").read_text().splitlines()
    heads = ["359.0", "", "3.0", "1.0", "", "5.0"]         # errors -2, 2, 0, 4 degrees
    (run / "fixes.csv").write_text("\n".join([lines[0] + ",heading_deg"]
                                             + [f"{r},{h}" for r, h in zip(lines[1:], heads, strict=True)]) + "\n")
    m = fix_metrics(fix_table(run, 5.0))
    assert m["fixes_with_heading"] == 4
    assert m["fix_heading_rms_error_deg"] == pytest.approx(math.sqrt((4 + 4 + 0 + 16) / 4))
