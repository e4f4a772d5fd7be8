"""Align a nadir camera capture with the north-up reference map (paper section 3).

The camera image has its top towards the drone's forward direction and its right towards the drone's
right, so at heading 0 (north) it is the north-up map crop. A ground point at compass bearing ``b``
appears at angle ``b - heading`` clockwise from image-up. Rotating the image clockwise (on screen) by
the heading therefore makes it north-up; in (u right, v down) pixel coordinates that is the matrix
``[[cos h, -sin h], [sin h, cos h]]``.

The camera ground sampling distance is ``footprint / width`` with ``footprint = 2 h tan(fov / 2)``
(``fov`` is the horizontal field of view, pixels are square;
``scenenav.core.camera_geometry.ground_footprint_m``), and the template is resampled by
``scale = camera_m_per_px / map_m_per_px``. Rotation and scale are one affine transform applied with a
single ``cv2.warpAffine`` (bilinear); the image centre (the nadir point) maps exactly to the template
centre, so the matched template centre is the drone's horizontal position.

Only the sensor values passed in are used (heading from the compass, altitude from the barometer).

**Homography alignment** (``tilt_rad`` given: a camera fixed to a tilted body). A camera looking
off-nadir sees the ground through a homography, not a rotation and scale: the nadir point is no longer
the image centre (27 m off at 15 degrees of pitch from 100 m) and the ground scale varies across the
image. With the body's roll and pitch (the autopilot's *estimate*, never truth), the heading and the
height, every template pixel (a north-up ground point at map scale, the template centre at the nadir
point) is projected into the capture, ``H = P A`` (``A``: template pixel -> ground offset from the
nadir point, ``P``: the pinhole projection of the fixed mount), and the capture is resampled once with
``cv2.warpPerspective``. The template is centred on the ground point of the image centre (where the
optical axis meets the ground) and is the largest square around it inside the ground footprint (the
image corners projected on the ground); ``AlignedCapture.centre_offset_px`` says where that centre is
from the nadir point, and the tracker (``perception.tracker.MatchTracker.match(offset_px=...)``)
subtracts it, so fixes stay the drone's position. At zero tilt this is the rotation + scale
alignment's inscribed square, offset zero. ``distortion`` (the frame's Brown-Conrady calibration) undistorts
the capture first (``undistort``, one remap with a cached map).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from perception.config import CropMode
from scenenav.core.camera_geometry import (
    NO_DISTORTION,
    Distortion,
    distort_normalized,
    fixed_mount_axes,
    focal_length_px,
    ground_footprint_m,
)
from scenenav.core.rotations import quat_from_aviation_euler, quat_to_rotation_matrix

log = logging.getLogger(__name__)

_U8_TO_UNIT = np.float32(1.0 / 255.0)
_MIN_IMAGE_PX = 8
_RGB_CHANNELS = 3
_RGBA_CHANNELS = 4


class BadInput(ValueError):
    """A sensor message the pipeline cannot use (bad image shape/dtype, NaN heading, altitude <= 0).

    The perception node counts and drops these; they are never a program error.
    """


class TemplateTooLarge(ValueError):
    """The aligned template would exceed ``max_template_px`` (e.g. flying too high for the map)."""


class TemplateTooSmall(ValueError):
    """The aligned template's smaller side would be below ``min_template_px`` (e.g. near the ground).

    Raised before any resampling: near the ground the scale is tiny and the anti-aliasing blur's
    sigma huge (seconds of work on the vehicle standing on the ground), for a template the pipeline
    would discard. ``side_px`` is the side the template would have had.
    """

    def __init__(self, side_px: int, altitude_m: float) -> None:
        super().__init__(f"template side {side_px} px at {altitude_m:.1f} m is too small")
        self.side_px = side_px
        self.altitude_m = altitude_m


@dataclass(frozen=True)
class AlignedCapture:
    """A capture rotated north-up and resampled to the reference map resolution.

    ``template``: float32 (n, m) grey levels in [0, 1]. ``mask``: bool, same shape, True where the
    template holds camera pixels (all True for ``CropMode.INSCRIBED_SQUARE``). ``scale``: template
    pixels per camera pixel. ``gray``: the capture as grey float32 in [0, 1], not rotated (the CNN
    input). The template centre (continuous coordinates (m/2, n/2)) is the nadir point.
    """

    template: np.ndarray
    mask: np.ndarray
    scale: float
    camera_m_per_px: float
    footprint_m: float
    heading_rad: float
    altitude_m: float
    gray: np.ndarray
    #: where the template centre lies relative to the nadir point, map pixels (u east, v south): zero
    #: for the rotation + scale alignment; the image centre's ground point for the homography one.
    centre_offset_px: tuple[float, float] = (0.0, 0.0)

    @property
    def side_px(self) -> int:
        """Smaller side of the template in map pixels."""
        return int(min(self.template.shape))

    @property
    def mask_is_full(self) -> bool:
        """True when every template pixel is valid (no mask needed in matching)."""
        return bool(self.mask.all())


def to_gray_float32(image: np.ndarray) -> np.ndarray:
    """uint8/float32 grey or RGB(A) image -> float32 grey in [0, 1] (one conversion, no extra copies).

    RGB uses the ITU-R BT.601 luma weights of ``cv2.COLOR_RGB2GRAY``. Raises BadInput on anything
    else (wrong rank, channel count or dtype).
    """
    if not isinstance(image, np.ndarray):
        raise BadInput(f"image: expected a numpy array, got {type(image).__name__}")
    if image.dtype not in (np.uint8, np.float32):
        raise BadInput(f"image dtype {image.dtype}: expected uint8 (0..255) or float32 (0..1)")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3:
        if image.shape[2] == _RGB_CHANNELS:
            gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        elif image.shape[2] == _RGBA_CHANNELS:
            gray = cv2.cvtColor(image, cv2.COLOR_RGBA2GRAY)
        else:
            raise BadInput(f"image shape {image.shape}: expected (H, W), (H, W, 3) or (H, W, 4)")
    elif image.ndim == 2:
        gray = image
    else:
        raise BadInput(f"image shape {image.shape}: expected (H, W), (H, W, 3) or (H, W, 4)")
    if min(gray.shape) < _MIN_IMAGE_PX:
        raise BadInput(f"image shape {image.shape}: expected at least {_MIN_IMAGE_PX} px per side")
    if gray.dtype == np.uint8:
        out = np.empty(gray.shape, dtype=np.float32)
        np.multiply(gray, _U8_TO_UNIT, out=out, casting="unsafe")
        return out
    if not np.all(np.isfinite(gray)):
        raise BadInput("image: float32 image contains NaN or inf")
    return np.ascontiguousarray(gray, dtype=np.float32)


def finite_number(name: str, value: float) -> float:
    """``value`` as a float; BadInput naming ``name`` when it is not a finite number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BadInput(f"{name} = {value!r}: expected a finite number") from None
    if not math.isfinite(v):
        raise BadInput(f"{name} = {value!r}: expected a finite number")
    return v


