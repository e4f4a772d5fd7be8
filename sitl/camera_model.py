"""Camera and mount realism: what a real camera does to the ideal pinhole render (pure numpy + cv2).

``CameraOptics`` runs where the image is rendered (the render worker, ``sitl.render_worker``, off the
simulator's critical path) and applies, per capture and in this order:

1. **capture-time jitter**: the shutter opens ``dt ~ N(0, capture_jitter_std_s)`` after the nominal
   capture tick; the pose is carried there with the truth velocity and body rates of the tick
   (``pose_after``). The frame's ``timestamp_us`` stays the nominal tick (plus the clock offset,
   ``sitl.core.SimulatorCore.camera_frame``): the camera does not know its own jitter.
2. **gimbal model** (GIMBAL mount, ``GimbalModel``): the stabiliser follows the body with a
   first-order lag of ``gimbal_time_constant_s`` (the camera tilts by the part of the body's roll and
   pitch the stabiliser has not yet taken out, and its heading lags the body's), plus a constant
   roll/pitch bias and white pointing noise per frame.
3. **motion blur**: the ground point at the image centre moves by ``motion_blur_px`` during the
   exposure ``exposure_time_s`` (the true velocity and body rates; a GIMBAL camera keeps its
   attitude over the exposure); the image is convolved with that line (``linear_motion_blur``).
4. **lens distortion** (Brown-Conrady k1, k2, p1, p2, ``scenenav.core.camera_geometry``): the ideal
   image is rendered with a margin wide enough for the distorted image's field (same focal length,
   same principal point) and resampled once through a map computed at construction (``LensMap``).
5. **auto-exposure** (``AutoExposure``): the gain steers the frame's mean grey towards
   ``auto_exposure_target_grey`` with a first-order lag ``auto_exposure_time_constant_s`` and a
   relative gain noise ``auto_exposure_gain_noise_std`` per frame.

JPEG compression (``jpeg_roundtrip``) comes last, after the sensor noise of ``sitl.sensors.CameraEffects``,
in ``SimulatorCore.camera_frame``. Randomness comes from one generator (the core's ``camera_optics``
stream) drawn in capture order, so lockstep runs stay deterministic whether the worker is a process or not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from scenenav.core.camera_geometry import (
    NO_DISTORTION,
    Distortion,
    distort_normalized,
    fixed_mount_axes,
    focal_length_px,
    undistort_normalized,
)
from scenenav.core.rotations import (
    aviation_euler_from_quat,
    quat_from_aviation_euler,
    quat_from_rotation_vector,
    quat_multiply,
    quat_normalise,
)
from sitl.config import CameraConfig, CameraMount
from sitl.dynamics import rotation_rows

#: The camera keys of the ``realistic`` realism profile (``sim.camera``; docs/realism.md "Camera and
#: mount" gives each value's basis). The perception side of it: ``perception.alignment: homography``.
REALISTIC_CAMERA: dict[str, object] = {
    "mount": "fixed",
    "distortion_k1_k2_p1_p2": (-0.10, 0.02, 0.0005, -0.0005),
    "exposure_time_s": 0.002,
    "auto_exposure_time_constant_s": 0.5,
    "auto_exposure_gain_noise_std": 0.02,
    "jpeg_quality": 85,
    "capture_jitter_std_s": 0.002,
    "clock_offset_s": 0.01,
}
#: The gimbal model's keys for a ``realistic`` run that chooses ``mount: gimbal``.
REALISTIC_GIMBAL: dict[str, object] = {
    "gimbal_time_constant_s": 0.1,
    "gimbal_bias_roll_pitch_deg": (0.5, -0.3),
    "gimbal_noise_std_deg": 0.3,
}

Vec3 = tuple[float, float, float]
Axes = tuple[Vec3, Vec3, Vec3]

#: A blur shorter than this (pixels) is not applied (below a tenth of a pixel it changes nothing
#: visible and the kernel would be a single tap).
MIN_BLUR_PX = 0.1
#: Samples per pixel of blur length when the line kernel is drawn (bilinear splats).
_KERNEL_SAMPLES_PER_PX = 8
#: Extra margin, pixels, of the ideal render around the distorted field (bilinear needs a neighbour).
_LENS_MARGIN_PX = 2
_GREY_MAX = 255.0


def camera_axes(q_wxyz: np.ndarray, mount: CameraMount) -> tuple[Vec3, Vec3, Vec3]:
    """World directions of the image right, image up, and the camera back (-optical axis)."""
    rows = rotation_rows(q_wxyz)
    if mount is CameraMount.FIXED:
        return fixed_mount_axes(rows)   # image right = body -y, image up = body +x, back = body +z
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
    # GIMBAL: nadir; image up = body +x projected on the ground. With body +x vertical (pitch
    # +-90 deg) the nose has no heading: use the body z axis, which then points forward (nose
    # down) or backward (nose up).
    fx, fy = r00, r10
    if fx * fx + fy * fy < 1e-12:
        fx, fy = -r20 * r02, -r20 * r12
    yaw = math.atan2(fy, fx)
    c, s = math.cos(yaw), math.sin(yaw)
    return (s, -c, 0.0), (c, s, 0.0), (0.0, 0.0, 1.0)


def pose_after(position_enu_m: np.ndarray, q_wxyz: np.ndarray, velocity_enu_m_s: np.ndarray,
               body_rates_flu_rad_s: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``dt_s`` later at constant velocity and body rates (q <- q * exp(omega dt / 2))."""
    pos = np.asarray(position_enu_m, dtype=float) + dt_s * np.asarray(velocity_enu_m_s, dtype=float)
    w = np.asarray(body_rates_flu_rad_s, dtype=float) * dt_s
    dq = quat_from_rotation_vector(float(w[0]), float(w[1]), float(w[2]))
    return pos, np.array(quat_normalise(quat_multiply(tuple(q_wxyz), dq)))


