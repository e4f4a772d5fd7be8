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
    du, dv = aligned.centre_offset_px          # the template centre is the image centre's ground point
    u, v = matcher.world_to_pixel(*POS)
    return math.hypot(r.position_px[0] - du - u, r.position_px[1] - dv - v) * MPP, r.peak, aligned


@pytest.mark.parametrize("roll_deg, pitch_deg, heading_deg", [(0.0, -15.0, 30.0), (3.0, -12.0, 115.0),
                                                               (-4.0, 10.0, 250.0)])
def test_homography_beats_rotation_and_scale_on_a_pitched_fixed_mount(scene, roll_deg, pitch_deg, heading_deg):
    roll, pitch, heading = math.radians(roll_deg), math.radians(pitch_deg), math.radians(heading_deg)
    err_rs, peak_rs, plain = _error_m(scene, roll, pitch, heading, None)
    err_h, peak_h, homog = _error_m(scene, roll, pitch, heading, (roll, pitch))
    # rotation + scale: the image centre is ALT * tan(tilt) (17 to 27 m) away from the nadir point
    assert err_rs > 0.6 * ALT * math.tan(math.radians(abs(pitch_deg)))
    assert err_h < 0.5 and peak_h > 0.95 > peak_rs
    # the template is centred on the image centre's ground point: it keeps most of the capture
    offset_m = math.hypot(*homog.centre_offset_px) * MPP
    assert offset_m == pytest.approx(ALT * math.hypot(math.tan(pitch), math.tan(roll) / math.cos(pitch)), rel=0.02)
    assert homog.side_px >= 0.8 * plain.side_px


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
    err, _, _ = _error_m(scene, 0.0, pitch, 0.0, (0.0, pitch + math.radians(1.0)))
    assert err == pytest.approx(ALT * math.tan(math.radians(1.0)), abs=0.5)


def test_a_camera_looking_above_the_horizon_is_bad_input(scene):
    image = np.zeros((200, 200, 3), np.uint8)
    with pytest.raises(BadInput, match="horizon"):
        align_capture(image, 0.0, ALT, FOV, MPP, tilt_rad=(0.0, math.radians(70.0)))


def test_pipeline_tracks_a_pitched_fixed_camera_with_the_homography(scene):
    """Six captures 1 m apart at 15 degrees of pitch: the tracker's window follows the template
    centre (the image centre's ground point, 27 m ahead) and every fix is the drone's position."""
    from perception.decision import FalseMatchMethod
    from perception.ncc_search import SearchMode
    from perception.pipeline import PerceptionPipeline
    cam, matcher = scene
    pipe = PerceptionPipeline(matcher.reference, MPP, FalseMatchMethod.NONE)
    pitch, heading = math.radians(-15.0), math.radians(90.0)
    q = np.array(quat_from_aviation_euler(0.0, pitch, heading))
    searches = []
    for i in range(6):
        x, y = POS[0] + i, POS[1]
        image = cam.render(np.array([x, y, ALT]), q)
        fix = pipe.process(image, heading, ALT, 0.1 * i, tilt_rad=(0.0, pitch))
        assert fix.valid and math.hypot(fix.position_enu_m[0] - x, fix.position_enu_m[1] - y) < 0.5
        searches.append(fix.search)
    assert searches[0] is SearchMode.GLOBAL and searches[-1] is SearchMode.WINDOW