_UNDISTORT_MAPS: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
_UNDISTORT_CACHE_MAX = 8


def undistort(gray: np.ndarray, intrinsics_px: tuple[float, float, float, float],
              distortion: Distortion) -> np.ndarray:
    """The ideal pinhole image (same size and intrinsics) of a capture taken through the lens
    ``distortion`` (Brown-Conrady; ``scenenav.core.camera_geometry``): every output pixel samples the
    capture where the lens put it (bilinear). The map is computed once per calibration."""
    h, w = gray.shape[:2]
    key = (w, h, tuple(intrinsics_px), tuple(distortion))
    maps = _UNDISTORT_MAPS.get(key)
    if maps is None:
        fx, fy, cx, cy = intrinsics_px
        u, v = np.meshgrid(np.arange(w, dtype=float) + 0.5, np.arange(h, dtype=float) + 0.5)
        xd, yd = distort_normalized((u - cx) / fx, (v - cy) / fy, distortion)
        maps = ((cx + fx * xd - 0.5).astype(np.float32), (cy + fy * yd - 0.5).astype(np.float32))
        if len(_UNDISTORT_MAPS) >= _UNDISTORT_CACHE_MAX:
            _UNDISTORT_MAPS.clear()
        _UNDISTORT_MAPS[key] = maps
    return cv2.remap(gray, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def ground_to_capture_homography(tilt_rad: tuple[float, float], heading_rad: float, altitude_m: float,
                                 intrinsics_px: tuple[float, float, float, float], map_m_per_px: float,
                                 centre_px: tuple[float, float]) -> np.ndarray:
    """3 x 3 ``H``: template pixel-index (i, j, 1) -> capture pixel-index (homogeneous), for a camera
    fixed to a body at (roll, pitch) = ``tilt_rad``, ``heading_rad`` and ``altitude_m`` above flat
    ground; the template is north-up at ``map_m_per_px`` with the nadir point at ``centre_px``."""
    roll, pitch = tilt_rad
    rows = quat_to_rotation_matrix(quat_from_aviation_euler(roll, pitch, heading_rad))
    right, up, back = (np.asarray(a, dtype=float) for a in fixed_mount_axes(rows))
    fx, fy, cx, cy = intrinsics_px
    # camera pixel-index = (fx (right.d) / z + cx - 0.5, -fy (up.d) / z + cy - 0.5), z = -back.d
    p = np.vstack([fx * right - (cx - 0.5) * back, -fy * up - (cy - 0.5) * back, -back])
    ci, cj = centre_px
    a = np.array([[map_m_per_px, 0.0, -map_m_per_px * ci],     # east offset of template column i
                  [0.0, -map_m_per_px, map_m_per_px * cj],     # north offset of template row j
                  [0.0, 0.0, -altitude_m]])                    # ground 'altitude' below the eye
    return p @ a


def _footprint_in_template(h_inv: np.ndarray, w_src: int, h_src: int) -> np.ndarray:
    """The capture's corners on the ground, as template-pixel offsets from the nadir point."""
    corners = np.array([[-0.5, -0.5, 1.0], [w_src - 0.5, -0.5, 1.0], [w_src - 0.5, h_src - 0.5, 1.0],
                        [-0.5, h_src - 0.5, 1.0]]).T
    g = h_inv @ corners
    if np.any(g[2] * np.sign(g[2, 0]) <= 1e-12) or np.any(np.sign(g[2]) != np.sign(g[2, 0])):
        raise BadInput("camera attitude: an image corner looks above the horizon (tilt too large)")
    return (g[:2] / g[2]).T


def _inscribed_half_side(poly: np.ndarray) -> float:
    """Half side of the largest axis-aligned square centred at the origin inside a convex polygon
    (a square of half side a is inside n.x <= d for all its corners when a (|nx| + |ny|) <= d)."""
    best = math.inf
    n = len(poly)
    area2 = sum(poly[i, 0] * poly[(i + 1) % n, 1] - poly[(i + 1) % n, 0] * poly[i, 1] for i in range(n))
    for i in range(n):
        p0, p1 = poly[i], poly[(i + 1) % n]
        ex, ey = p1 - p0
        nx, ny = (ey, -ex) if area2 > 0 else (-ey, ex)   # outward normal
        norm = math.hypot(nx, ny)
        if norm == 0.0:
            continue
        nx, ny = nx / norm, ny / norm
        d = nx * p0[0] + ny * p0[1]
        best = min(best, d / (abs(nx) + abs(ny)))
    return best


def _check_size(out_w: int, out_h: int, altitude: float, max_template_px: tuple[int, int] | None,
                min_template_px: int | None) -> None:
    if max_template_px is not None and (out_w > max_template_px[0] or out_h > max_template_px[1]):
        raise TemplateTooLarge(f"template {out_w}x{out_h} px at {altitude:.1f} m exceeds "
                               f"{max_template_px[0]}x{max_template_px[1]} px")
    if min_template_px is not None and min(out_w, out_h) < min_template_px:
        raise TemplateTooSmall(min(out_w, out_h), altitude)


def _align_homography(gray: np.ndarray, heading: float, altitude: float, tilt: tuple[float, float],
                      fov: float, mpp: float, crop_mode: CropMode, max_template_px,
                      intrinsics: tuple[float, float, float, float] | None,
                      min_template_px: int | None = None) -> AlignedCapture:
    h_src, w_src = gray.shape
    if intrinsics is None:
        f = focal_length_px(w_src, fov)
        intrinsics = (f, f, 0.5 * w_src, 0.5 * h_src)
    foot = ground_footprint_m(altitude, fov)
    cam_mpp = foot / w_src
    scale = cam_mpp / mpp
    h0 = ground_to_capture_homography(tilt, heading, altitude, intrinsics, mpp, (0.0, 0.0))
    h_inv = np.linalg.inv(h0)
    g = h_inv @ np.array([intrinsics[2] - 0.5, intrinsics[3] - 0.5, 1.0])   # the principal point
    if g[2] == 0.0 or not np.all(np.isfinite(g)):
        raise BadInput("camera attitude: the optical axis does not meet the ground")
    off = (float(g[0] / g[2]), float(g[1] / g[2]))
    poly = _footprint_in_template(h_inv, w_src, h_src) - np.array(off)
    if crop_mode is CropMode.INSCRIBED_SQUARE:
        half = _inscribed_half_side(poly)
        side = max(1, int(math.floor(2.0 * half + 1e-6)))
        out_w = out_h = side
    else:
        out_w = max(1, int(math.ceil(2.0 * float(np.max(np.abs(poly[:, 0]))) - 1e-6)))
        out_h = max(1, int(math.ceil(2.0 * float(np.max(np.abs(poly[:, 1]))) - 1e-6)))
    _check_size(out_w, out_h, altitude, max_template_px, min_template_px)
    hm = ground_to_capture_homography(tilt, heading, altitude, intrinsics, mpp,
                                      ((out_w - 1) / 2.0 - off[0], (out_h - 1) / 2.0 - off[1]))
    src = gray
    if scale < 1.0:
        sigma = 0.5 * math.sqrt(1.0 / (scale * scale) - 1.0)
        if sigma > _MIN_PREBLUR_SIGMA:
            src = cv2.GaussianBlur(gray, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    template = cv2.warpPerspective(src, hm, (out_w, out_h), flags=flags, borderMode=cv2.BORDER_REPLICATE)
    if crop_mode is CropMode.INSCRIBED_SQUARE:
        mask = np.ones(template.shape, dtype=bool)
    else:
        ones = np.ones(gray.shape, dtype=np.uint8)
        mask_u8 = cv2.warpPerspective(ones, hm, (out_w, out_h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        mask_u8 = cv2.erode(mask_u8, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
        mask = mask_u8.astype(bool)
        template[~mask] = 0.0
    return AlignedCapture(template=template, mask=mask, scale=float(scale), camera_m_per_px=float(cam_mpp),
                          footprint_m=float(foot), heading_rad=heading, altitude_m=altitude, gray=gray,
                          centre_offset_px=off)


#: Below this Gaussian sigma (pixels) the anti-aliasing pre-blur is skipped.
_MIN_PREBLUR_SIGMA = 0.3


def align_capture(image: np.ndarray, heading_rad: float, altitude_m: float, fov_deg: float,
                  map_m_per_px: float, crop_mode: CropMode = CropMode.INSCRIBED_SQUARE,
                  max_template_px: tuple[int, int] | None = None, *,
                  tilt_rad: tuple[float, float] | None = None,
                  intrinsics_px: tuple[float, float, float, float] | None = None,
                  distortion: Distortion = NO_DISTORTION,
                  min_template_px: int | None = None) -> AlignedCapture:
    """Grey, rotate north-up and scale a capture to the map resolution with one warpAffine.

    ``tilt_rad`` = (roll, pitch) of the body a FIXED camera is mounted on (the autopilot's estimate):
    align with the ground homography instead (module docstring). ``distortion`` (with the frame's
    ``intrinsics_px``; None: from ``fov_deg``, principal point at the centre): undistort first.

    ``crop_mode`` INSCRIBED_SQUARE (default) returns the largest axis-aligned square inside the
    rotated image, side ``scale * min(W, H) / (|cos h| + |sin h|)`` (the full image at multiples of
    90 degrees, 1/sqrt(2) of it at 45 degrees) and an all-True mask; MASKED_BOUNDS returns the whole
    rotated image's bounding box with a mask of valid pixels (eroded by one pixel).
    Raises BadInput for a bad image, a non-finite heading, or an altitude that is not > 0, and
    TemplateTooLarge (before any resampling) when the template would be wider or taller than
    ``max_template_px`` = (width, height), e.g. the reference map's size, and TemplateTooSmall (also
    before any resampling) when its smaller side would be below ``min_template_px`` (None: no limit).
    """
    heading = finite_number("heading_rad", heading_rad)
    altitude = finite_number("altitude_m", altitude_m)
    if altitude <= 0.0:
        raise BadInput(f"altitude_m = {altitude_m!r}: expected > 0 (metres above ground)")
    fov = finite_number("fov_deg", fov_deg)
    if not 0.0 < fov < 180.0:
        raise BadInput(f"fov_deg = {fov_deg!r}: expected a number in (0, 180)")
    mpp = finite_number("map_m_per_px", map_m_per_px)
    if mpp <= 0.0:
        raise BadInput(f"map_m_per_px = {map_m_per_px!r}: expected > 0")

    gray = to_gray_float32(image)
    if tuple(distortion) != NO_DISTORTION:
        if intrinsics_px is None:
            f = focal_length_px(gray.shape[1], fov)
            intrinsics_px = (f, f, 0.5 * gray.shape[1], 0.5 * gray.shape[0])
        gray = undistort(gray, intrinsics_px, distortion)
    if tilt_rad is not None:
        tilt = (finite_number("roll_rad", tilt_rad[0]), finite_number("pitch_rad", tilt_rad[1]))
        return _align_homography(gray, heading, altitude, tilt, fov, mpp, crop_mode, max_template_px,
                                 intrinsics_px, min_template_px)
    h_src, w_src = gray.shape
    foot = ground_footprint_m(altitude, fov)
    cam_mpp = foot / w_src
    scale = cam_mpp / mpp
    c, s = math.cos(heading), math.sin(heading)
    ac, as_ = abs(c), abs(s)

    if crop_mode is CropMode.INSCRIBED_SQUARE:
        side = max(1, int(math.floor(scale * min(w_src, h_src) / (ac + as_) + 1e-6)))
        out_w = out_h = side
    else:
        out_w = max(1, int(math.ceil(scale * (w_src * ac + h_src * as_) - 1e-6)))
        out_h = max(1, int(math.ceil(scale * (w_src * as_ + h_src * ac) - 1e-6)))

    _check_size(out_w, out_h, altitude, max_template_px, min_template_px)

    # dst = A (src - c_src) + c_dst in pixel-index coordinates (pixel centres on integers).
    a = np.array([[c, -s], [s, c]]) * scale
    c_src = np.array([(w_src - 1) / 2.0, (h_src - 1) / 2.0])
    c_dst = np.array([(out_w - 1) / 2.0, (out_h - 1) / 2.0])
    m = np.hstack([a, (c_dst - a @ c_src)[:, None]])

    src = gray
    if scale < 1.0:
        # Anti-alias before shrinking: blur to the target sampling (bilinear alone would alias).
        sigma = 0.5 * math.sqrt(1.0 / (scale * scale) - 1.0)
        if sigma > _MIN_PREBLUR_SIGMA:
            src = cv2.GaussianBlur(gray, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)

    template = cv2.warpAffine(src, m, (out_w, out_h), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
    if crop_mode is CropMode.INSCRIBED_SQUARE:
        mask = np.ones(template.shape, dtype=bool)
    else:
        ones = np.ones(gray.shape, dtype=np.uint8)
        mask_u8 = cv2.warpAffine(ones, m, (out_w, out_h), flags=cv2.INTER_NEAREST,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        mask_u8 = cv2.erode(mask_u8, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                            borderValue=0)
        mask = mask_u8.astype(bool)
        template[~mask] = 0.0
    return AlignedCapture(template=template, mask=mask, scale=float(scale),
                          camera_m_per_px=float(cam_mpp), footprint_m=float(foot),
                          heading_rad=heading, altitude_m=altitude, gray=gray)
