"""Camera and mount realism (sitl.camera_model): each effect on small images, hand-checked.

* lens: undistort(distort(x)) = x; an image rendered through the lens and undistorted by perception
  (``perception.alignment.undistort``) is the ideal pinhole image;
* motion blur: the blur length is speed x exposure / ground sampling distance, along the motion;
* JPEG: the quality changes the bytes (lower quality, larger error);
* auto-exposure: the first-order lag per frame, the gain noise;
* gimbal: lag (a roll step decays by exp(-dt / tau)), bias, noise;
* capture jitter and the camera clock offset; everything off = the ideal image, byte for byte;
* the render worker applies the effects exactly as in-process (same seed, same images).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from perception.alignment import undistort
from scenenav.core.camera_geometry import (
    distort_normalized,
    focal_length_px,
    ground_footprint_m,
    intrinsics_px,
    undistort_normalized,
)
from scenenav.core.rotations import quat_from_aviation_euler
from sitl.camera import GroundCamera
from sitl.camera_model import (
    REALISTIC_CAMERA,
    AutoExposure,
    CameraOptics,
    GimbalModel,
    camera_axes,
    jpeg_roundtrip,
    line_kernel,
    linear_motion_blur,
    motion_blur_px,
    pose_after,
)
from sitl.config import CameraConfig, CameraMount

K = (-0.10, 0.02, 0.0005, -0.0005)
W = H = 64
FOV = 60.0


def _pattern(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth grey pattern of normalised image coordinates (what an ideal pinhole sees)."""
    return 128.0 + 60.0 * np.sin(9.0 * x + 1.0) * np.cos(7.0 * y - 0.5) + 30.0 * np.sin(4.0 * x * y)


def _stub_render(eye, right, up, back, w, h, tan_x, tan_y):
    """A 'renderer' drawing ``_pattern`` at its pinhole pixel centres (focal from ``tan_x``)."""
    f = 0.5 * w / tan_x
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    g = np.clip(np.rint(_pattern((u - w / 2) / f, (v - h / 2) / f)), 0, 255).astype(np.uint8)
    return np.dstack([g, g, g])


def _cfg(**kw) -> CameraConfig:
    return CameraConfig(width_px=W, height_px=H, fov_deg=FOV, **kw)


def _capture(cfg: CameraConfig, seed: int = 0, **kw) -> np.ndarray:
    optics = CameraOptics(cfg, np.random.default_rng(seed), 0.3)
    return optics.capture(_stub_render, kw.get("t_s", 0.0), np.array([0.0, 0.0, 100.0]),
                          np.array([1.0, 0.0, 0.0, 0.0]), kw.get("vel", (0.0, 0.0, 0.0)), (0.0, 0.0, 0.0))


# ------------------------------------------------------------------------------------------- lens
def test_undistort_inverts_distort_over_the_image():
    f = focal_length_px(200, FOV)
    u, v = np.meshgrid(np.linspace(0, 200, 41), np.linspace(0, 200, 41))
    x, y = (u - 100) / f, (v - 100) / f
    xd, yd = distort_normalized(x, y, K)
    assert np.max(np.hypot(xd - x, yd - y)) * f > 3.0          # the lens moves the corners by pixels
    xu, yu = undistort_normalized(xd, yd, K)
    assert np.max(np.hypot(xu - x, yu - y)) * f < 1e-4           # and the inverse takes them back


def test_distortion_is_rendered_and_perception_undistorts_it():
    ideal = _stub_render(None, None, None, None, W, H, math.tan(math.radians(FOV / 2)), 0.0)[:, :, 0]
    lensed = _capture(_cfg(distortion_k1_k2_p1_p2=K))[:, :, 0]
    # the distorted image is what the pattern looks like through the lens
    f = focal_length_px(W, FOV)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    xu, yu = undistort_normalized((u - W / 2) / f, (v - H / 2) / f, K)
    np.testing.assert_allclose(lensed, _pattern(xu, yu), atol=3.0)
    inner = (slice(4, H - 4), slice(4, W - 4))
    lens_error = np.abs(lensed.astype(float) - ideal)[inner]
    assert np.max(lens_error) > 10.0
    back = undistort(lensed.astype(np.float32) / 255.0, intrinsics_px(W, H, FOV), K) * 255.0
    back_error = np.abs(back - ideal)[inner]
    assert np.max(back_error) < 4.0 and np.mean(back_error) < 0.4 * np.mean(lens_error)


