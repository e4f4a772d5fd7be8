"""The 3-D city: surface model (DSM, facades), DSM shadows, the perspective reference,
misregistration, changed buildings and the winter reference (worlds/surface.py and neighbours)."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from scenenav.core.config import ConfigError
from scenenav.core.formats.world_manifest import ReferenceInfo, WarpTerm
from worlds.blocks import HEIGHT_RANGE_M, BuildingKind, RoofStyle
from worlds.changes import day_scenes, plan_changes
from worlds.city_config import CityConfig, Stream, stream_rng
from worlds.drawing import fill_convex
from worlds.generator import generate_world
from worlds.landcover import LandCover
from worlds.materials import Material
from worlds.perspective import perspective_reference
from worlds.reference import Season, capture_day, other_day
from worlds.registration import misregister
from worlds.rendering import render
from worlds.scene import build_scene
from worlds.shadows import cast_shadows
from worlds.surface import TREE_HEIGHT_RANGE_M, UNDERSTOREY_M, surface_model

SMALL = CityConfig(seed=3, width_px=400, height_px=400)


@pytest.fixture(scope="module")
def scene_and_dsm():
    sc = build_scene(SMALL)
    dsm, facade = surface_model(sc)
    return sc, dsm, facade


@pytest.fixture(scope="module")
def small3d():
    return generate_world(SMALL)


def _footprint(sc, b) -> np.ndarray:
    m = np.zeros(sc.material.shape, dtype=np.uint8)
    fill_convex(m, b.corners, 1)
    return m.astype(bool)


def test_building_heights_follow_the_documented_table_and_the_dsm_holds_them(scene_and_dsm):
    sc, dsm, facade = scene_and_dsm
    kinds = {b.kind for b in sc.buildings}
    assert {BuildingKind.HOUSE, BuildingKind.PERIMETER, BuildingKind.TOWER} <= kinds
    roof = np.isin(sc.material, [Material.ROOF_TEXTURED, Material.ROOF_UNIFORM])
    owner = np.full(sc.material.shape, -1)          # neighbours share edges: the later one is drawn
    for i, b in enumerate(sc.buildings):
        owner[_footprint(sc, b)] = i
    for i, b in enumerate(sc.buildings):
        lo, hi = HEIGHT_RANGE_M[b.kind]
        assert lo <= b.height_m <= hi, (b.kind, b.height_m)
        own = (owner == i) & roof
        if own.sum() < 30:
            continue
        z = dsm[own]
        if b.style in (RoofStyle.GABLE, RoofStyle.HIP):
            # the ridge at the top, the eaves roof_rise_m lower
            assert b.roof_rise_m > 0.5
            assert z.max() <= b.height_m + 0.01 and z.min() >= b.height_m - b.roof_rise_m - 0.01
            assert z.max() - z.min() > 0.5 * b.roof_rise_m
        else:
            # flat: the roof at height_m, roof boxes above it
            assert np.median(z) == pytest.approx(b.height_m, abs=0.01)
            assert z.max() <= b.height_m + b.hvac_height_m + 0.01
        assert (facade[own].max(axis=1) > 0).all()
        # walls darker than a bright roof: at most the brightest plaster
        assert facade[own].mean() < 200
    # every roof pixel is raised, nothing else but trees is
    assert (dsm[roof] > 0).all()
    other = ~roof & (sc.material != Material.FOREST)
    assert (dsm[other] == 0).all()


def test_tree_crowns_are_domes_of_plausible_height(scene_and_dsm):
    sc, dsm, _ = scene_and_dsm
    lo, hi = TREE_HEIGHT_RANGE_M
    assert len(sc.crowns) > 50
    assert (sc.crowns[:, 3] >= lo).all() and (sc.crowns[:, 3] <= hi).all()
    forest = sc.material == Material.FOREST
    assert (dsm[forest] >= UNDERSTOREY_M).all() and (dsm[forest] <= hi).all()
    assert np.median(dsm[forest]) > lo
    # a dome: highest at its centre, lower towards the rim
    domes = 0
    for u, v, r, h in sc.crowns:
        c, rr = int(u), int(v)
        if r < 4 or not (0 <= c < dsm.shape[1] and 0 <= rr < dsm.shape[0]) or not forest[rr, c]:
            continue
        centre = dsm[rr, c]
        rim = dsm[rr, min(dsm.shape[1] - 1, int(u + 0.8 * r))]
        if abs(centre - h) < 0.5:
            domes += 1
            assert rim < centre
    assert domes >= 5


def test_generation_is_deterministic_dsm_and_references_included(small3d):
    again = generate_world(SMALL)
    for name in ("orthophoto", "reference", "reference_perspective", "landcover", "dsm_m", "facade_rgb"):
        assert np.array_equal(getattr(small3d, name), getattr(again, name)), name
    assert again.manifest == small3d.manifest
    m = small3d.manifest
    assert m.has_dsm and m.reference.camera_height_m == 500.0 and m.reference.kind.value == "perspective"


def test_dsm_shadows_fall_away_from_the_sun_at_the_right_length():
    # one 20 m box on flat ground, sun from the east at 45 degrees: a 20 m shadow to the west
    mpp = 0.5
    dsm = np.zeros((200, 200), dtype=np.float32)
    dsm[90:110, 100:110] = 20.0
    mat = np.zeros((200, 200), dtype=np.uint8)
    sh = cast_shadows(dsm, mat, 0, 200, np.array([1.0, 0.0]), 45.0, mpp, 0.9)
    row = sh[100]
    assert row[100:110].max() == 0.0                    # the roof is lit
    assert (row[61:100] == 1.0).all()                   # 20 m / tan 45 = 40 px west of the wall
    assert row[:58].max() == 0.0 and row[110:].max() == 0.0
    assert sh[80].max() == 0.0 and sh[115].max() == 0.0  # nothing north or south
    # tree crowns (FOREST) let light through by the day's opacity
    mat[90:110, 100:110] = Material.FOREST
    assert cast_shadows(dsm, mat, 100, 101, np.array([1.0, 0.0]), 45.0, mpp, 0.35)[0, 80] == \
        pytest.approx(0.35)


def test_misregistration_puts_a_ground_point_where_offset_m_says():
    mpp = 0.5
    H = W = 400
    info = ReferenceInfo(shift_east_m=1.3, shift_north_m=-0.8,
                         warp=(WarpTerm(0.6, 0.3, 1 / 150.0, 1 / 400.0, 0.4),
                               WarpTerm(-0.2, 0.4, -1 / 300.0, 1 / 120.0, 1.9)))
    img = np.zeros((H, W), dtype=np.float32)
    points = [(-60.0, 45.0), (30.0, -70.0), (0.0, 0.0), (75.0, 80.0)]
    vv, uu = np.mgrid[0:H, 0:W] + 0.5
    for x, y in points:
        u, v = x / mpp + W / 2, H / 2 - y / mpp
        img += np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2 * 2.0 ** 2)).astype(np.float32)
    out = misregister(img, info, mpp)
    for x, y in points:
        dx, dy = info.offset_m(x, y)
        u, v = (x + dx) / mpp + W / 2, H / 2 - (y + dy) / mpp
        win = (slice(int(v) - 8, int(v) + 9), slice(int(u) - 8, int(u) + 9))
        w = np.clip(out[win], 0, None)
        cu = float((w * uu[win]).sum() / w.sum())
        cv = float((w * vv[win]).sum() / w.sum())
        assert math.hypot(cu - u, cv - v) < 0.1, (x, y, cu - u, cv - v)


def test_generated_misregistration_is_half_a_metre_to_three_metres(small3d, tmp_path):
    info = small3d.manifest.reference
    assert len(info.warp) == 3
    for t in info.warp:
        lam = 1.0 / math.hypot(t.k_east_per_m, t.k_north_per_m)
        assert 100.0 <= lam <= 1000.0
    xs, ys = np.meshgrid(np.linspace(-2000, 2000, 41), np.linspace(-2000, 2000, 41))
    dx, dy = info.offset_m(xs, ys)
    mag = np.hypot(dx, dy)
    assert 0.5 <= mag.min() and mag.max() <= 3.0
    # both references carry it: the perspective one equals the ortho one over flat open ground
    lc = small3d.landcover
    road = (lc == LandCover.ROAD) & (cv2.dilate((small3d.dsm_m > 0).astype(np.uint8), np.ones((41, 41))) == 0)
    diff = np.abs(small3d.reference.astype(int) - small3d.reference_perspective.astype(int)).max(axis=2)
    assert road.sum() > 1000 and np.median(diff[road]) <= 2


def test_perspective_reference_leans_a_tall_building_away_from_the_centre():
    mpp, H_eye, h = 0.5, 500.0, 40.0
    size = 600
    dsm = np.zeros((size, size), dtype=np.float32)
    top = np.full((size, size, 3), 120, dtype=np.uint8)
    facade = np.zeros((size, size, 3), dtype=np.uint8)
    # a 10 m x 10 m tower of 40 m, 100 m east and 60 m south of the centre
    c0, r0 = size // 2 + 200 - 10, size // 2 + 120 - 10
    dsm[r0:r0 + 20, c0:c0 + 20] = h
    top[r0:r0 + 20, c0:c0 + 20] = (250, 0, 0)
    facade[r0:r0 + 20, c0:c0 + 20] = (0, 0, 250)
    out = perspective_reference(top, dsm, facade, mpp, H_eye)
    red = (out[..., 0] > 200) & (out[..., 1] < 50)
    vs, us = np.nonzero(red)
    cu, cv = us.mean() + 0.5 - size / 2, vs.mean() + 0.5 - size / 2     # px from the centre
    foot = np.array([200.0, 120.0])                                       # footprint centre, px
    d_seen = math.hypot(cu, cv) * mpp                                     # where the roof appears, m
    lean_px = math.hypot(cu - foot[0], cv - foot[1])
    assert lean_px == pytest.approx(h * d_seen / H_eye / mpp, abs=1.0)
    # ... away from the centre, along the line through it
    assert np.dot([cu - foot[0], cv - foot[1]], foot) > 0.99 * lean_px * np.hypot(*foot)
    # the walls facing the centre appear between the footprint and the roof; none on the far side
    blue = (out[..., 2] > 60) & (out[..., 0] < 60)
    assert blue.sum() > 100
    bv, bu = np.nonzero(blue)
    assert np.mean(np.hypot(bu + 0.5 - size / 2, bv + 0.5 - size / 2)) < math.hypot(cu, cv)
    # flat heights give back the top image exactly
    flat = perspective_reference(top, np.zeros_like(dsm), None, mpp, H_eye)
    assert np.array_equal(flat, top)


def _has(buildings, b) -> bool:
    return any(x is b for x in buildings)


def test_changed_buildings_are_counted_and_differ_between_the_days(small3d):
    cfg = CityConfig(seed=3, width_px=400, height_px=400, reroofed_share=0.1, added_share=0.05,
                     demolished_share=0.05)
    base = build_scene(cfg)
    footprints = [_footprint(base, b) for b in base.buildings]
    changes = plan_changes(base, cfg, stream_rng(cfg, Stream.CHANGES))
    n = len(base.buildings)
    assert len(changes.reroofed) == round(0.1 * n) and len(changes.added) == round(0.05 * n)
    assert len(changes.demolished) == round(0.05 * n) and changes.count == sum(
        round(s * n) for s in (0.1, 0.05, 0.05))
    assert not set(changes.reroofed) & set(changes.added)
    originals = list(base.buildings)
    capture, ref = day_scenes(base, changes)
    assert len(capture.buildings) == n - len(changes.demolished)
    assert len(ref.buildings) == n - len(changes.added)
    for i in changes.demolished:     # in the reference only: bare ground on the capture day
        assert _has(ref.buildings, originals[i]) and not _has(capture.buildings, originals[i])
        assert (capture.material[footprints[i]] == Material.GROUND).all()
    for i in changes.added:          # on the capture day only
        assert _has(capture.buildings, originals[i]) and not _has(ref.buildings, originals[i])
        assert (ref.material[footprints[i]] == Material.GROUND).all()
    for i, tone in zip(changes.reroofed, changes.new_tones, strict=True):
        assert np.abs(np.array(tone) - np.array(originals[i].tone[:3])).mean() >= 20
    world = generate_world(cfg)
    assert world.manifest.reference.changed_buildings == changes.count
    dem = footprints[changes.demolished[0]]
    assert (world.dsm_m[dem] == 0).all() and (world.landcover[dem] == LandCover.UNKNOWN).all()
    assert small3d.manifest.reference.changed_buildings > 0


def test_winter_changes_grass_trees_and_flat_roofs_only(scene_and_dsm):
    sc, dsm, _ = scene_and_dsm
    rng = stream_rng(sc.cfg, Stream.DAYS)
    summer = other_day(rng, capture_day(rng))
    winter = dataclasses.replace(summer, season=Season.WINTER)
    a = render(sc, summer, dsm).astype(int)
    b = render(sc, winter, dsm).astype(int)
    flat = np.zeros(sc.material.shape, dtype=bool)
    for bld in sc.buildings:
        if bld.style in (RoofStyle.FLAT, RoofStyle.UNIFORM):
            flat |= _footprint(sc, bld)
    args = (dsm, sc.material, 0, dsm.shape[0], summer.sun_vector_px(), summer.sun_elevation_deg,
            sc.cfg.m_per_px)
    tree_shadow = cast_shadows(*args, summer.tree_opacity) != cast_shadows(*args, winter.tree_opacity)
    should = flat | np.isin(sc.material, [Material.GRASS, Material.FOREST]) | tree_shadow
    # optical blur (3 sigma) and JPEG blocks (16 px) spread a change a little
    near = cv2.dilate(should.astype(np.uint8), np.ones((45, 45), np.uint8)) > 0
    changed = np.abs(a - b).max(axis=2) > 0
    assert changed[~near].sum() == 0
    assert (~near).sum() > 2000              # the test sees untouched city
    grass = (sc.material == Material.GRASS) & ~tree_shadow
    assert b[grass].mean() > a[grass].mean() + 60          # snow
    assert b[flat].mean() > a[flat].mean() + 20


def test_reference_options_are_checked():
    with pytest.raises(ConfigError, match="reference_kind"):
        CityConfig(reference_kind="oblique")
    with pytest.raises(ConfigError, match="season"):
        CityConfig(season="spring")
    with pytest.raises(ConfigError, match="reference_height_m"):
        CityConfig(reference_height_m=10.0)
