"""Homography alignment of a FIXED-mount capture (perception.alignment, ``tilt_rad``).

The captures are rendered by the simulator's camera (``sitl.camera.GroundCamera``, flat world, FIXED
mount): an independent model of the same pinhole geometry. On a pitched body the rotation + scale
alignment puts the image centre (not the nadir point) at the template centre and keeps the
perspective: its fix is tens of metres off. The homography from the attitude puts it within a
fraction of a map pixel.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from perception.alignment import BadInput, align_capture
from perception.config import CropMode
from perception.ncc_search import SceneMatcher
from scenenav.core.rotations import quat_from_aviation_euler
from sitl.camera import GroundCamera
from sitl.config import CameraConfig, CameraMount

MPP = 0.5
ALT = 100.0
FOV = 60.0
POS = (10.0, -5.0)


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(2)
    t = cv2.GaussianBlur(rng.standard_normal((700, 700)).astype(np.float32), (0, 0), 3.0)
    grey = ((t - t.min()) / (t.max() - t.min()) * 255).astype(np.uint8)
    cam = GroundCamera(-1, np.dstack([grey, grey, grey]), MPP,
                       CameraConfig(mount=CameraMount.FIXED, relief=False))
    yield cam, SceneMatcher(grey.astype(np.float32) / 255.0, MPP)
    cam.close()


def _error_m(scene, roll, pitch, heading, tilt):
    cam, matcher = scene
    q = np.array(quat_from_aviation_euler(roll, pitch, heading))
    image = cam.render(np.array([POS[0], POS[1], ALT]), q)
    aligned = align_capture(image, heading, ALT, FOV, MPP, tilt_rad=tilt)
    r = matcher.match(aligned.template)
    u, v = matcher.world_to_pixel(*POS)
    return math.hypot(r.position_px[0] - u, r.position_px[1] - v) * MPP, r.peak


@pytest.mark.parametrize("roll_deg, pitch_deg, heading_deg", [(0.0, -15.0, 30.0), (3.0, -12.0, 115.0),
                                                               (-4.0, 10.0, 250.0)])
def test_homography_beats_rotation_and_scale_on_a_pitched_fixed_mount(scene, roll_deg, pitch_deg, heading_deg):
    roll, pitch, heading = math.radians(roll_deg), math.radians(pitch_deg), math.radians(heading_deg)
    err_rs, peak_rs = _error_m(scene, roll, pitch, heading, None)
    err_h, peak_h = _error_m(scene, roll, pitch, heading, (roll, pitch))
    # rotation + scale: the image centre is ALT * tan(tilt) (17 to 27 m) away from the nadir point
    assert err_rs > 0.6 * ALT * math.tan(math.radians(abs(pitch_deg)))
    assert err_h < 0.5 and peak_h > 0.95 > peak_rs


def test_level_homography_is_the_rotation_and_scale_alignment(scene):
    cam, _ = scene
    heading = math.radians(40.0)
    image = cam.render(np.array([POS[0], POS[1], ALT]), np.array(quat_from_aviation_euler(0.0, 0.0, heading)))
    plain = align_capture(image, heading, ALT, FOV, MPP)
    homog = align_capture(image, heading, ALT, FOV, MPP, tilt_rad=(0.0, 0.0))
    assert homog.template.shape == plain.template.shape
    np.testing.assert_allclose(homog.template, plain.template, atol=2e-3)
    masked = align_capture(image, heading, ALT, FOV, MPP, CropMode.MASKED_BOUNDS, tilt_rad=(0.0, 0.0))
    assert masked.mask.sum() > 0.9 * masked.template.shape[0] * masked.template.shape[1] / 2


def test_estimate_error_shows_as_a_fix_error(scene):
    """A 1 degree pitch error in the estimate moves the fix by about ALT * tan(1 deg) = 1.75 m."""
    pitch = math.radians(-12.0)
    err, _ = _error_m(scene, 0.0, pitch, 0.0, (0.0, pitch + math.radians(1.0)))
    assert err == pytest.approx(ALT * math.tan(math.radians(1.0)), abs=0.5)


def test_a_camera_looking_above_the_horizon_is_bad_input(scene):
    image = np.zeros((200, 200, 3), np.uint8)
    with pytest.raises(BadInput, match="horizon"):
        align_capture(image, 0.0, ALT, FOV, MPP, tilt_rad=(0.0, math.radians(70.0)))
