"""The rendered camera image is the orthophoto crop under the vehicle, at the right place and scale.

A synthetic orthophoto (random texture, lightly blurred; 1200 x 1100 px at 0.53 m/px) lies on the
ground. From 100 m, level, the render is resized to map scale (footprint / m_per_px) and located in
the orthophoto by normalised cross-correlation; the peak must be within 1 px of where the frame
conventions (scenenav/core/frames.py) put it. A small ground window (512 texels) forces re-centring.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from scenenav.core.rotations import quat_from_euler_zyx, quat_from_yaw
from sitl.camera import GroundCamera
from sitl.config import CameraConfig, CameraMount, SimConfig
from sitl.physics import PhysicsWorld
from sitl.vehicle import VehicleParams

M_PER_PX = 0.53
MAP_W, MAP_H = 1200, 1100
ALTITUDE_M = 100.0


@pytest.fixture(scope="module")
def orthophoto() -> np.ndarray:
    rng = np.random.default_rng(1234)
    noise = rng.integers(0, 256, (MAP_H, MAP_W, 3), dtype=np.uint8)
    img = cv2.GaussianBlur(noise, (0, 0), 1.5)
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)


@pytest.fixture(scope="module")
def rig(orthophoto):
    cfg = SimConfig(camera=CameraConfig(ground_window_px=512))
    world = PhysicsWorld(VehicleParams(), cfg, np.random.default_rng(0))
    camera = GroundCamera(world.client_id, orthophoto, M_PER_PX, cfg.camera)
    yield world, camera
    camera.close()
    world.close()


def _render_at(world: PhysicsWorld, camera: GroundCamera, x_m: float, y_m: float, heading_rad: float,
               altitude_m: float = ALTITUDE_M) -> np.ndarray:
    state = world.set_pose(np.array([x_m, y_m, altitude_m]), quat_from_yaw(math.pi / 2.0 - heading_rad),
                           np.zeros(3))
    return camera.render(state.position_enu_m, state.q_wxyz)


def _locate(orthophoto: np.ndarray, image: np.ndarray,
            footprint_m: float) -> tuple[tuple[int, int], tuple[float, int], float]:
    """NCC peak (col, row) of the map-scale image, the expected top-left, and the peak value."""
    side = footprint_m / M_PER_PX
    n = int(round(side))
    template = cv2.resize(image, (n, n), interpolation=cv2.INTER_LINEAR)
    scores = cv2.matchTemplate(orthophoto, template, cv2.TM_CCOEFF_NORMED)
    _, peak, _, loc = cv2.minMaxLoc(scores)
    return loc, (side, n), peak


def _expected_top_left(x_m: float, y_m: float, side: float, n: int) -> tuple[float, float]:
    # Map-pixel coordinates of the footprint centre (scenenav/core/frames.py), minus half the footprint;
    # template pixel k (centre k + 0.5, scaled by side/n) sits on map pixel top_left + k.
    u = x_m / M_PER_PX + MAP_W / 2.0
    v = MAP_H / 2.0 - y_m / M_PER_PX
    shift = 0.5 * (side / n - 1.0)
    return u - side / 2.0 + shift, v - side / 2.0 + shift


# Points from the centre to near every edge and corner (the footprint, ~218 px wide, stays inside).
POINTS_M = [
    (0.0, 0.0),
    (37.3, -11.9),
    (-255.0, 0.0),      # near the west edge
    (255.0, 10.0),      # near the east edge
    (5.0, 230.0),       # near the north edge
    (-20.0, -230.0),    # near the south edge
    (250.0, -228.0),    # south-east corner
    (-252.0, 229.0),    # north-west corner
]


def test_nadir_render_is_the_crop_under_the_vehicle(rig, orthophoto):
    world, camera = rig
    footprint_m, _ = camera.footprint_m(ALTITUDE_M)
    assert footprint_m == pytest.approx(2.0 * ALTITUDE_M * math.tan(math.radians(30.0)))
    windows = set()
    for x_m, y_m in POINTS_M:
        image = _render_at(world, camera, x_m, y_m, 0.0)
        assert image.shape == (200, 200, 3) and image.dtype == np.uint8
        windows.add(camera.window)
        loc, (side, n), peak = _locate(orthophoto, image, footprint_m)
        ex, ey = _expected_top_left(x_m, y_m, side, n)
        assert peak > 0.9, (x_m, y_m, peak)
        assert abs(loc[0] - ex) <= 1.0 and abs(loc[1] - ey) <= 1.0, ((x_m, y_m), loc, (ex, ey))
    # The 512-texel window cannot hold all these footprints: it must have been re-centred.
    assert len(windows) >= 3 and camera.window_builds >= 3


def test_render_after_recentring_far_and_back(rig, orthophoto):
    world, camera = rig
    footprint_m, _ = camera.footprint_m(ALTITUDE_M)
    _render_at(world, camera, -240.0, 220.0, 0.0)
    builds = camera.window_builds
    window_before = camera.window
    x_m, y_m = 240.0, -220.0
    image = _render_at(world, camera, x_m, y_m, 0.0)
    assert camera.window_builds == builds + 1 and camera.window != window_before
    loc, (side, n), _ = _locate(orthophoto, image, footprint_m)
    ex, ey = _expected_top_left(x_m, y_m, side, n)
    assert abs(loc[0] - ex) <= 1.0 and abs(loc[1] - ey) <= 1.0


@pytest.mark.parametrize("quarter_turns", [1, 2, 3])
def test_heading_rotates_the_image(rig, orthophoto, quarter_turns):
    """Facing east (heading 90 deg) the image top is east: rotated back clockwise it is north-up."""
    world, camera = rig
    footprint_m, _ = camera.footprint_m(ALTITUDE_M)
    x_m, y_m = 60.0, -40.0
    image = _render_at(world, camera, x_m, y_m, quarter_turns * math.pi / 2.0)
    north_up = np.ascontiguousarray(np.rot90(image, k=-quarter_turns))   # clockwise by the heading
    loc, (side, n), peak = _locate(orthophoto, north_up, footprint_m)
    ex, ey = _expected_top_left(x_m, y_m, side, n)
    assert peak > 0.9
    assert abs(loc[0] - ex) <= 1.0 and abs(loc[1] - ey) <= 1.0


def test_heading_east_equals_rotated_north_render(rig):
    world, camera = rig
    north = _render_at(world, camera, 12.0, 34.0, 0.0)
    east = _render_at(world, camera, 12.0, 34.0, math.pi / 2.0)
    # Same footprint, 90 degrees apart: identical up to nearest-texel rounding at pixel borders.
    same = np.all(np.rot90(east, k=-1) == north, axis=2)
    assert same.mean() > 0.95


def test_gimbal_ignores_roll_and_pitch(rig):
    world, camera = rig
    level = camera.render(np.array([10.0, 20.0, 80.0]), quat_from_euler_zyx(0.7, 0.0, 0.0))
    tilted = camera.render(np.array([10.0, 20.0, 80.0]), quat_from_euler_zyx(0.7, -0.2, 0.3))
    assert np.array_equal(level, tilted)


def test_fixed_mount_level_matches_gimbal_and_follows_roll(orthophoto):
    cfg = CameraConfig(mount=CameraMount.FIXED, ground_window_px=512)
    with GroundCamera(-1, orthophoto, M_PER_PX, cfg) as fixed, \
            GroundCamera(-1, orthophoto, M_PER_PX, CameraConfig(ground_window_px=512)) as gimbal:
        pos = np.array([-30.0, 15.0, 100.0])
        q = quat_from_euler_zyx(0.3, 0.0, 0.0)
        assert np.array_equal(fixed.render(pos, q), gimbal.render(pos, q))
        # Rolled right by 10 deg (right side down, heading north): the belly, and the optical axis
        # with it, turns to the left, so the image centre shows the ground h tan(10 deg) WEST of
        # the nadir point.
        roll = math.radians(10.0)
        image = fixed.render(pos, quat_from_euler_zyx(math.pi / 2.0, 0.0, roll))
        centre = (slice(80, 120), slice(80, 120))

        def similarity(offset_x_m: float) -> float:
            reference = gimbal.render(pos + np.array([offset_x_m, 0.0, 0.0]), quat_from_yaw(math.pi / 2.0))
            a = image[centre].astype(float).ravel()
            b = reference[centre].astype(float).ravel()
            return float(np.corrcoef(a, b)[0, 1])

        shift_m = pos[2] * math.tan(roll)
        assert similarity(-shift_m) > 0.9
        assert similarity(+shift_m) < 0.3


def test_outside_the_map_is_grey(rig):
    world, camera = rig
    image = _render_at(world, camera, 5000.0, -4000.0, 0.3)
    assert np.all(image == camera.cfg.outside_grey_level)


def test_high_altitude_uses_a_coarser_window_and_stays_registered(rig, orthophoto):
    world, camera = rig
    altitude_m = 400.0
    footprint_m, _ = camera.footprint_m(altitude_m)
    x_m, y_m = 20.0, -10.0
    image = _render_at(world, camera, x_m, y_m, 0.0, altitude_m)
    assert camera.window.lod >= 2      # ~4.4 map px per image px: texels are 2x2 or 4x4 map px
    # A texel now averages several map pixels, like a real camera pixel: compare with the map
    # smoothed to the same ground resolution.
    ratio = footprint_m / M_PER_PX / image.shape[1]
    smoothed = cv2.GaussianBlur(orthophoto, (0, 0), 0.5 * ratio)
    loc, (side, n), peak = _locate(smoothed, image, footprint_m)
    ex, ey = _expected_top_left(x_m, y_m, side, n)
    assert peak > 0.8
    assert abs(loc[0] - ex) <= 1.5 and abs(loc[1] - ey) <= 1.5


def test_map_smaller_than_the_window_is_uploaded_once(orthophoto):
    with GroundCamera(-1, orthophoto, M_PER_PX, CameraConfig()) as camera:     # 2048-texel window
        for x_m, y_m in POINTS_M[::-1]:
            camera.render(np.array([x_m, y_m, ALTITUDE_M]), quat_from_yaw(0.4))
        assert camera.window_builds == 1
