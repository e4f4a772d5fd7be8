"""A GeoTIFF with a DSM imports and flies: `scenenav world import` of a UTM orthophoto, its
reference of another day and an nDSM, then a short lockstep `scenenav run` over the imported world,
matching against the perspective reference the import rendered from the DSM.

The rasters are a generated city (its two days and its land cover, heights given to buildings and
trees) written as UTM zone 32N GeoTIFFs 2.2 degrees east of the central meridian, so the import
has to turn the image by the meridian convergence (1.6 degrees) onto a true-north grid.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
from support.geotiffs import centred_transform, write_raster

from worlds.landcover import LandCover
from worlds.world import load_world

UTM = "EPSG:32632"


def scenenav(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "scenenav.app.cli", *args], capture_output=True,
                          text=True, timeout=timeout)


def test_geotiff_with_dsm_imports_and_flies(tmp_path, small_world):
    h, w = small_world.height_px, small_world.width_px
    tr = centred_transform(UTM, 48.0, 11.2, 0.5, w, h)
    write_raster(tmp_path / "ortho.tif", np.moveaxis(small_world.orthophoto, 2, 0), UTM, tr,
                 compress="deflate")
    write_raster(tmp_path / "ref.tif", np.moveaxis(small_world.reference, 2, 0), UTM, tr, compress="deflate")
    cover = small_world.landcover
    ndsm = np.zeros((h, w), np.float32)
    ndsm[(cover == LandCover.BUILDING_TEXTURED) | (cover == LandCover.BUILDING_UNIFORM)] = 12.0
    ndsm[cover == LandCover.FOREST] = 16.0
    write_raster(tmp_path / "ndsm.tif", ndsm, UTM, tr, compress="deflate")

    world_dir = tmp_path / "world"
    r = scenenav("world", "import", str(tmp_path / "ortho.tif"), "--reference", str(tmp_path / "ref.tif"),
                 "--dsm", str(tmp_path / "ndsm.tif"), "--out", str(world_dir))
    assert r.returncode == 0, r.stderr[-2000:]
    world = load_world(world_dir)
    assert world.manifest.has_dsm and world.manifest.source_crs == UTM
    assert abs(float(np.mean(world.heights_m > 6.0)) - float(np.mean(ndsm > 6.0))) < 0.02
    # the reference the paper and realistic profiles match against, rendered from 500 m with the DSM
    assert world.manifest.reference.camera_height_m == 500.0 and world.reference_perspective is not None

    out = tmp_path / "run"
    r = scenenav("run", "--out", str(out), "--quiet", "--set", f"world={world_dir}",
                 "--set", "duration_s=5", "--set", "perception.method=statistical",
                 "--set", "perception.reference=perspective",
                 "--set", "autopilot.mavlink_tcp_port=0", "--set", "autopilot.mavlink_udp_out=none")
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads((out / "summary.json").read_text())
    assert 4.9 <= s["sim_time_s"] <= 5.1
    assert s["fixes_total"] >= 40                     # 10 Hz camera for 5 s, minus the latency
    assert s["fixes_accepted"] >= 10 and s["fix_rms_error_accepted_m"] < 5.0
    facts = json.loads((out / "run.json").read_text())
    assert facts["reference_map"].endswith("reference_perspective.png") and facts["reference_kind"] == "perspective"
