"""The camera's flow between consecutive frames (perception.frame_flow): the FlowSample convention
(body FLU), checked on frames rendered by a pinhole over a textured ground plane with the fixed
mount's axes (scenenav.core.camera_geometry.fixed_mount_axes), so a sign or axis error fails."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from perception.frame_flow import MAX_INTERVAL_S, FrameFlow
from scenenav.core.camera_geometry import fixed_mount_axes, focal_length_px
from scenenav.core.rotations import quat_from_aviation_euler, quat_to_rotation_matrix

SIZE_PX = 200
FOV_DEG = 60.0
F_PX = focal_length_px(SIZE_PX, FOV_DEG)
TEXTURE_M_PER_PX = 0.25


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    """A 400 m ground texture: smoothed noise, grey in [0, 1]."""
    rng = np.random.default_rng(7)
    t = cv2.GaussianBlur(rng.random((1600, 1600)).astype(np.float32), (0, 0), 2.0)
    return (t - t.min()) / (t.max() - t.min())


def _render(texture: np.ndarray, eye_enu_m, roll: float, pitch: float, heading: float) -> np.ndarray:
    """The fixed-mount camera's image of the textured plane z = 0 (texture centred on the origin)."""
    rows = quat_to_rotation_matrix(np.array(quat_from_aviation_euler(roll, pitch, heading)))
    right, up, back = (np.asarray(a) for a in fixed_mount_axes(rows))
    c = SIZE_PX / 2.0
    u, v = np.meshgrid(np.arange(SIZE_PX) + 0.5, np.arange(SIZE_PX) + 0.5)
    d = (((u - c) / F_PX)[..., None] * right - ((v - c) / F_PX)[..., None] * up - back)
    s = -eye_enu_m[2] / d[..., 2]
    x = eye_enu_m[0] + s * d[..., 0]
    y = eye_enu_m[1] + s * d[..., 1]
    n = texture.shape[0]
    mx = (x / TEXTURE_M_PER_PX + n / 2 - 0.5).astype(np.float32)
    my = (n / 2 - y / TEXTURE_M_PER_PX - 0.5).astype(np.float32)
    return cv2.remap(texture, mx, my, cv2.INTER_LINEAR)


def _flow(texture, pose0, pose1, dt=0.1):
    ff = FrameFlow()
    assert ff.update(0.0, _render(texture, *pose0), (F_PX, F_PX)) is None      # the first frame
    return ff.update(dt, _render(texture, *pose1), (F_PX, F_PX))


def test_forward_motion_is_positive_y(texture):
    """Heading north, 1 m north in 0.1 s at 100 m: (0, vx / r) = (0, +0.1) rad/s."""
    north = 0.0
    flow = _flow(texture, ((0.0, 0.0, 100.0), 0.0, 0.0, north), ((0.0, 1.0, 100.0), 0.0, 0.0, north))
    assert flow is not None and flow.quality > 0.5
    assert flow.interval_s == pytest.approx(0.1)
    assert flow.flow_flu_rad_s == pytest.approx((0.0, 0.1), abs=0.004)


def test_rightward_motion_is_positive_x(texture):
    """Heading east, 1 m south (the body's right) in 0.1 s: -vy / r = +0.1 rad/s on x."""
    east = 0.5 * math.pi
    flow = _flow(texture, ((0.0, 0.0, 100.0), 0.0, 0.0, east), ((0.0, -1.0, 100.0), 0.0, 0.0, east))
    assert flow is not None
    assert flow.flow_flu_rad_s == pytest.approx((0.1, 0.0), abs=0.004)


def test_a_body_rotation_shows_as_its_negative(texture):
    """Rolling right (wx > 0) and pitching nose down (wy > 0, FLU) at 0.05 rad/s, not moving:
    (-wx, -wy)."""
    w = 0.05
    flow = _flow(texture, ((0.0, 0.0, 100.0), 0.0, 0.0, 0.0),
                 ((0.0, 0.0, 100.0), w * 0.1, 0.0, 0.0))
    assert flow.flow_flu_rad_s == pytest.approx((-w, 0.0), abs=0.003)
    # aviation pitch is nose up; FLU's rate about +y (left) is nose down
    flow = _flow(texture, ((0.0, 0.0, 100.0), 0.0, 0.0, 0.0),
                 ((0.0, 0.0, 100.0), 0.0, -w * 0.1, 0.0))
    assert flow.flow_flu_rad_s == pytest.approx((0.0, -w), abs=0.003)


def test_no_flow_across_a_gap_a_resize_or_a_reset(texture):
    img = _render(texture, (0.0, 0.0, 100.0), 0.0, 0.0, 0.0)
    ff = FrameFlow()
    ff.update(0.0, img, (F_PX, F_PX))
    assert ff.update(MAX_INTERVAL_S + 0.1, img, (F_PX, F_PX)) is None
    assert ff.update(MAX_INTERVAL_S + 0.2, img[:150, :150], (F_PX, F_PX)) is None
    ff.reset()
    assert ff.update(MAX_INTERVAL_S + 0.3, img[:150, :150], (F_PX, F_PX)) is None
    still = ff.update(MAX_INTERVAL_S + 0.4, img[:150, :150], (F_PX, F_PX))
    assert still is not None and still.flow_flu_rad_s == pytest.approx((0.0, 0.0), abs=1e-3)
    assert ff.update(MAX_INTERVAL_S + 0.5, img[:150, :150], (0.0, F_PX)) is None      # no focal length


def test_a_flat_image_has_no_quality():
    ff = FrameFlow()
    flat = np.full((SIZE_PX, SIZE_PX), 0.5)
    ff.update(0.0, flat, (F_PX, F_PX))
    flow = ff.update(0.1, flat, (F_PX, F_PX))
    assert flow is None or flow.quality < 0.5