def project(point_enu_m, eye_enu_m, axes: Axes, f_px: float, cx: float, cy: float) -> tuple[float, float]:
    """Continuous pixel (u, v) of a world point in a pinhole camera at ``eye`` with ``axes``
    (image right, image up, back); NaN behind the camera."""
    d = np.asarray(point_enu_m, dtype=float) - np.asarray(eye_enu_m, dtype=float)
    right, up, back = (np.asarray(a, dtype=float) for a in axes)
    z = -float(d @ back)
    if z <= 0.0:
        return math.nan, math.nan
    return cx + f_px * float(d @ right) / z, cy - f_px * float(d @ up) / z


def centre_ground_point(eye_enu_m, axes: Axes) -> np.ndarray | None:
    """Where the optical axis meets the ground plane z = 0 (None when it does not point down)."""
    back = np.asarray(axes[2], dtype=float)
    if back[2] <= 1e-9:
        return None
    eye = np.asarray(eye_enu_m, dtype=float)
    return eye - back * (eye[2] / back[2])


def motion_blur_px(eye0, axes0: Axes, eye1, axes1: Axes, f_px: float) -> tuple[float, float]:
    """Image displacement (du, dv), pixels, of the ground point at the image centre between the
    start (eye0, axes0) and the end (eye1, axes1) of an exposure; (0, 0) when the camera does not
    look at the ground."""
    g = centre_ground_point(eye0, axes0)
    if g is None:
        return 0.0, 0.0
    u, v = project(g, eye1, axes1, f_px, 0.0, 0.0)
    if not (math.isfinite(u) and math.isfinite(v)):
        return 0.0, 0.0
    return u, v


def line_kernel(du: float, dv: float) -> np.ndarray:
    """Normalised float32 kernel of a uniform line of length |(du, dv)| pixels centred on the
    kernel centre (bilinear splats of evenly spaced samples: sub-pixel lengths and angles)."""
    length = math.hypot(du, dv)
    half = int(math.ceil(0.5 * max(abs(du), abs(dv)))) + 1
    size = 2 * half + 1
    k = np.zeros((size, size), dtype=np.float64)
    n = max(2, int(math.ceil(length * _KERNEL_SAMPLES_PER_PX)) + 1)
    for t in np.linspace(-0.5, 0.5, n):
        x, y = half + t * du, half + t * dv
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        k[y0, x0] += (1 - fx) * (1 - fy)
        k[y0, x0 + 1] += fx * (1 - fy)
        k[y0 + 1, x0] += (1 - fx) * fy
        k[y0 + 1, x0 + 1] += fx * fy
    return (k / k.sum()).astype(np.float32)


def linear_motion_blur(image: np.ndarray, du: float, dv: float) -> np.ndarray:
    """``image`` (float32, (H, W) or (H, W, C)) averaged along the line (du, dv) pixels; unchanged
    below ``MIN_BLUR_PX``."""
    if math.hypot(du, dv) < MIN_BLUR_PX:
        return image
    return cv2.filter2D(image, -1, line_kernel(du, dv), borderType=cv2.BORDER_REPLICATE)


