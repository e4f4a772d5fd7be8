"""Alignment: heading rotation, altitude scale, crop/mask, bad input."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from perception.alignment import BadInput, TemplateTooSmall, align_capture, to_gray_float32
from perception.config import CropMode
from perception.ncc_search import SceneMatcher
from scenenav.core.camera_geometry import ground_footprint_m

FOV = 60.0
CAM = 200


def texture(h: int, w: int, seed: int = 0, sigma: float = 2.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), sigma)
    return ((t - t.min()) / (t.max() - t.min())).astype(np.float32)


def altitude_for_scale(scale: float, map_m_per_px: float) -> float:
    """Altitude at which one camera pixel covers ``scale`` map pixels."""
    return scale * map_m_per_px * CAM / (2.0 * math.tan(math.radians(FOV) / 2.0))


def render(world: np.ndarray, u: float, v: float, heading: float, alt: float, mpp: float) -> np.ndarray:
    """Independent camera model: camera pixel offset (right, down) = R(-heading) (east, south)."""
    g = ground_footprint_m(alt, FOV) / CAM / mpp                     # map px per camera px
    jj, ii = np.meshgrid(np.arange(CAM) - (CAM - 1) / 2.0, np.arange(CAM) - (CAM - 1) / 2.0)
    # A camera pixel `right` along the forward-right axes maps to map east/south by the heading.
    c, s = math.cos(heading), math.sin(heading)
    east = g * (c * jj - s * ii)
    south = g * (s * jj + c * ii)
    mx = (u - 0.5 + east).astype(np.float32)
    my = (v - 0.5 + south).astype(np.float32)
    return cv2.remap(world, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def to_u8_rgb(gray: np.ndarray) -> np.ndarray:
    g = np.clip(np.rint(gray * 255), 0, 255).astype(np.uint8)
    return np.dstack([g, g, g])


@pytest.fixture(scope="module")
def world() -> np.ndarray:
    return texture(500, 600, seed=2)


def test_heading_zero_scale_one_is_identity(world):
    img = world[100:300, 150:350]
    mpp = 0.5
    al = align_capture(img, 0.0, altitude_for_scale(1.0, mpp), FOV, mpp)
    assert al.scale == pytest.approx(1.0)
    assert al.template.shape == (200, 200) and al.template.dtype == np.float32
    assert np.allclose(al.template, img, atol=1e-5)
    assert al.mask.all()


@pytest.mark.parametrize("k,heading", [(1, math.pi / 2), (2, math.pi), (3, 3 * math.pi / 2)])
def test_multiples_of_90_deg_recover_north_up_crop(world, k, heading):
    north_up = world[50:250, 60:260]
    # Heading east: image-up is east, so the camera sees the north-up crop turned counter-clockwise.
    camera = np.ascontiguousarray(np.rot90(north_up, k))
    mpp = 0.5
    al = align_capture(camera, heading, altitude_for_scale(1.0, mpp), FOV, mpp)
    assert np.allclose(al.template, north_up, atol=1e-4)


@pytest.mark.parametrize("heading_deg", [30.0, 137.0, 290.0])
def test_rotated_capture_matches_at_the_right_place(world, heading_deg):
    mpp = 0.5
    alt = altitude_for_scale(0.8, mpp)
    u, v, h = 310.3, 240.6, math.radians(heading_deg)
    cam = to_u8_rgb(render(world, u, v, h, alt, mpp))
    al = align_capture(cam, h, alt, FOV, mpp)
    side = al.template.shape[0]
    assert side == math.floor(0.8 * CAM / (abs(math.cos(h)) + abs(math.sin(h))) + 1e-6)
    r = SceneMatcher(world, mpp).match(al.template)
    assert r.peak > 0.95
    assert r.position_px == pytest.approx((u, v), abs=0.3)


@pytest.mark.parametrize("alt_m", [60.0, 100.0, 140.0])
def test_altitude_scales_template(world, alt_m):
    mpp = 0.6
    u, v = 300.0, 250.0
    cam = render(world, u, v, 0.0, alt_m, mpp)
    al = align_capture(cam, 0.0, alt_m, FOV, mpp)
    expected_scale = 2 * alt_m * math.tan(math.radians(30)) / CAM / mpp
    assert al.scale == pytest.approx(expected_scale)
    assert al.footprint_m == pytest.approx(2 * alt_m * math.tan(math.radians(30)))
    assert al.template.shape[0] == math.floor(expected_scale * CAM + 1e-6)
    r = SceneMatcher(world, mpp).match(al.template)
    assert r.position_px == pytest.approx((u, v), abs=0.3)
    assert r.peak > 0.95


def test_wrong_altitude_lowers_the_peak(world):
    mpp = 0.6
    cam = render(world, 300.0, 250.0, 0.0, 100.0, mpp)
    m = SceneMatcher(world, mpp)
    right = m.match(align_capture(cam, 0.0, 100.0, FOV, mpp).template, (300.0, 250.0), 10)
    wrong = m.match(align_capture(cam, 0.0, 130.0, FOV, mpp).template, (300.0, 250.0), 10)
    assert wrong.peak < right.peak - 0.2


def test_inscribed_square_at_45_deg(world):
    al = align_capture(world[:200, :200], math.pi / 4, altitude_for_scale(1.0, 0.5), FOV, 0.5)
    assert al.template.shape == (141, 141)          # floor(200 / sqrt(2))


def test_masked_bounds_mode(world):
    al = align_capture(world[:200, :200], math.pi / 4, altitude_for_scale(1.0, 0.5), FOV, 0.5,
                       CropMode.MASKED_BOUNDS)
    n = al.template.shape[0]
    assert n == math.ceil(200 * math.sqrt(2) - 1e-6)
    assert not al.mask[0, 0] and not al.mask[-1, -1] and al.mask[n // 2, n // 2]
    assert al.mask[n // 2, 3] and al.mask[3, n // 2]       # the rotated image's corners (edge midpoints)
    assert np.all(al.template[~al.mask] == 0.0)
    assert al.mask.mean() == pytest.approx(0.5, abs=0.03)  # a 45-degree square fills half its box


def test_gray_conversion_uint8_rgb_and_mono():
    rgb = np.zeros((10, 12, 3), np.uint8)
    rgb[..., 0] = 255
    g = to_gray_float32(rgb)
    assert g.dtype == np.float32 and g.shape == (10, 12)
    assert g[0, 0] == pytest.approx(76 / 255, abs=1 / 255)       # BT.601 red weight 0.299
    mono = np.full((10, 12), 128, np.uint8)
    assert to_gray_float32(mono)[0, 0] == pytest.approx(128 / 255)


@pytest.mark.parametrize("image,heading,alt", [
    (np.zeros((200, 200, 3), np.uint8), float("nan"), 100.0),
    (np.zeros((200, 200, 3), np.uint8), 0.0, float("nan")),
    (np.zeros((200, 200, 3), np.uint8), 0.0, 0.0),
    (np.zeros((200, 200, 3), np.uint8), 0.0, -5.0),
    (np.zeros((200, 200, 3), np.int16), 0.0, 100.0),
    (np.zeros((200, 200, 2), np.uint8), 0.0, 100.0),
    (np.zeros((200,), np.uint8), 0.0, 100.0),
    (np.zeros((4, 4), np.uint8), 0.0, 100.0),
    ([[1, 2], [3, 4]], 0.0, 100.0),
])
def test_bad_input(image, heading, alt):
    with pytest.raises(BadInput):
        align_capture(image, heading, alt, FOV, 0.5)


@pytest.mark.parametrize("tilt", [None, (0.0, 0.0)])
def test_too_small_template_is_refused_before_resampling(world, tilt, monkeypatch):
    """Near the ground the scale is tiny and the anti-aliasing blur huge: the size is checked first."""
    img = to_u8_rgb(world[100:300, 150:350])
    mpp = 0.5
    alt = altitude_for_scale(15.0 / CAM, mpp)           # 200 camera px -> 15 map px (< 16)
    assert align_capture(img, 0.0, alt, FOV, mpp, tilt_rad=tilt).side_px == 15
    assert align_capture(img, 0.0, alt, FOV, mpp, tilt_rad=tilt, min_template_px=15).side_px == 15
    monkeypatch.setattr(cv2, "GaussianBlur", lambda *a, **k: pytest.fail("blurred a dropped capture"))
    with pytest.raises(TemplateTooSmall) as exc:
        align_capture(img, 0.0, alt, FOV, mpp, tilt_rad=tilt, min_template_px=16)
    assert exc.value.side_px == 15
