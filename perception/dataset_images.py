"""Rendering of dataset images: a rotated, scaled, mirrored crop of a world, and its photometry.

See ``perception.dataset`` (Augmentation) for the recipe.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

from perception.dataset_config import AugmentRecipe
from perception.dataset_samples import BaseSample

if TYPE_CHECKING:
    from perception.capture import CaptureScene

log = logging.getLogger(__name__)


def render_crop(gray: np.ndarray, u: float, v: float, crop_px: int, out_px: int, angle_rad: float = 0.0,
                scale: float = 1.0, flip: bool = False) -> np.ndarray:
    """Square crop of side ``crop_px * scale`` centred on continuous (u, v), rotated by ``angle_rad``,
    optionally mirrored, resampled to ``out_px`` x ``out_px`` (one bilinear warp; reflecting border)."""
    g = crop_px * scale / out_px
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    a = g * np.array([[c, -s], [s, c]])
    if flip:
        a = a @ np.array([[-1.0, 0.0], [0.0, 1.0]])
    c_out = np.array([(out_px - 1) / 2.0, (out_px - 1) / 2.0])
    c_src = np.array([u - 0.5, v - 0.5])
    m = np.hstack([a, (c_src - a @ c_out)[:, None]])
    src = gray
    if g > 1.3:  # anti-alias a real downscale
        src = cv2.GaussianBlur(gray, (0, 0), 0.5 * math.sqrt(g * g - 1.0), borderType=cv2.BORDER_REFLECT_101)
    return cv2.warpAffine(src, m, (out_px, out_px), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT_101)


def augment_image(scene: CaptureScene, sample: BaseSample, crop_px: int, out_px: int,
                  recipe: AugmentRecipe, rng: np.random.Generator,
                  fov_deg: float = 60.0) -> tuple[np.ndarray, dict]:
    """One augmented copy of a base crop, re-rendered from the world's capture scene (with relief
    when it has a DSM, ``CaptureScene.footprint_image``); returns (image, parameters)."""
    angle = math.radians(rng.uniform(*recipe.rotation_deg))
    flip = bool(rng.random() < recipe.flip_probability)
    scale = rng.uniform(*recipe.scale)
    img = scene.footprint_image(sample.u_px, sample.v_px, crop_px, out_px, fov_deg, angle, scale, flip)
    img = apply_photometry(img, rng, recipe)
    return img, {"rotation_deg": math.degrees(angle), "flip": flip, "scale": scale}


def apply_photometry(img: np.ndarray, rng: np.random.Generator, recipe: AugmentRecipe) -> np.ndarray:
    """Gamma, gain/offset, blur and additive noise on a float image in [0, 1]."""
    gamma = math.exp(rng.uniform(*recipe.log_gamma))
    out = np.power(np.clip(img, 0.0, 1.0), gamma).astype(np.float32)
    out = out * np.float32(rng.uniform(*recipe.gain)) + np.float32(rng.uniform(*recipe.offset))
    sigma = rng.uniform(*recipe.blur_sigma_px)
    if sigma > 0.2:
        out = cv2.GaussianBlur(out, (0, 0), sigma, borderType=cv2.BORDER_REFLECT_101)
    noise = rng.uniform(*recipe.noise_sigma)
    if noise > 0.0:
        out = out + rng.normal(0.0, noise, out.shape).astype(np.float32)
    return np.clip(out, 0.0, 1.0).astype(np.float32)
