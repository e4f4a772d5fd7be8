"""GeoTIFF import (worlds/importer.py, worlds/georaster.py, worlds/ground.py): known ground points
land on the right pixel whatever the source CRS, grid north is true north, a DSM lands under its
roofs, and every bad input is one line before anything is written.

The rasters are written here with rasterio and painted by ground position (support.geotiffs): a
UTM zone 32N image at 11.2 E (2.2 degrees east of the zone's central meridian, so its grid north
is 1.6 degrees off true north) and a Web Mercator image at 48.1 N (whose metres are 1.5 ground
metres).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.geotiffs import centred_transform, north_of, pixel_enu, write_raster

from scenenav.core import frames
from scenenav.core.errors import UserError
from worlds.ground import estimate_ground_m
from worlds.importer import import_world
from worlds.world import load_world

UTM = "EPSG:32632"
MERC = "EPSG:3857"
LAT0, LON0 = 48.0, 11.2          # UTM 32N central meridian is 9 E
MLAT0, MLON0 = 48.1, 11.57
SIZE = 600
MARKER_R_M = 3.0
NORTH_M = 60.0
BG = 40
BOX = (20.0, 60.0, -50.0, -20.0)   # x0, x1, y0, y1 in ENU metres around the origin
BOX_H_M = 15.0


def _marker_a(lat0, lon0):
    return lat0 - 0.0004, lon0 + 0.0006


def _paint(crs, lat0, lon0, res, size=SIZE, box=False):
    """An RGB raster of a dark ground with a red disc at marker A, a green disc NORTH_M due north
    of it, and optionally a blue roof over BOX; returns (bands, transform)."""
    tr = centred_transform(crs, lat0, lon0, res, size, size)
    x, y = pixel_enu(crs, tr, size, size, lat0, lon0)
    rgb = np.full((3, size, size), BG, dtype=np.uint8)
    alat, alon = _marker_a(lat0, lon0)
    for (lat, lon), band in (((alat, alon), 0), ((north_of(alat, NORTH_M), alon), 1)):
        mx, my = frames.geodetic_to_enu(lat, lon, lat0, lon0)
        rgb[band][(x - mx) ** 2 + (y - my) ** 2 <= MARKER_R_M ** 2] = 255
    if box:
        inside = (x >= BOX[0]) & (x < BOX[1]) & (y >= BOX[2]) & (y < BOX[3])
        rgb[2][inside] = 255
    return rgb, tr


def _centroid(world, band):
    img = world.orthophoto.astype(float)
    w = np.clip(img[..., band] - img[..., 0 if band else 1], 0, None)
    w[w < 30] = 0
    rows, cols = np.nonzero(w)
    assert rows.size > 10, "marker not found"
    ww = w[rows, cols]
    return float(np.sum((cols + 0.5) * ww) / ww.sum()), float(np.sum((rows + 0.5) * ww) / ww.sum())


def _expected_px(world, lat, lon):
    m = world.manifest
    return world.world_to_pixel(*frames.geodetic_to_enu(lat, lon, m.origin_lat_deg, m.origin_lon_deg))


def _check_markers(world, lat0, lon0):
    alat, alon = _marker_a(lat0, lon0)
    ua, va = _centroid(world, 0)
    ea = _expected_px(world, alat, alon)
    assert math.hypot(ua - ea[0], va - ea[1]) < 1.0, ((ua, va), ea)
    ub, vb = _centroid(world, 1)
    eb = _expected_px(world, north_of(alat, NORTH_M), alon)
    assert math.hypot(ub - eb[0], vb - eb[1]) < 1.0, ((ub, vb), eb)
    # B is due north of A (grid north = true north) at the right distance (ground metres)
    du, dv = ub - ua, vb - va
    assert abs(math.degrees(math.atan2(du, -dv))) < 0.4, (du, dv)
    assert abs(math.hypot(du, dv) * world.m_per_px - NORTH_M) < world.m_per_px


def test_utm_image_lands_on_true_north_grid(tmp_path):
    rgb, tr = _paint(UTM, LAT0, LON0, 0.5)
    write_raster(tmp_path / "utm.tif", rgb, UTM, tr)
    world = import_world(tmp_path / "utm.tif", None, tmp_path / "w")
    m = world.manifest
    assert m.source_crs == UTM and m.local_projection.startswith("+proj=aeqd")
    assert abs(m.origin_lat_deg - LAT0) < 1e-7 and abs(m.origin_lon_deg - LON0) < 1e-7
    assert abs(m.m_per_px - 0.5) < 1e-3              # UTM scale factor ~0.9999 here
    # the source grid is turned by the meridian convergence (~ dlon * sin(lat) = 1.63 deg)
    assert abs(m.generator["source_up_azimuth_deg"] - (LON0 - 9.0) * math.sin(math.radians(LAT0))) < 0.02
    assert world.width_px > SIZE and world.width_px % 2 == 0      # the turned footprint, symmetric
    assert not m.has_dsm and world.dsm_m is None and "dsm" in m.missing_ground_truth
    assert "geodetic_origin" not in m.missing_ground_truth
    assert m.generator["nodata_share"] > 0.0 and tuple(world.orthophoto[0, 0]) == (0, 0, 0)
    _check_markers(world, LAT0, LON0)
    back = load_world(tmp_path / "w")
    assert back.manifest.source_crs == UTM and back.manifest.local_projection == m.local_projection


def test_web_mercator_image_keeps_ground_metres(tmp_path):
    rgb, tr = _paint(MERC, MLAT0, MLON0, 0.5)
    write_raster(tmp_path / "merc.tif", rgb, MERC, tr)
    world = import_world(tmp_path / "merc.tif", 0.4, tmp_path / "w")
    assert world.m_per_px == 0.4 and world.manifest.source_crs == MERC
    assert abs(world.manifest.generator["source_up_azimuth_deg"]) < 1e-6
    # 0.5 map metres are 0.5 cos(lat) sqrt(M N) / a ground metres (EPSG:3857's spherical formulas
    # on WGS-84 latitudes): the default grid keeps that resolution, not 0.5 m
    s = math.sin(math.radians(MLAT0))
    w = math.sqrt(1.0 - frames.WGS84_E2 * s * s)
    mn = math.sqrt((1.0 - frames.WGS84_E2) / w ** 3 * (1.0 / w)) * frames.WGS84_A_M
    expected = 0.5 * math.cos(math.radians(MLAT0)) * mn / frames.WGS84_A_M
    src_res = world.manifest.generator["source_m_per_px_at_centre"]
    assert abs(src_res - expected) < 1e-4 * expected and 0.33 < src_res < 0.34
    assert world.manifest.generator["image_resampling"] == "average"   # 0.4 m is coarser than 0.334
    _check_markers(world, MLAT0, MLON0)


def test_ndsm_in_another_crs_lands_under_its_roof(tmp_path):
    rgb, tr = _paint(UTM, LAT0, LON0, 0.5, box=True)
    write_raster(tmp_path / "utm.tif", rgb, UTM, tr)
    # the nDSM: Web Mercator, 1 map metre (0.67 ground metres) a pixel, with a nodata corner
    dtr = centred_transform(MERC, LAT0, LON0, 1.0, 400, 400)
    x, y = pixel_enu(MERC, dtr, 400, 400, LAT0, LON0)
    ndsm = np.zeros((400, 400), dtype=np.float32)
    ndsm[(x >= BOX[0]) & (x < BOX[1]) & (y >= BOX[2]) & (y < BOX[3])] = BOX_H_M
    ndsm[:40, :40] = -9999.0
    write_raster(tmp_path / "ndsm.tif", ndsm, MERC, dtr, nodata=-9999.0)
    import_world(tmp_path / "utm.tif", None, tmp_path / "w", dsm=tmp_path / "ndsm.tif")
    world = load_world(tmp_path / "w")
    m = world.manifest
    assert m.has_dsm and "dsm" not in m.missing_ground_truth and world.dsm_m is not None
    assert m.generator["dsm_kind"] == "ndsm" and 0.5 < m.generator["dsm_coverage_share"] < 1.0
    img = world.orthophoto.astype(int)
    roof = (img[..., 2] - img[..., 0]) > 100
    raised = world.dsm_m > BOX_H_M / 2
    iou = np.sum(roof & raised) / np.sum(roof | raised)
    assert iou > 0.9, iou
    uc, vc = world.world_to_pixel((BOX[0] + BOX[1]) / 2, (BOX[2] + BOX[3]) / 2)
    assert abs(float(world.dsm_m[int(vc), int(uc)]) - BOX_H_M) < 0.011
    assert float(world.dsm_m.min()) == 0.0 and float(world.dsm_m.max()) <= BOX_H_M + 0.011
    assert float(np.mean(raised)) < 0.02                              # only the box is raised


def _dsm_scene(tmp_path):
    """UTM image with the box, and a DSM of elevations 480 m + a 2 % slope + the box + a tree row."""
    rgb, tr = _paint(UTM, LAT0, LON0, 0.5, box=True)
    write_raster(tmp_path / "utm.tif", rgb, UTM, tr)
    x, y = pixel_enu(UTM, tr, SIZE, SIZE, LAT0, LON0)
    ground = (480.0 + 0.02 * x - 0.01 * y).astype(np.float32)
    dsm = ground.copy()
    dsm[(x >= BOX[0]) & (x < BOX[1]) & (y >= BOX[2]) & (y < BOX[3])] += BOX_H_M
    dsm[(np.abs(y - 60.0) < 4.0) & (np.abs(x) < 100.0)] += 10.0       # a row of trees
    write_raster(tmp_path / "dsm.tif", dsm, UTM, tr)
    write_raster(tmp_path / "dtm.tif", ground, UTM, tr)
    return x, y, ground, dsm


def test_dsm_minus_dtm_and_minus_the_estimated_ground(tmp_path):
    _dsm_scene(tmp_path)
    box_c = ((BOX[0] + BOX[1]) / 2, (BOX[2] + BOX[3]) / 2)
    for label, dtm, tol in (("dtm", tmp_path / "dtm.tif", 0.05), ("estimate", None, 0.5)):
        world = import_world(tmp_path / "utm.tif", None, tmp_path / label, dsm=tmp_path / "dsm.tif",
                             dsm_kind="dsm", dtm=dtm)
        h = world.dsm_m
        assert h is not None
        uc, vc = world.world_to_pixel(*box_c)
        assert abs(float(h[int(vc), int(uc)]) - BOX_H_M) < tol, label
        ut, vt = world.world_to_pixel(0.0, 60.0)
        assert abs(float(h[int(vt), int(ut)]) - 10.0) < tol, label
        ug, vg = world.world_to_pixel(-80.0, -80.0)                    # open ground
        assert float(h[int(vg), int(ug)]) < tol, label
        assert float(np.mean(h > 1.0)) < 0.06, label                   # box + trees, nothing else
        assert world.manifest.generator["ground"].startswith("the DTM" if dtm else "estimated")


def test_ground_estimate_keeps_planes_and_removes_objects():
    yy, xx = np.mgrid[0:400, 0:400].astype(np.float32) * 0.5          # 200 m at 0.5 m/px
    ground = 300.0 + 0.03 * xx + 0.01 * yy
    dsm = ground.copy()
    dsm[100:200, 150:300] += 30.0                                     # a 75 x 50 m hall
    dsm[300:305, :] += 12.0                                           # a tree row across the map
    dsm[20:60, 20:60] = np.nan                                        # a nodata hole
    est = estimate_ground_m(dsm, 0.5, window_m=120.0)
    err = np.abs(est - ground)
    assert float(np.max(err[120:-120, 120:-120])) < 0.2           # farther than half a window from the edge
    assert np.percentile(err, 99) < 0.4 and float(err.max()) < 0.6  # edge bias ~ slope * window / 16
    # without the pad the opening would lower the rising edge by ~ slope * window / 2 = 1.8 m
    with pytest.raises(ValueError):
        estimate_ground_m(np.full((50, 50), np.nan, dtype=np.float32), 0.5)


def _one_line(fn, needle, out):
    with pytest.raises(UserError) as info:
        fn()
    text = str(info.value)
    assert "\n" not in text and needle in text, text
    assert not out.exists()


def test_bad_inputs_are_one_line_and_write_nothing(tmp_path):
    rgb, tr = _paint(UTM, LAT0, LON0, 0.5)
    img = write_raster(tmp_path / "utm.tif", rgb, UTM, tr)
    write_raster(tmp_path / "nocrs.tif", rgb, None, None)
    (tmp_path / "junk.tif").write_bytes(b"II*\x00 this is not a tiff at all")
    local_wkt = 'LOCAL_CS["site grid",UNIT["metre",1],AXIS["Easting",EAST],AXIS["Northing",NORTH]]'
    write_raster(tmp_path / "local.tif", rgb, local_wkt, tr)
    unitless = 'LOCAL_CS["arbitrary",UNIT["unknown",1]]'
    write_raster(tmp_path / "unitless.tif", rgb, unitless, tr)
    far = centred_transform(UTM, LAT0 + 0.1, LON0, 0.5, 300, 300)        # 11 km north
    write_raster(tmp_path / "far.tif", np.zeros((300, 300), np.float32), UTM, far)
    write_raster(tmp_path / "elev.tif", np.full((SIZE, SIZE), 520.0, np.float32), UTM, tr)
    write_raster(tmp_path / "dsm_small.tif", np.zeros((100, 100), np.float32), None, None)
    out = tmp_path / "w"
    cases = [
        (lambda: import_world(tmp_path / "missing.tif", None, out), "no such image"),
        (lambda: import_world(tmp_path / "junk.tif", None, out), "not a raster"),
        (lambda: import_world(tmp_path / "nocrs.tif", None, out), "pass --m-per-px"),
        (lambda: import_world(tmp_path / "local.tif", None, out), "not tied to the earth"),
        (lambda: import_world(tmp_path / "unitless.tif", None, out), "CRS"),
        (lambda: import_world(img, 0.0, out), "m-per-px"),
        (lambda: import_world(img, float("nan"), out), "m-per-px"),
        (lambda: import_world(img, 5.0, out), "too small"),
        (lambda: import_world(img, 0.005, out), "too large"),
        (lambda: import_world(img, None, out, origin_lat_lon=(1.0, 2.0)), "--origin"),
        (lambda: import_world(img, None, out, dsm=tmp_path / "far.tif"), "does not overlap"),
        (lambda: import_world(img, None, out, dsm=tmp_path / "nope.tif"), "no such DSM"),
        (lambda: import_world(img, None, out, dsm=tmp_path / "junk.tif"), "not a raster"),
        (lambda: import_world(img, None, out, dsm=tmp_path / "dsm_small.tif"), "pixel-aligned"),
        (lambda: import_world(img, None, out, dsm=tmp_path / "elev.tif"), "--dsm-kind dsm"),
        (lambda: import_world(img, None, out, dsm=img), "colour image"),          # RGB is no DSM
        (lambda: import_world(img, None, out, dtm=tmp_path / "elev.tif"), "without --dsm"),
        (lambda: import_world(img, None, out, reference=tmp_path / "far.tif"), "does not overlap"),
    ]
    for fn, needle in cases:
        _one_line(fn, needle, out)


def test_geotiff_without_crs_imports_as_a_plain_image(tmp_path, caplog):
    rgb, _ = _paint(UTM, LAT0, LON0, 0.5)
    write_raster(tmp_path / "nocrs.tif", rgb, None, None)
    heights = np.zeros((SIZE, SIZE), np.float32)
    heights[100:150, 200:260] = 9.0
    write_raster(tmp_path / "h.tif", heights, None, None)
    with caplog.at_level("WARNING"):
        world = import_world(tmp_path / "nocrs.tif", 0.5, tmp_path / "w", dsm=tmp_path / "h.tif")
    assert "plain image" in caplog.text
    assert (world.width_px, world.height_px, world.m_per_px) == (SIZE, SIZE, 0.5)
    assert np.array_equal(world.orthophoto, np.ascontiguousarray(np.moveaxis(rgb, 0, 2)))
    m = world.manifest
    assert m.source_crs is None and "geodetic_origin" in m.missing_ground_truth and m.has_dsm
    assert float(world.dsm_m[120, 230]) == pytest.approx(9.0) and float(world.dsm_m[0, 0]) == 0.0


def test_manifest_geo_fields_are_optional_and_checked():
    from scenenav.core.formats.world_manifest import WorldManifest
    base = {"format_version": 2, "name": "x", "width_px": 300, "height_px": 300, "m_per_px": 0.5,
            "origin_lat_deg": 48.0, "origin_lon_deg": 11.0, "source": "imported", "seed": None,
            "has_landcover": False, "has_junctions": False}
    old = WorldManifest.from_dict(dict(base), "m.json")              # a manifest written before
    assert old.source_crs is None and old.local_projection is None
    new = WorldManifest.from_dict(dict(base, source_crs=UTM, local_projection="+proj=aeqd"), "m.json")
    assert WorldManifest.from_json(new.to_json()).source_crs == UTM
    for key, bad in (("source_crs", 32632), ("local_projection", "  ")):
        with pytest.raises(UserError, match=f"m.json: {key}"):
            WorldManifest.from_dict(dict(base, **{key: bad}), "m.json")


def _roof_centre_m(world, img):
    """ENU centre (m) of the blue roof in ``img`` (a map-grid image of ``world``)."""
    rgb = img.astype(int)
    rows, cols = np.nonzero((rgb[..., 2] - rgb[..., 0]) > 100)
    assert rows.size > 100, "roof not found"
    x = (cols.mean() + 0.5 - world.width_px / 2.0) * world.m_per_px
    y = (world.height_px / 2.0 - (rows.mean() + 0.5)) * world.m_per_px
    return np.array([x, y])


def test_an_import_with_relief_renders_the_perspective_reference_the_profiles_match_against(tmp_path):
    from scenenav.core.formats.world_manifest import PERSPECTIVE_REFERENCE_FILE, REFERENCE_FILE, reference_file
    rgb, tr = _paint(UTM, LAT0, LON0, 0.5, box=True)
    write_raster(tmp_path / "utm.tif", rgb, UTM, tr)
    ndsm = np.zeros((SIZE, SIZE), dtype=np.float32)
    x, y = pixel_enu(UTM, tr, SIZE, SIZE, LAT0, LON0)
    ndsm[(x >= BOX[0]) & (x < BOX[1]) & (y >= BOX[2]) & (y < BOX[3])] = 60.0      # a 60 m tower
    write_raster(tmp_path / "ndsm.tif", ndsm, UTM, tr)
    import_world(tmp_path / "utm.tif", None, tmp_path / "w", dsm=tmp_path / "ndsm.tif", reference_height_m=300)
    world = load_world(tmp_path / "w")
    assert world.manifest.reference.camera_height_m == 300.0
    assert reference_file(world.manifest, "perspective") == PERSPECTIVE_REFERENCE_FILE
    persp = world.reference_map("perspective")
    assert persp is world.reference_perspective
    # seen from 300 m above the centre, the roof 60 m up is drawn away from the centre by 300 / 240
    top, seen = _roof_centre_m(world, world.reference), _roof_centre_m(world, persp)
    assert np.linalg.norm(seen) / np.linalg.norm(top) == pytest.approx(300.0 / 240.0, rel=0.03)
    # 0: no perspective reference; a profile asking for one gets one line saying how to get it
    import_world(tmp_path / "utm.tif", None, tmp_path / "none", dsm=tmp_path / "ndsm.tif", reference_height_m=0)
    bare = load_world(tmp_path / "none")
    assert bare.reference_perspective is None
    with pytest.raises(UserError, match="relief but no perspective reference.*--reference-height-m"):
        bare.reference_map("perspective")
    # a flat world's perspective view is its orthophoto: the same map, no file needed
    import_world(tmp_path / "utm.tif", None, tmp_path / "flat")
    flat = load_world(tmp_path / "flat")
    assert reference_file(flat.manifest, "perspective") == REFERENCE_FILE
    assert flat.reference_map("perspective") is flat.reference
    with pytest.raises(UserError, match="reference-height-m"):
        import_world(tmp_path / "utm.tif", None, tmp_path / "bad", reference_height_m=10.0)
