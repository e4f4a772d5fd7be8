"""`scenenav world import` of a GeoTIFF with a DSM on the command line: what it prints and writes,
and bad input as one line `error: ...` with exit code 2 and nothing written."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from support.geotiffs import centred_transform, pixel_enu, write_raster

UTM = "EPSG:32632"


def scenenav(*args):
    return subprocess.run([sys.executable, "-m", "scenenav.app.cli", *args], capture_output=True,
                          text=True, timeout=120)


@pytest.fixture
def rasters(tmp_path):
    tr = centred_transform(UTM, 48.0, 11.2, 0.5, 400, 400)
    x, y = pixel_enu(UTM, tr, 400, 400, 48.0, 11.2)
    rgb = np.full((3, 400, 400), 60, np.uint8)
    box = (np.abs(x - 30.0) < 10.0) & (np.abs(y + 20.0) < 10.0)
    rgb[:, box] = 220
    write_raster(tmp_path / "ortho.tif", rgb, UTM, tr)
    write_raster(tmp_path / "plain.tif", rgb, None, None)
    write_raster(tmp_path / "ndsm.tif", np.where(box, 12.0, 0.0).astype(np.float32), UTM, tr)
    (tmp_path / "junk.tif").write_bytes(b"II*\x00 not a tiff")
    return tmp_path


def test_import_geotiff_with_dsm_and_info(rasters, capsys):
    from scenenav.app.cli import main
    out = rasters / "w"
    assert main(["world", "import", str(rasters / "ortho.tif"), "--dsm", str(rasters / "ndsm.tif"),
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "EPSG:32632" in text and "DSM up to 12.0 m" in text and "48.000000, 11.200000" in text
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["source_crs"] == UTM and manifest["has_dsm"] is True
    assert manifest["local_projection"].startswith("+proj=aeqd +lat_0=48.0")
    assert (out / "dsm.png").is_file()
    assert main(["world", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "source crs:  EPSG:32632" in text and "surface:     DSM" in text


def test_bad_import_is_one_line_exit_2(rasters):
    # in a real process: GDAL must not add lines of its own to stderr
    r = scenenav("world", "import", str(rasters / "junk.tif"), "--out", str(rasters / "bad"))
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "not a raster image" in lines[0], r.stderr
    assert not (rasters / "bad").exists()


@pytest.mark.parametrize("args,needle", [
    (["plain.tif"], "pass --m-per-px"),
    (["ortho.tif", "--dsm", "junk.tif"], "not a raster DSM"),
    (["ortho.tif", "--dsm", "ndsm.tif", "--dtm", "ndsm.tif"], "--dsm-kind dsm"),
    (["ortho.tif", "--origin", "48,11"], "--origin"),
])
def test_bad_import_in_process(rasters, capfd, args, needle):
    from scenenav.app.cli import main
    args = [str(rasters / a) if a.endswith(".tif") else a for a in args]
    assert main(["world", "import", *args, "--out", str(rasters / "bad")]) == 2
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], err
    assert not (rasters / "bad").exists()


def test_an_out_folder_that_is_not_empty_is_refused_unless_forced(rasters, capfd):
    from scenenav.app.cli import main
    out = rasters / "kept"
    out.mkdir()
    (out / "thesis.txt").write_text("years of work")
    assert main(["world", "import", str(rasters / "ortho.tif"), "--out", str(out)]) == 2
    err = capfd.readouterr().err
    assert "holds other files" in err and "--force" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in out.iterdir()) == ["thesis.txt"]
    world = rasters / "w2"
    assert main(["world", "import", str(rasters / "ortho.tif"), "--dsm", str(rasters / "ndsm.tif"),
                 "--out", str(world)]) == 0
    assert main(["world", "generate", "--seed", "1", "--width-px", "256", "--height-px", "256",
                 "--out", str(world)]) == 2
    assert "holds a world" in capfd.readouterr().err
    assert (world / "dsm.png").is_file()                   # untouched
    assert main(["world", "import", str(rasters / "ortho.tif"), "--out", str(world), "--force"]) == 0
    assert not (world / "dsm.png").exists()                # replaced: the new world has no DSM
