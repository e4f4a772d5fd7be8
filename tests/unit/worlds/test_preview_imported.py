"""``scenenav world preview`` of an imported world (a GeoTIFF orthophoto, optionally a DSM): an
imported world has no land cover, so its preview draws no empty land-cover panel. With a DSM the
third panel is the DSM heights, titled; a flat one shows the orthophoto and the reference only.

The GeoTIFFs are written here with rasterio (support.geotiffs): 300 px of UTM zone 32N at 0.5 m on
its central meridian, a dark ground with a bright square roof; the nDSM raises that roof by 12 m.
"""

from __future__ import annotations

import argparse
import dataclasses

import cv2
import numpy as np
import pytest
from support.geotiffs import centred_transform, pixel_enu, write_raster

from scenenav.app.commands.world import has_landcover_info, preview_third_panel, register, render_preview
from worlds.landcover import LandCover, colourise
from worlds.world import World, load_world

UTM = "EPSG:32632"
LAT0, LON0 = 48.0, 9.0          # the zone's central meridian: grid north is true north
SIZE_PX = 300
RES_M = 0.5
ROOF = (-15.0, 15.0, -15.0, 15.0)    # x0, x1, y0, y1 in ENU metres around the centre
ROOF_H_M = 12.0
SEP_PX = 4                           # white gap between two panels


def _cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="scenenav")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def _roof_mask() -> tuple[np.ndarray, object]:
    tr = centred_transform(UTM, LAT0, LON0, RES_M, SIZE_PX, SIZE_PX)
    x, y = pixel_enu(UTM, tr, SIZE_PX, SIZE_PX, LAT0, LON0)
    return (x >= ROOF[0]) & (x < ROOF[1]) & (y >= ROOF[2]) & (y < ROOF[3]), tr


def _import(tmp_path, with_dsm: bool) -> World:
    roof, tr = _roof_mask()
    rgb = np.full((3, SIZE_PX, SIZE_PX), 60, dtype=np.uint8)
    rgb[:, roof] = 220
    write_raster(tmp_path / "ortho.tif", rgb, UTM, tr)
    argv = ["world", "import", str(tmp_path / "ortho.tif"), "--m-per-px", str(RES_M), "--quiet",
            "--reference-height-m", "0", "--out", str(tmp_path / "w")]
    if with_dsm:
        ndsm = np.where(roof, ROOF_H_M, 0.0).astype(np.float32)
        write_raster(tmp_path / "ndsm.tif", ndsm, UTM, tr)
        argv += ["--dsm", str(tmp_path / "ndsm.tif")]
    assert _cli(argv) == 0
    world = load_world(tmp_path / "w")
    assert world.landcover is None and not world.manifest.has_landcover
    assert "landcover" in world.manifest.missing_ground_truth
    return world


def _preview(tmp_path) -> np.ndarray:
    out = tmp_path / "preview.png"
    assert _cli(["world", "preview", str(tmp_path / "w"), "--out", str(out)]) == 0
    bgr = cv2.imread(str(out))
    assert bgr is not None
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def test_imported_world_with_a_dsm_previews_its_heights_instead_of_an_empty_land_cover(tmp_path):
    world = _import(tmp_path, with_dsm=True)
    w, h = world.width_px, world.height_px
    img = _preview(tmp_path)
    assert img.shape == (h, 3 * w + 2 * SEP_PX, 3)
    third = img[:, 2 * (w + SEP_PX):].astype(int)
    assert np.array_equal(img[:, :w], world.orthophoto)           # first panels unchanged
    # the heights: the roof (12 m) is drawn apart from the ground (0 m), not a blank panel
    assert world.dsm_m is not None
    raised = world.dsm_m > ROOF_H_M / 2
    ground = world.dsm_m < 0.5
    ground[:60] = False                                            # below the title band
    assert raised.sum() > 1000 and ground.sum() > 1000
    roof_rgb = np.median(third[raised], axis=0)
    ground_rgb = np.median(third[ground], axis=0)
    assert np.abs(roof_rgb - ground_rgb).sum() > 200, (roof_rgb, ground_rgb)
    assert np.ptp(third[ground], axis=0).max() < 10                # flat ground: one colour
    # a title says what the panel is: dark text on a white band at the top
    band = third[:20]
    assert (band == 255).all(axis=-1).mean() > 0.5 and (band.sum(axis=-1) < 200).any()
    _, title = preview_third_panel(world)
    assert "DSM heights" in title[0] and f"{float(world.dsm_m.max()):.1f} m" in title[1]


def test_flat_imported_world_previews_two_panels(tmp_path):
    world = _import(tmp_path, with_dsm=False)
    w, h = world.width_px, world.height_px
    img = _preview(tmp_path)
    assert img.shape == (h, 2 * w + SEP_PX, 3)                    # no empty third panel
    assert np.array_equal(img[:, :w], world.orthophoto)
    assert np.array_equal(img[:, w + SEP_PX:], world.reference)
    assert (img[:, w:w + SEP_PX] == 255).all()
    assert preview_third_panel(world) is None


def test_land_cover_that_classifies_nothing_counts_as_none(tmp_path):
    world = _import(tmp_path, with_dsm=True)
    unknown = np.full((world.height_px, world.width_px), int(LandCover.UNKNOWN), dtype=np.uint8)
    assert not has_landcover_info(dataclasses.replace(world, landcover=unknown))
    _, title = preview_third_panel(dataclasses.replace(world, landcover=unknown))
    assert title and "DSM heights" in title[0]
    # a land cover with a class drawn is shown as before: its colours, no title
    roads = unknown.copy()
    roads[:, : world.width_px // 3] = int(LandCover.ROAD)
    covered = dataclasses.replace(world, landcover=roads)
    assert has_landcover_info(covered)
    panel, title = preview_third_panel(covered)
    assert title == () and np.array_equal(panel, colourise(roads))
    img = render_preview(covered, max_width_px=10_000)
    assert np.array_equal(img[:, 2 * (world.width_px + SEP_PX):], colourise(roads))


@pytest.mark.parametrize("max_width_px", [300, 900])
def test_the_heights_title_fits_a_downscaled_preview(tmp_path, max_width_px):
    world = _import(tmp_path, with_dsm=True)
    img = render_preview(world, max_width_px)
    assert img.shape[1] <= max_width_px + 2 * SEP_PX
    panel_w = (img.shape[1] - 2 * SEP_PX) // 3
    band = img[:12, 2 * (panel_w + SEP_PX):].astype(int)
    assert (band.sum(axis=-1) < 200).any()                          # text drawn after scaling
