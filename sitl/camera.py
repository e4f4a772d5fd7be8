"""The simulator's downward camera: the 3-D city seen from the vehicle pose.

A thin shell over ``worlds.view_renderer.CityRenderer`` (the height-field ray caster; read its module
docstring for the image model): this module adds the mount, the lowest rendered height and the camera
effects. With ``CameraConfig.relief`` (default) the world's DSM and facade colours are rendered; with
``relief: false``, or on a flat world, the ground is flat and the image is exactly what the previous
TinyRenderer camera (now ``sitl.mesh_camera.MeshCamera``, the reference renderer) gave.

Camera model: ideal pinhole, ``fov_deg`` across the image width (and the height for a square image),
square pixels, principal point at the image centre, optical centre at the vehicle position. Image top =
body forward, image right = body right. GIMBAL mount: optical axis straight down and image rotated by
the body heading only; FIXED mount: optical axis along body -z (full attitude). At heading 0, level,
the image is the north-up crop under the vehicle with footprint width 2 h tan(fov/2). Colours are the
texel colours (roofs and ground) and the shaded facades (walls).

Camera effects (gain, blur, noise; ``sitl.sensors.CameraEffects``) are applied by ``render`` when the
camera is given an ``rng``; without one ``render`` returns the ideal image. The camera and mount
realism (``sitl.camera_model``: capture jitter, gimbal model, motion blur, lens distortion,
auto-exposure) is applied by ``render_capture`` when the camera is given an ``optics_rng``.
"""

from __future__ import annotations

import math

import numpy as np

from sitl.camera_model import CameraOptics, camera_axes
from sitl.config import CameraConfig
from sitl.sensors import CameraEffects
from worlds.ground_window import GroundWindow
from worlds.view_renderer import CityRenderer

# Lowest optical-centre height rendered (a landed vehicle's camera is about this high).
MIN_HEIGHT_M = 0.3

def warm_up() -> None:
    """Load (or compile once) the renderer's numba kernels by rendering throwaway frames of a tiny flat
    and a tiny relief world; the kernels' types do not depend on the map, so the real camera's first
    frame then costs what any frame does. Touches no camera's state."""
    top = np.zeros((16, 16, 3), np.uint8)
    heights = np.zeros((16, 16), np.float32)
    heights[4:8, 4:8] = 5.0
    cfg = CameraConfig(width_px=8, height_px=8, ground_window_px=64)
    for h in (None, heights):
        for facade in (None, top):
            GroundCamera(-1, top, 1.0, cfg, heights_m=h, facade_rgb=facade).render_ideal(
                np.array([0.0, 0.0, 20.0]), np.array([1.0, 0.0, 0.0, 0.0]))


class GroundCamera:
    """Renders (h, w, 3) uint8 RGB images of the world from a vehicle pose.

    Args:
        client_id: the simulator's physics client; unused (kept for the node's API).
        orthophoto_rgb: (H, W, 3) uint8 map, row 0 = north edge; kept by reference, not copied.
        m_per_px: ground size of one map pixel, m.
        cfg: camera configuration.
        rng: when given, ``render`` applies ``CameraEffects(cfg, rng)``; otherwise images are ideal.
        optics_rng: when given and ``cfg.optics_enabled``, ``render_capture`` applies the camera and
            mount realism of ``sitl.camera_model.CameraOptics`` (jitter, gimbal, blur, lens, exposure).
        heights_m: the world's DSM (``World.dsm_m``), None = flat; ignored when ``cfg.relief`` is False.
        facade_rgb: the world's wall colours (``World.facade_rgb``) or None.
    """

    def __init__(self, client_id: int, orthophoto_rgb: np.ndarray, m_per_px: float, cfg: CameraConfig,
                 rng: np.random.Generator | None = None, heights_m: np.ndarray | None = None,
                 facade_rgb: np.ndarray | None = None, optics_rng: np.random.Generator | None = None) -> None:
        self.physics_client_id = client_id
        self.cfg = cfg
        self.m_per_px = float(m_per_px)
        relief = cfg.relief and heights_m is not None
        self.renderer = CityRenderer(orthophoto_rgb, m_per_px, heights_m if relief else None,
                                     facade_rgb if relief else None, outside_grey_level=cfg.outside_grey_level,
                                     ground_window_px=cfg.ground_window_px)
        self.effects = CameraEffects(cfg, rng) if rng is not None else None
        self.optics = (CameraOptics(cfg, optics_rng, MIN_HEIGHT_M)
                       if optics_rng is not None and cfg.optics_enabled else None)
        self._tan_x = math.tan(math.radians(cfg.fov_deg) / 2.0)
        self._tan_y = self._tan_x * cfg.height_px / cfg.width_px
        self._tracker = self.renderer.tracker(cfg.width_px, cfg.height_px, self._tan_x, self._tan_y)
        self._closed = False

    @property
    def window(self) -> GroundWindow | None:
        """The current ground window (``worlds.ground_window``)."""
        return self._tracker.window

    @property
    def window_builds(self) -> int:
        return self._tracker.builds

    def render(self, position_enu_m: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
        """(height_px, width_px, 3) uint8 RGB image seen from the vehicle pose (ENU m, body->ENU quat)."""
        image = self.render_ideal(position_enu_m, q_wxyz)
        if self.effects is not None:
            image = self.effects.apply(image)
        return image

    def render_capture(self, capture_s: float, position_enu_m: np.ndarray, q_wxyz: np.ndarray,
                       velocity_enu_m_s=(0.0, 0.0, 0.0), body_rates_flu_rad_s=(0.0, 0.0, 0.0)) -> np.ndarray:
        """``render`` of a capture at simulated time ``capture_s`` with the truth velocity and body rates
        of that instant: through ``CameraOptics`` when the camera has one, else exactly ``render``."""
        if self.optics is None:
            return self.render(position_enu_m, q_wxyz)
        if self._closed:
            raise RuntimeError("GroundCamera.render after close()")
        image = self.optics.capture(self.renderer.render, capture_s, position_enu_m, q_wxyz,
                                    velocity_enu_m_s, body_rates_flu_rad_s)
        if self.effects is not None:
            image = self.effects.apply(image)
        return image

    def render_ideal(self, position_enu_m: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
        """The image without camera effects."""
        if self._closed:
            raise RuntimeError("GroundCamera.render after close()")
        x, y, z = (float(c) for c in position_enu_m)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise ValueError(f"camera position {position_enu_m!r}: expected finite ENU metres")
        eye = (x, y, max(z, MIN_HEIGHT_M))
        right, up, back = camera_axes(q_wxyz, self.cfg.mount)
        cfg = self.cfg
        return self.renderer.render(eye, right, up, back, cfg.width_px, cfg.height_px, self._tan_x, self._tan_y)

    def footprint_m(self, height_m: float) -> tuple[float, float]:
        """Ground size (width, height) in metres of a nadir image taken ``height_m`` above the ground."""
        h = max(height_m, MIN_HEIGHT_M)
        return 2.0 * h * self._tan_x, 2.0 * h * self._tan_y

    def close(self) -> None:
        """Nothing to release but the renderer's buffers (idempotent); ``render`` afterwards raises."""
        self._closed = True

    def __enter__(self) -> "GroundCamera":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