# ------------------------------------------------------------------------------------ motion blur
def test_blur_length_is_speed_times_exposure_over_gsd():
    speed, exposure, alt = 10.0, 0.05, 100.0
    gsd = ground_footprint_m(alt, FOV) / 200
    f = focal_length_px(200, FOV)
    q = np.array(quat_from_aviation_euler(0.0, 0.0, 0.0))     # heading north: image right = east
    axes = camera_axes(q, CameraMount.GIMBAL)
    eye0 = np.array([0.0, 0.0, alt])
    eye1, _ = pose_after(eye0, q, np.array([speed, 0.0, 0.0]), np.zeros(3), exposure)
    du, dv = motion_blur_px(eye0, axes, eye1, axes, f)
    # the ground moves left in the image as the camera flies east
    assert du == pytest.approx(-speed * exposure / gsd, rel=1e-9) and dv == pytest.approx(0.0, abs=1e-9)


def test_pitch_rate_blurs_a_fixed_camera_along_the_image_column():
    f = focal_length_px(200, FOV)
    q = np.array(quat_from_aviation_euler(0.0, 0.0, 0.0))
    rate, exposure = 0.5, 0.01                                  # nose up at 0.5 rad/s for 10 ms
    _, q1 = pose_after(np.zeros(3), q, np.zeros(3), np.array([0.0, -rate, 0.0]), exposure)
    eye = np.array([0.0, 0.0, 100.0])
    du, dv = motion_blur_px(eye, camera_axes(q, CameraMount.FIXED), eye, camera_axes(q1, CameraMount.FIXED), f)
    assert du == pytest.approx(0.0, abs=1e-9)
    assert abs(dv) == pytest.approx(f * math.tan(rate * exposure), rel=1e-6)


def test_line_kernel_spreads_an_edge_over_the_blur_length():
    k = line_kernel(3.0, 0.0)
    assert k.sum() == pytest.approx(1.0, abs=1e-6) and k.shape[0] == k.shape[1]
    cols = np.arange(k.shape[1]) - k.shape[1] // 2
    assert np.sum(k.sum(axis=0) * cols) == pytest.approx(0.0, abs=1e-6)          # centred
    # a uniform line of 3 px has variance 3^2 / 12; the bilinear splats add at most 1/4 px^2
    assert 9.0 / 12.0 <= np.sum(k.sum(axis=0) * cols ** 2) <= 9.0 / 12.0 + 0.25
    edge = np.zeros((9, 20), np.float32)
    edge[:, 10:] = 1.0
    out = linear_motion_blur(edge, 3.0, 0.0)
    ramp = np.sum((out[4] > 0.02) & (out[4] < 0.98))
    assert ramp in (3, 4)                                         # 3 px, plus the splats' sub-pixel tails
    assert linear_motion_blur(edge, 0.05, 0.0) is edge            # below 0.1 px: untouched


# ------------------------------------------------------------------------------------------- JPEG
def test_jpeg_quality_changes_the_bytes():
    rng = np.random.default_rng(3)
    img = np.clip(128 + 40 * rng.standard_normal((64, 64, 3)), 0, 255).astype(np.uint8)
    hi, lo = jpeg_roundtrip(img, 95), jpeg_roundtrip(img, 20)
    assert hi.shape == img.shape and hi.dtype == np.uint8
    err_hi = np.mean(np.abs(hi.astype(float) - img))
    err_lo = np.mean(np.abs(lo.astype(float) - img))
    assert 0.0 < err_hi < err_lo and not np.array_equal(hi, lo)


# ---------------------------------------------------------------------------------- auto-exposure
def test_auto_exposure_lags_with_its_time_constant():
    ae = AutoExposure(_cfg(auto_exposure_time_constant_s=0.5, auto_exposure_target_grey=120.0),
                      np.random.default_rng(0))
    assert ae.step(60.0, 0.0) == pytest.approx(2.0)               # the first frame starts exposed
    a = 1.0 - math.exp(-0.1 / 0.5)
    assert ae.step(120.0, 0.1) == pytest.approx(2.0 + a * (1.0 - 2.0))   # scene brighter: one step
    for i in range(2, 60):
        g = ae.step(120.0, 0.1 * i)
    assert g == pytest.approx(1.0, abs=1e-4)


def test_auto_exposure_gain_noise():
    ae = AutoExposure(_cfg(auto_exposure_time_constant_s=0.5, auto_exposure_gain_noise_std=0.02),
                      np.random.default_rng(1))
    gains = np.array([ae.step(118.0, 0.1 * i) for i in range(2000)])
    assert np.mean(gains) == pytest.approx(1.0, abs=0.003)
    assert np.std(gains) == pytest.approx(0.02, rel=0.1)


