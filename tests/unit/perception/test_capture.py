"""Captures of the offline tools (perception/capture.py): flat = today's images, relief through the
city renderer where the world has a DSM, the chosen reference, the misregistration undone."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from perception.assistant_map import build_assistant_map
from perception.capture import CaptureScene, CaptureSettings, ReferenceChoice
from perception.dataset_images import render_crop
from perception.matchability import CaptureNoise, MatchabilityConfig, matchability, render_camera
from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import FORMAT_VERSION, ReferenceInfo, ReferenceKind, WorldManifest
from worlds.world import World

MPP = 0.5
SIZE = 400                 # 200 m x 200 m


def _texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.integers(0, 255, (SIZE, SIZE, 3), dtype=np.uint8), (0, 0), 2.0)
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)


def _world(ortho: np.ndarray, heights: np.ndarray | None, reference: np.ndarray | None = None,
           info: ReferenceInfo | None = None, perspective: np.ndarray | None = None) -> World:
    info = info or ReferenceInfo(camera_height_m=500.0 if perspective is not None else None)
    man = WorldManifest(format_version=FORMAT_VERSION, name="t", width_px=SIZE, height_px=SIZE, m_per_px=MPP,
                        origin_lat_deg=0.0, origin_lon_deg=0.0, source="generated", seed=None,
                        has_landcover=False, has_junctions=False, has_dsm=heights is not None, reference=info)
    return World(manifest=man, orthophoto=ortho, reference=ortho if reference is None else reference,
                 dsm_m=heights, reference_perspective=perspective)


def test_flat_worlds_and_relief_off_give_todays_images_exactly():
    ortho = _texture(0)
    gray = cv2.cvtColor(ortho, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    box = np.zeros((SIZE, SIZE), np.float32)
    box[150:250, 150:250] = 25.0
    for scene in (CaptureScene.from_world(_world(ortho, None)),                  # a flat world
                  CaptureScene.from_world(_world(ortho, box), CaptureSettings(relief=False))):
        assert not scene.relief and scene.renderer() is None
        today = render_camera(scene.camera_gray, 201.3, 188.8, 0.7, 100.0, 60.0, MPP, 200)
        np.testing.assert_array_equal(scene.camera_image(201.3, 188.8, 0.7, 100.0, 60.0, 200), today)
        np.testing.assert_array_equal(scene.footprint_image(201.3, 188.8, 217, 200, 60.0, 1.1, 0.95, True),
                                      render_crop(scene.camera_gray, 201.3, 188.8, 217, 200, 1.1, 0.95, True))
        np.testing.assert_allclose(scene.camera_gray, gray, atol=1.0 / 255.0)
    assert CaptureScene.from_world(_world(ortho, box)).relief              # relief is the default


def test_reference_choice():
    a, b = _texture(1), _texture(2)
    w = _world(a, None, reference=a, perspective=b)
    assert CaptureScene.from_world(w).reference_kind is ReferenceKind.ORTHOPHOTO
    persp = CaptureScene.from_world(w, CaptureSettings(reference=ReferenceChoice.PERSPECTIVE))
    assert persp.reference_kind is ReferenceKind.PERSPECTIVE
    np.testing.assert_allclose(persp.reference_gray * 255.0,
                               cv2.cvtColor(b, cv2.COLOR_RGB2GRAY).astype(np.float32), atol=1.0)
    # a world with relief and no perspective reference: one line saying how to get one
    relief = np.zeros((SIZE, SIZE), np.float32)
    relief[150:250, 150:250] = 25.0
    with pytest.raises(UserError, match="perspective"):
        CaptureScene.from_world(_world(a, relief), CaptureSettings(reference="perspective"))
    # a flat world's perspective reference is its orthophoto one (flat ground seen from straight
    # above, drawn back onto the map grid, is the orthophoto)
    flat = CaptureScene.from_world(_world(a, None, reference=b), CaptureSettings(reference="perspective"))
    np.testing.assert_allclose(flat.reference_gray * 255.0,
                               cv2.cvtColor(b, cv2.COLOR_RGB2GRAY).astype(np.float32), atol=1.0)
    with pytest.raises(UserError, match="expected default, orthophoto or perspective"):
        CaptureSettings(reference="oblique")


def test_matchability_measures_against_the_stated_misregistration():
    """The reference draws the ground 3 m east and 1.5 m south of where it is: with the offset
    stated every capture matches (error about 0), without it every capture is 3.35 m off."""
    cam = _texture(3).astype(np.float32)[..., 0] / 255.0
    ref = np.roll(cam, (3, 6), axis=(0, 1))         # +6 px east (3 m), +3 px south (1.5 m north-)
    info = ReferenceInfo(shift_east_m=3.0, shift_north_m=-1.5)
    cfg = MatchabilityConfig(n_captures=3, tolerance_m=1.0, search_radius_px=30,
                             noise=CaptureNoise(heading_sigma_deg=0.0, altitude_sigma_rel=0.0, noise_sigma=0.0))
    pos = np.array([[200.0, 200.0], [180.0, 215.0]])
    stated = CaptureScene(camera_gray=cam, reference_gray=ref, m_per_px=MPP, reference_info=info)
    res = matchability(stated, pos, cfg, np.random.default_rng(0))
    assert np.all(res.score == 1.0) and float(np.max(res.errors_m)) < 0.6
    unstated = CaptureScene.flat(cam, ref, MPP)
    res = matchability(unstated, pos, cfg, np.random.default_rng(0))
    assert np.all(res.score == 0.0)
    np.testing.assert_allclose(res.errors_m, math.hypot(3.0, 1.5), atol=0.6)


def test_assistant_map_builder_classifies_the_given_captures():
    ref = np.zeros((120, 160), np.float32)
    seen = []

    def capture(u, v):
        seen.append((u, v))
        return np.full((16, 16), u / 160.0, np.float32)      # brighter to the east

    amap = build_assistant_map(ref, lambda b: b.mean(axis=(1, 2)), 1.0, altitude_m=20.0, fov_deg=60.0,
                               stride_px=10, cnn_input_px=16, capture=capture)
    known = ~np.isnan(amap.probability)
    assert seen and known.any()
    p = amap.probability
    cols = np.nonzero(known.any(axis=0))[0]
    # p_true = 1 - P(bad) = 1 - u / 160 for the cell centred on u
    assert p[60, cols[0]] == pytest.approx(1.0 - (cols[0] // 10 * 10 + 5) / 160.0, abs=1e-6)
    assert p[60, cols[-1]] < p[60, cols[0]]


# ---- relief through the city renderer ---------------------------------------------------------------

def _box_world(height_m: float) -> World:
    """Black ground, one white 10 m x 10 m box roof at x 20..30 m east, y -5..5 m north."""
    ortho = np.zeros((SIZE, SIZE, 3), np.uint8)
    heights = np.zeros((SIZE, SIZE), np.float32)
    # x 20..30 m -> u 240..260; y -5..5 m -> v 190..210
    ortho[190:210, 240:260] = 255
    heights[190:210, 240:260] = height_m
    return _world(ortho, heights)


def test_a_box_roof_leans_away_from_the_nadir_point():
    """Seen straight down from 100 m over (0, 0), a roof at 20 m scales by 100 / 80 about the
    nadir point: its edges at x = 20 and 30 m appear where ground points at 25 and 37.5 m would."""
    world = _box_world(20.0)
    relief = CaptureScene.from_world(world)
    flat = CaptureScene.from_world(world, CaptureSettings(relief=False))
    u, v = world.world_to_pixel(0.0, 0.0)
    g = 2 * 100.0 * math.tan(math.radians(30.0)) / 200       # ground metres per camera pixel
    for scene, (x0, x1) in ((flat, (20.0, 30.0)), (relief, (25.0, 37.5))):
        img = scene.camera_image(u, v, 0.0, 100.0, 60.0, 200)
        cols = np.nonzero((img > 0.95).any(axis=0))[0]
        rows = np.nonzero((img > 0.95).any(axis=1))[0]
        lo, hi = (cols[0] - 99.5) * g, (cols[-1] + 1 - 99.5) * g     # pixel edges -> metres east
        assert lo == pytest.approx(x0, abs=1.5 * g) and hi == pytest.approx(x1, abs=1.5 * g)
        half = (rows[-1] + 1 - rows[0]) * g / 2
        assert half == pytest.approx(5.0 * (x1 - x0) / 10.0, abs=1.5 * g)
    # Heading 90 deg (image up = east): the roof is now above the image centre.
    img = relief.camera_image(u, v, math.pi / 2, 100.0, 60.0, 200)
    rows = np.nonzero((img > 0.95).any(axis=1))[0]
    assert (99.5 - rows[-1] - 1) * g == pytest.approx(25.0, abs=1.5 * g)
    # The wall facing the nadir point shows between the roof and its footprint, darker than the roof.
    img = relief.camera_image(u, v, 0.0, 100.0, 60.0, 200)
    wall = img[95:105, int(99.5 + 21.0 / g):int(99.5 + 24.0 / g)]
    assert 0.05 < float(wall.mean()) < 0.95


def test_relief_dataset_crops_mirror_and_scale_like_the_flat_ones():
    world = _box_world(0.5)                  # nearly flat: relief and flat crops nearly agree
    relief = CaptureScene.from_world(world)
    flat = CaptureScene.from_world(world, CaptureSettings(relief=False))
    u, v = world.world_to_pixel(10.0, 3.0)
    for angle, scale, flip in ((0.0, 1.0, False), (0.6, 1.1, True)):
        a = relief.footprint_image(u, v, 217, 200, 60.0, angle, scale, flip)
        b = flat.footprint_image(u, v, 217, 200, 60.0, angle, scale, flip)
        assert a.shape == b.shape == (200, 200)
        assert float(np.mean(np.abs(a - b))) < 0.03