@dataclass(frozen=True)
class LensMap:
    """Rendering through a distorting lens: the ideal image is rendered ``margin_px`` wider on every
    side (same focal length and principal point, so ``tan_x`` grows by (W + 2 m) / W) and resampled
    with ``map_x``, ``map_y`` (float32, pixel-index coordinates of the ideal image, per distorted pixel)."""

    margin_px: int
    map_x: np.ndarray
    map_y: np.ndarray

    @classmethod
    def build(cls, width_px: int, height_px: int, fov_deg: float, k: Distortion) -> LensMap:
        f = focal_length_px(width_px, fov_deg)
        cx, cy = 0.5 * width_px, 0.5 * height_px
        u, v = np.meshgrid(np.arange(width_px, dtype=float) + 0.5, np.arange(height_px, dtype=float) + 0.5)
        xu, yu = undistort_normalized((u - cx) / f, (v - cy) / f, k)
        uu, vu = cx + f * xu, cy + f * yu
        reach = max(float(np.max(-uu)), float(np.max(uu - width_px)), float(np.max(-vu)),
                    float(np.max(vu - height_px)), 0.0)
        margin = int(math.ceil(reach)) + _LENS_MARGIN_PX
        # Pixel-index coordinates in the enlarged ideal image (pixel centres on integers).
        return cls(margin, (uu + margin - 0.5).astype(np.float32), (vu + margin - 0.5).astype(np.float32))

    def apply(self, ideal: np.ndarray) -> np.ndarray:
        return cv2.remap(ideal, self.map_x, self.map_y, interpolation=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)


def distorted_pixel(u: float, v: float, width_px: int, height_px: int, fov_deg: float,
                    k: Distortion) -> tuple[float, float]:
    """Where an ideal (pinhole) continuous pixel (u, v) appears through the lens ``k``."""
    f = focal_length_px(width_px, fov_deg)
    cx, cy = 0.5 * width_px, 0.5 * height_px
    xd, yd = distort_normalized((u - cx) / f, (v - cy) / f, k)
    return cx + f * xd, cy + f * yd


class GimbalModel:
    """A two-axis stabilised gimbal with yaw follow (see the module docstring, step 2).

    ``axes(q_body, t_s)``: the camera axes at capture time ``t_s``. The stabiliser's state (the
    body roll, pitch and heading it has caught up with) follows the body through
    ``1 - exp(-dt / tau)`` per capture; the first capture starts caught up.
    """

    def __init__(self, cfg: CameraConfig, rng: np.random.Generator) -> None:
        self.tau_s = cfg.gimbal_time_constant_s
        self.bias_rad = tuple(math.radians(b) for b in cfg.gimbal_bias_roll_pitch_deg)
        self.noise_rad = math.radians(cfg.gimbal_noise_std_deg)
        self._rng = rng
        self._state: tuple[float, float, float] | None = None
        self._t_s = 0.0

    def pointing(self, q_wxyz, t_s: float) -> tuple[float, float, float]:
        """(roll error, pitch error, heading) of the camera, radians."""
        roll, pitch, heading = aviation_euler_from_quat(q_wxyz)
        if self._state is None or self.tau_s <= 0.0:
            state = (roll, pitch, heading)
        else:
            a = 1.0 - math.exp(-max(t_s - self._t_s, 0.0) / self.tau_s)
            r0, p0, h0 = self._state
            dh = math.remainder(heading - h0, math.tau)
            state = (r0 + a * (roll - r0), p0 + a * (pitch - p0), h0 + a * dh)
        self._state, self._t_s = state, t_s
        err_r = roll - state[0] + self.bias_rad[0]
        err_p = pitch - state[1] + self.bias_rad[1]
        if self.noise_rad > 0.0:
            n = self._rng.standard_normal(2)
            err_r += self.noise_rad * float(n[0])
            err_p += self.noise_rad * float(n[1])
        return err_r, err_p, state[2]

    def axes(self, q_wxyz, t_s: float) -> Axes:
        err_r, err_p, heading = self.pointing(q_wxyz, t_s)
        return fixed_mount_axes(rotation_rows(quat_from_aviation_euler(err_r, err_p, heading)))


class AutoExposure:
    """Gain steering the mean grey to a target with a first-order lag, plus relative gain noise.

    The gain wanted for a frame is ``target / mean`` of the frame as exposed at gain 1; the gain
    applied moves towards it by ``1 - exp(-dt / tau)`` per frame (the first frame starts there),
    times ``1 + noise * N(0, 1)``.
    """

    def __init__(self, cfg: CameraConfig, rng: np.random.Generator) -> None:
        self.tau_s = cfg.auto_exposure_time_constant_s
        self.target = cfg.auto_exposure_target_grey
        self.noise = cfg.auto_exposure_gain_noise_std
        self._rng = rng
        self.gain: float | None = None
        self._t_s = 0.0

    def step(self, mean_grey: float, t_s: float) -> float:
        """The gain for a frame of ``mean_grey`` (0..255 at gain 1) captured at ``t_s``."""
        wanted = self.target / max(mean_grey, 1.0)
        if self.gain is None:
            self.gain = wanted
        else:
            a = 1.0 - math.exp(-max(t_s - self._t_s, 0.0) / self.tau_s)
            self.gain += a * (wanted - self.gain)
        self._t_s = t_s
        g = self.gain
        if self.noise > 0.0:
            g *= 1.0 + self.noise * float(self._rng.standard_normal())
        return max(g, 0.0)