def test_auto_exposure_brightens_a_dark_capture():
    img = _capture(_cfg(auto_exposure_time_constant_s=0.5, auto_exposure_target_grey=160.0))
    assert np.mean(img) == pytest.approx(160.0, abs=2.0)


# ----------------------------------------------------------------------------------------- gimbal
def test_gimbal_lag_bias_and_noise():
    cfg = _cfg(gimbal_time_constant_s=0.1)
    g = GimbalModel(cfg, np.random.default_rng(0))
    level = quat_from_aviation_euler(0.0, 0.0, 0.3)
    rolled = quat_from_aviation_euler(math.radians(10.0), 0.0, 0.3)
    assert g.pointing(level, 0.0) == pytest.approx((0.0, 0.0, 0.3))
    err_r, err_p, heading = g.pointing(rolled, 0.1)               # a roll step, one frame later
    assert err_r == pytest.approx(math.radians(10.0) * math.exp(-1.0), rel=1e-6)
    assert err_p == pytest.approx(0.0, abs=1e-9) and heading == pytest.approx(0.3)
    biased = GimbalModel(_cfg(gimbal_bias_roll_pitch_deg=(0.5, -0.3)), np.random.default_rng(0))
    assert biased.pointing(level, 0.0)[:2] == pytest.approx((math.radians(0.5), math.radians(-0.3)))
    noisy = GimbalModel(_cfg(gimbal_noise_std_deg=0.3), np.random.default_rng(0))
    errs = np.array([noisy.pointing(level, 0.1 * i)[:2] for i in range(2000)])
    assert np.degrees(np.std(errs, axis=0)) == pytest.approx([0.3, 0.3], rel=0.1)


def test_gimbal_bias_tilts_the_optical_axis():
    g = GimbalModel(_cfg(gimbal_bias_roll_pitch_deg=(0.0, 1.0)), np.random.default_rng(0))
    _, up, back = g.axes(quat_from_aviation_euler(0.0, 0.0, 0.0), 0.0)
    # pitched up 1 degree at heading north: the optical axis (-back) leans 1 degree to the north
    assert math.degrees(math.atan2(-back[1], back[2])) == pytest.approx(1.0, abs=1e-9)
    assert up[1] > 0.99


# ------------------------------------------------------------------------- jitter, clock, default off
def test_pose_after_moves_and_turns():
    q = np.array(quat_from_aviation_euler(0.0, 0.0, 0.0))
    pos, q1 = pose_after(np.array([1.0, 2.0, 3.0]), q, np.array([10.0, 0.0, -1.0]),
                         np.array([0.0, 0.0, -1.0]), 0.1)            # yaw right 1 rad/s
    np.testing.assert_allclose(pos, [2.0, 2.0, 2.9])
    from scenenav.core.rotations import heading_from_quat
    assert heading_from_quat(q1) == pytest.approx(0.1)


def test_capture_jitter_moves_the_image_deterministically():
    cfg = _cfg(capture_jitter_std_s=0.01)
    a = _capture(cfg, seed=4, vel=(30.0, 0.0, 0.0))
    b = _capture(cfg, seed=4, vel=(30.0, 0.0, 0.0))
    np.testing.assert_array_equal(a, b)


def test_everything_off_is_the_ideal_image():
    cfg = CameraConfig()
    assert not cfg.optics_enabled
    # JPEG and the clock offset act where the frame is published (SimulatorCore.camera_frame)
    assert not CameraConfig(jpeg_quality=80, clock_offset_s=0.01).optics_enabled
    fixed_gimbal_keys = CameraConfig(mount=CameraMount.FIXED, gimbal_noise_std_deg=0.3)
    assert not fixed_gimbal_keys.optics_enabled                   # the gimbal model needs the gimbal
    top = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    small = CameraConfig(width_px=16, height_px=16, ground_window_px=64)
    with GroundCamera(-1, top, 1.0, small, optics_rng=np.random.default_rng(0)) as cam:
        assert cam.optics is None
        pos, q = np.array([1.0, 2.0, 20.0]), np.array([1.0, 0.0, 0.0, 0.0])
        np.testing.assert_array_equal(cam.render_capture(0.0, pos, q, (5.0, 0.0, 0.0)), cam.render(pos, q))


def test_camera_frame_clock_offset_jpeg_and_calibration():
    from sitl.config import SimConfig
    from sitl.core import CameraRelease, SimulatorCore
    cam = CameraConfig(width_px=32, height_px=32, clock_offset_s=0.012, jpeg_quality=50,
                       distortion_k1_k2_p1_p2=K)
    core = SimulatorCore(SimConfig(camera=cam), 100.0, 0, 0.0, 0.0)
    try:
        image = np.random.default_rng(2).integers(0, 255, (32, 32, 3), dtype=np.uint8)
        frame = core.camera_frame(CameraRelease(3, 300_000), image)
    finally:
        core.close()
    assert frame.timestamp_us == 312_000 and frame.seq == 3
    assert frame.intrinsics_fx_fy_cx_cy_px == pytest.approx(intrinsics_px(32, 32, cam.fov_deg))
    assert frame.distortion_k1_k2_p1_p2 == K
    np.testing.assert_array_equal(frame.pixels, jpeg_roundtrip(image, 50))


def test_render_worker_applies_the_effects_as_in_process():
    from sitl.render_worker import CameraPipeline
    top = np.random.default_rng(5).integers(0, 255, (128, 128, 3), dtype=np.uint8)
    keys = {k: v for k, v in REALISTIC_CAMERA.items() if k != "mount"}
    keys["exposure_time_s"] = 0.02
    base = CameraConfig(width_px=48, height_px=48, ground_window_px=256, mount=CameraMount.FIXED,
                        **keys)   # type: ignore[arg-type]
    images = []
    for in_worker in (True, False):
        cfg = dataclasses.replace(base, render_in_worker=in_worker)
        pipe = CameraPipeline(top, 0.5, cfg, optics_seed=np.random.SeedSequence(9))
        try:
            got = []
            for seq in range(3):
                pipe.request(seq, np.array([seq * 1.0, 0.0, 30.0]), np.array([1.0, 0.0, 0.0, 0.0]),
                             capture_s=0.1 * seq, velocity_enu_m_s=(10.0, 0.0, 0.0))
            for seq in range(3):
                got.append(pipe.result(seq))
        finally:
            pipe.close()
        images.append(got)
    for a, b in zip(*images, strict=True):
        np.testing.assert_array_equal(a, b)
    with GroundCamera(-1, top, 0.5, dataclasses.replace(base, render_in_worker=False)) as ideal:
        plain = ideal.render(np.array([0.0, 0.0, 30.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    assert not np.array_equal(images[0][0], plain)


def test_render_worker_more_frames_in_flight_than_image_slots():
    """Images come back through the shared ring while it has free slots and through the pipe
    beyond; either way each frame is the in-process render of its own pose."""
    from sitl.render_worker import IMAGE_SLOTS, CameraPipeline
    top = np.random.default_rng(6).integers(0, 255, (128, 128, 3), dtype=np.uint8)
    n = IMAGE_SLOTS + 3
    images = []
    for in_worker in (True, False):
        cfg = CameraConfig(width_px=40, height_px=32, ground_window_px=256, render_in_worker=in_worker)
        pipe = CameraPipeline(top, 0.5, cfg)
        try:
            for seq in range(n):
                pipe.request(seq, np.array([seq * 0.7, -seq * 0.3, 30.0]), np.array([1.0, 0.0, 0.0, 0.0]))
            got = [pipe.result(seq) for seq in reversed(range(n))]   # out of order as well
            pipe.request(n, np.array([1.0, 1.0, 30.0]), np.array([1.0, 0.0, 0.0, 0.0]))   # slots reused
            got.append(pipe.result(n))
        finally:
            pipe.close()
        images.append(got)
    assert images[0][0].shape == (32, 40, 3)
    for a, b in zip(*images, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len({img.tobytes() for img in images[0]}) == n + 1


def test_render_worker_reports_ready_before_the_first_frame():
    """``wait_ready`` returns once the worker has built its camera; a frame requested after that
    comes back like any other, and one requested before ``wait_ready`` was ever called too (the
    ready message is consumed on the way)."""
    from sitl.render_worker import CameraPipeline
    top = np.random.default_rng(7).integers(0, 255, (96, 96, 3), dtype=np.uint8)
    cfg = CameraConfig(width_px=32, height_px=32, ground_window_px=128, render_in_worker=True)
    pose = (np.array([0.0, 0.0, 30.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    early = CameraPipeline(top, 0.5, cfg)
    ready = CameraPipeline(top, 0.5, cfg)
    try:
        early.request(0, *pose)
        first = early.result(0)
        assert ready.wait_ready(30.0)
        assert ready.wait_ready(0.0)          # once ready, stays ready without another message
        ready.request(0, *pose)
        np.testing.assert_array_equal(ready.result(0), first)
    finally:
        early.close()
        ready.close()
    in_process = CameraPipeline(top, 0.5, dataclasses.replace(cfg, render_in_worker=False))
    try:
        assert in_process.wait_ready(0.0)
    finally:
        in_process.close()