def jpeg_roundtrip(image_rgb_uint8: np.ndarray, quality: int) -> np.ndarray:
    """The image after JPEG compression at ``quality`` (1..100) and decompression (cv2 / libjpeg)."""
    bgr = cv2.cvtColor(image_rgb_uint8, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if decoded is None:
        raise RuntimeError("JPEG decoding failed")
    return cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)


class CameraOptics:
    """Steps 1-5 of the module docstring around a renderer ``render(eye, right, up, back, w, h, tan_x,
    tan_y) -> uint8 RGB`` (``worlds.view_renderer.CityRenderer.render``)."""

    def __init__(self, cfg: CameraConfig, rng: np.random.Generator, min_height_m: float) -> None:
        self.cfg = cfg
        self._rng = rng
        self.min_height_m = min_height_m
        self.f_px = focal_length_px(cfg.width_px, cfg.fov_deg)
        k = tuple(float(c) for c in cfg.distortion_k1_k2_p1_p2)
        self.lens = None if k == NO_DISTORTION else LensMap.build(cfg.width_px, cfg.height_px, cfg.fov_deg, k)  # type: ignore[arg-type]
        self.gimbal = GimbalModel(cfg, rng) if cfg.mount is CameraMount.GIMBAL and cfg.gimbal_enabled else None
        self.exposure = AutoExposure(cfg, rng) if cfg.auto_exposure_time_constant_s > 0.0 else None
        self.last_blur_px = (0.0, 0.0)
        self.last_gain = 1.0

    def axes(self, q_wxyz, t_s: float) -> Axes:
        if self.gimbal is not None:
            return self.gimbal.axes(q_wxyz, t_s)
        return camera_axes(np.asarray(q_wxyz, dtype=float), self.cfg.mount)

    def capture(self, render, capture_s: float, position_enu_m, q_wxyz, velocity_enu_m_s=(0.0, 0.0, 0.0),
                body_rates_flu_rad_s=(0.0, 0.0, 0.0)) -> np.ndarray:
        cfg = self.cfg
        pos = np.asarray(position_enu_m, dtype=float)
        q = np.asarray(q_wxyz, dtype=float)
        vel = np.asarray(velocity_enu_m_s, dtype=float)
        rates = np.asarray(body_rates_flu_rad_s, dtype=float)
        t_s = capture_s
        if cfg.capture_jitter_std_s > 0.0:
            dt = cfg.capture_jitter_std_s * float(self._rng.standard_normal())
            pos, q = pose_after(pos, q, vel, rates, dt)
            t_s += dt
        axes = self.axes(q, t_s)
        eye = (float(pos[0]), float(pos[1]), max(float(pos[2]), self.min_height_m))
        w, h = cfg.width_px, cfg.height_px
        tan_x = 0.5 * w / self.f_px
        m = self.lens.margin_px if self.lens is not None else 0
        wr, hr = w + 2 * m, h + 2 * m
        image = render(eye, *axes, wr, hr, tan_x * wr / w, tan_x * hr / w)
        float_img: np.ndarray | None = None
        if cfg.exposure_time_s > 0.0:
            pos1, q1 = pose_after(pos, q, vel, rates, cfg.exposure_time_s)
            axes1 = self.axes_end(q1, axes)
            eye1 = (float(pos1[0]), float(pos1[1]), max(float(pos1[2]), self.min_height_m))
            du, dv = motion_blur_px(eye, axes, eye1, axes1, self.f_px)
            self.last_blur_px = (du, dv)
            if math.hypot(du, dv) >= MIN_BLUR_PX:
                float_img = linear_motion_blur(image.astype(np.float32), du, dv)
        if self.lens is not None:
            image = self.lens.apply(float_img if float_img is not None else image)
            float_img = image if image.dtype == np.float32 else None
        if self.exposure is not None:
            src = float_img if float_img is not None else image.astype(np.float32)
            gain = self.exposure.step(float(np.mean(src)), t_s)
            self.last_gain = gain
            float_img = src * np.float32(gain)
        if float_img is not None:
            image = np.clip(np.rint(float_img), 0.0, _GREY_MAX).astype(np.uint8)
        return image

    def axes_end(self, q_end, axes_start: Axes) -> Axes:
        """The camera axes at the end of the exposure: a FIXED camera turns with the body; a
        GIMBAL keeps its attitude over the few milliseconds."""
        if self.cfg.mount is CameraMount.GIMBAL:
            return axes_start
        return fixed_mount_axes(rotation_rows(q_end))
