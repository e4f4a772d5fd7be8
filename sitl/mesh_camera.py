"""Downward camera: renders the orthophoto lying on the ground with pybullet's TinyRenderer.

Ground model (world conventions of scenenav/core/frames.py: origin = map centre, x east, y north, pixel
row 0 = north edge). Only a *ground window* of ``ground_window_px`` x ``ground_window_px`` texels is
ever uploaded, whatever the map size, so the per-frame cost does not depend on the map:

* the window is one textured quad (``createVisualShape(GEOM_MESH, vertices, indices, uvs, normals)``)
  covering ``N * L`` x ``N * L`` map pixels, where N = ``ground_window_px`` and L (1, 2, 4, ...) is the
  level of detail: each texel is the mean of an L x L block of map pixels. L follows the altitude so
  that a texel is about one image pixel (between 1/2.5 and 1.25 image pixels), which is also what a
  real camera integrates; L = 1 (full map resolution) whenever the image is finer than the map;
* texels of the window that fall outside the map are plain grey (``outside_grey_level``), and a grey
  frame surrounds the window (seen only by a tilted FIXED camera);
* before every render the camera footprint (ground intersection of the image corners) is checked
  against the window; when it comes within a margin of the edge (or L must change) the window is
  re-centred on the footprint, snapped to whole map pixels (multiples of L), and rebuilt.

Rebuild = a fresh private DIRECT client with the two ground bodies and the window texture written to a
temporary BMP and loaded with ``loadTexture``. The private client is deliberate: in DIRECT mode
TinyRenderer ignores ``changeTexture`` (verified with pybullet 3.2.7: the rendered image does not
change), and every ``loadTexture`` keeps its pixels until the client disconnects (``resetSimulation``
does not free them), so re-centring inside a long-lived client would leak ~40 MB per re-centre at
N = 2048. A private client also keeps the vehicle's own body out of its nadir images.

Camera model: ideal pinhole, ``fov_deg`` across the image width (and the height for a square image),
square pixels, principal point at the image centre, optical centre at the vehicle position. Image
top = body forward, image right = body right. GIMBAL mount: optical axis straight down and image
rotated by the body heading only; FIXED mount: optical axis along body -z (full attitude). At
heading 0, level, the image is the north-up crop under the vehicle with footprint width
2 h tan(fov/2). Lighting is ambient-only (ambient 1, diffuse 0, specular 0, no shadows), so rendered
colours are the texel colours. TinyRenderer samples the nearest texel at a pixel *corner*; the
projection matrix shifts the principal point by half a pixel so that pixels sample their centres
(checked to 1/50 pixel with a coded texture).

Camera effects (gain, blur, noise; ``sitl.sensors.CameraEffects``) are applied by ``render`` when the
camera is given an ``rng``; without one ``render`` returns the ideal image.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
import weakref
from dataclasses import dataclass

import cv2
import numpy as np
import pybullet as p

from sitl.config import CameraConfig, CameraMount
from sitl.dynamics import rotation_rows
from sitl.sensors import CameraEffects

logger = logging.getLogger(__name__)

# Lowest optical-centre height rendered (a landed vehicle's camera is about this high).
_MIN_HEIGHT_M = 0.3
# Clip planes: the ground is a single surface, so depth precision is irrelevant; the near plane
# stays below the lowest camera, the far plane beyond the grey frame seen by a tilted FIXED camera.
_NEAR_M = 0.1
_FAR_M = 30000.0
# A tilted FIXED camera sees ground up to the horizon: its footprint is clipped at this many heights.
_MAX_RANGE_HEIGHTS = 6.0
# Extent of the grey frame around the window, beyond the window edge, m.
_FRAME_MARGIN_M = 10000.0
# Level-of-detail hysteresis, in map pixels per image pixel over L.
_LOD_TOO_FINE = 2.5
_LOD_TOO_COARSE = 0.8


@dataclass(frozen=True)
class GroundWindow:
    """Placement of the textured window: top-left map pixel (col, row), texels per side, texel size."""

    col0_px: int
    row0_px: int
    size_texels: int
    lod: int            # map pixels per texel side

    @property
    def span_px(self) -> int:
        return self.size_texels * self.lod


def _pow2_floor(x: float) -> int:
    return 1 << max(0, int(math.floor(math.log2(max(x, 1.0)))))


def _pow2_ceil(x: float) -> int:
    return 1 << max(0, int(math.ceil(math.log2(max(x, 1.0)))))


class GroundCamera:
    """Renders (h, w, 3) uint8 RGB images of the orthophoto from a vehicle pose.

    Args:
        client_id: the simulator's physics client. Kept for the node's API; the ground is drawn in a
            private DIRECT client owned by the camera (see the module docstring for why).
        orthophoto_rgb: (H, W, 3) uint8 map, row 0 = north edge; kept by reference, not copied.
        m_per_px: ground size of one map pixel, m.
        cfg: camera configuration.
        rng: when given, ``render`` applies ``CameraEffects(cfg, rng)``; otherwise images are ideal.
    """

    def __init__(self, client_id: int, orthophoto_rgb: np.ndarray, m_per_px: float, cfg: CameraConfig,
                 rng: np.random.Generator | None = None) -> None:
        ortho = np.asarray(orthophoto_rgb)
        if ortho.ndim == 2:
            ortho = np.repeat(ortho[:, :, None], 3, axis=2)
        if ortho.ndim != 3 or ortho.shape[2] != 3 or ortho.dtype != np.uint8 or min(ortho.shape[:2]) < 1:
            raise ValueError(f"orthophoto: shape {ortho.shape} dtype {ortho.dtype}: expected (H, W, 3) uint8")
        if not (m_per_px > 0.0 and math.isfinite(m_per_px)):
            raise ValueError(f"m_per_px = {m_per_px}: expected a number > 0")
        self.physics_client_id = client_id
        self.cfg = cfg
        self.m_per_px = float(m_per_px)
        self._map = ortho
        self._map_h, self._map_w = ortho.shape[:2]
        self.effects = CameraEffects(cfg, rng) if rng is not None else None
        self.window: GroundWindow | None = None
        self.window_builds = 0
        self._render_client = -1
        self._closed = False
        self._tmpdir = tempfile.mkdtemp(prefix="scenenav-ground-")
        self._client_box = [-1]      # the render client id, shared with the finalizer
        self._finalizer = weakref.finalize(self, _cleanup, self._tmpdir, self._client_box)
        self._tan_x = math.tan(math.radians(cfg.fov_deg) / 2.0)
        self._tan_y = self._tan_x * cfg.height_px / cfg.width_px
        self._projection = self._projection_matrix()
        self._margin_texels = max(2, cfg.ground_window_px // 32)

    # ------------------------------------------------------------------ public
    def render(self, position_enu_m: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
        """(height_px, width_px, 3) uint8 RGB image seen from the vehicle pose (ENU m, body->ENU quat)."""
        image = self.render_ideal(position_enu_m, q_wxyz)
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
        eye = (x, y, max(z, _MIN_HEIGHT_M))
        right, up, back = self._camera_axes(q_wxyz)
        self._ensure_window(eye, right, up, back)
        view = self._view_matrix(eye, right, up, back)
        cfg = self.cfg
        out = p.getCameraImage(cfg.width_px, cfg.height_px, view, self._projection,
                               lightAmbientCoeff=1.0, lightDiffuseCoeff=0.0, lightSpecularCoeff=0.0,
                               shadow=0, flags=p.ER_NO_SEGMENTATION_MASK, renderer=p.ER_TINY_RENDERER,
                               physicsClientId=self._render_client)
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(cfg.height_px, cfg.width_px, 4)
        return np.ascontiguousarray(rgba[:, :, :3])

    def footprint_m(self, height_m: float) -> tuple[float, float]:
        """Ground size (width, height) in metres of a nadir image taken ``height_m`` above the ground."""
        h = max(height_m, _MIN_HEIGHT_M)
        return 2.0 * h * self._tan_x, 2.0 * h * self._tan_y

    def close(self) -> None:
        """Disconnect the private render client and remove the temporary directory (idempotent)."""
        self._finalizer()
        self._render_client = -1
        self._closed = True

    def __enter__(self) -> "GroundCamera":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # ------------------------------------------------------------------ geometry
    def _camera_axes(self, q_wxyz: np.ndarray) -> tuple[tuple[float, float, float], ...]:
        """World directions of the image right, image up, and the camera back (-optical axis)."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rotation_rows(q_wxyz)
        if self.cfg.mount is CameraMount.FIXED:
            # Image right = body -y, image up = body +x, back = body +z.
            return (-r01, -r11, -r21), (r00, r10, r20), (r02, r12, r22)
        # GIMBAL: nadir; image up = body +x projected on the ground. With body +x vertical (pitch
        # +-90 deg) the nose has no heading: use the body z axis, which then points forward (nose
        # down) or backward (nose up).
        fx, fy = r00, r10
        if fx * fx + fy * fy < 1e-12:
            fx, fy = -r20 * r02, -r20 * r12
        yaw = math.atan2(fy, fx)
        c, s = math.cos(yaw), math.sin(yaw)
        return (s, -c, 0.0), (c, s, 0.0), (0.0, 0.0, 1.0)

    @staticmethod
    def _view_matrix(eye, right, up, back) -> list[float]:
        """OpenGL view matrix (world -> camera), column-major as pybullet expects."""
        tr = -(right[0] * eye[0] + right[1] * eye[1] + right[2] * eye[2])
        tu = -(up[0] * eye[0] + up[1] * eye[1] + up[2] * eye[2])
        tb = -(back[0] * eye[0] + back[1] * eye[1] + back[2] * eye[2])
        return [right[0], up[0], back[0], 0.0,
                right[1], up[1], back[1], 0.0,
                right[2], up[2], back[2], 0.0,
                tr, tu, tb, 1.0]

    def _projection_matrix(self) -> list[float]:
        """OpenGL perspective projection, column-major, principal point at the image centre.

        TinyRenderer rasterises pixel (i, j) at the integer viewport point (i, j), i.e. at a pixel
        corner, not its centre: the image would be shifted by half a pixel (measured). The third
        column shifts NDC by -1/w and -1/h so that every pixel samples the ray through its centre.
        """
        n, f = _NEAR_M, _FAR_M
        return [1.0 / self._tan_x, 0.0, 0.0, 0.0,
                0.0, 1.0 / self._tan_y, 0.0, 0.0,
                1.0 / self.cfg.width_px, 1.0 / self.cfg.height_px, (f + n) / (n - f), -1.0,
                0.0, 0.0, 2.0 * f * n / (n - f), 0.0]

    def _footprint(self, eye, right, up, back) -> tuple[float, float, float, float, float]:
        """(u_min, u_max, v_min, v_max, map px per image px) of the ground seen, map pixel coordinates."""
        h = eye[2]
        max_range = _MAX_RANGE_HEIGHTS * h
        xs, ys = [], []
        centre_range = h
        for a, b in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0), (0.0, 0.0)):
            ax, by = a * self._tan_x, b * self._tan_y
            d = (-back[0] + ax * right[0] + by * up[0],
                 -back[1] + ax * right[1] + by * up[1],
                 -back[2] + ax * right[2] + by * up[2])
            horiz = math.hypot(d[0], d[1])
            if d[2] < 0.0 and horiz * h <= -d[2] * max_range:
                t = h / -d[2]
                gx, gy = d[0] * t, d[1] * t
                dist = math.sqrt(gx * gx + gy * gy + h * h)
            elif horiz > 0.0:       # toward or above the horizon: clip at the maximum range
                gx, gy = d[0] / horiz * max_range, d[1] / horiz * max_range
                dist = math.hypot(max_range, h)
            else:
                gx = gy = 0.0
                dist = h
            if a == 0.0 and b == 0.0:
                centre_range = dist
            xs.append(eye[0] + gx)
            ys.append(eye[1] + gy)
        m = self.m_per_px
        u = [x / m + self._map_w / 2.0 for x in xs]
        v = [self._map_h / 2.0 - y / m for y in ys]
        # Ground sampling along the optical axis, in map pixels per image pixel.
        ratio = 2.0 * centre_range * self._tan_x / m / self.cfg.width_px
        return min(u), max(u), min(v), max(v), ratio

    # ------------------------------------------------------------------ ground window
    def _ensure_window(self, eye, right, up, back) -> None:
        u0, u1, v0, v1, ratio = self._footprint(eye, right, up, back)
        n = self.cfg.ground_window_px
        extent = max(u1 - u0, v1 - v0)
        lod_fit = _pow2_ceil(extent / (0.5 * n))
        win = self.window
        if win is not None:
            lod = win.lod
            margin = self._margin_texels * lod
            inside = (u0 >= win.col0_px + margin and u1 <= win.col0_px + win.span_px - margin
                      and v0 >= win.row0_px + margin and v1 <= win.row0_px + win.span_px - margin)
            too_fine = ratio >= _LOD_TOO_FINE * lod
            too_coarse = lod > 1 and lod > lod_fit and ratio < _LOD_TOO_COARSE * lod
            if inside and not too_fine and not too_coarse:
                return
        lod = max(_pow2_floor(ratio), lod_fit)
        span = n * lod
        margin = self._margin_texels * lod
        col0 = self._place_axis(u0, u1, self._map_w, span, lod, margin)
        row0 = self._place_axis(v0, v1, self._map_h, span, lod, margin)
        self._build(GroundWindow(col0, row0, n, lod))

    @staticmethod
    def _place_axis(lo: float, hi: float, map_size: int, span: int, lod: int, margin: int) -> int:
        """First map pixel of the window along one axis (a multiple of ``lod``).

        Centred on the map when that still holds the footprint (a map smaller than the window then
        never needs another re-centre along this axis), otherwise centred on the footprint.
        """
        on_map = lod * int(round((map_size - span) / 2.0 / lod))
        if lo >= on_map + margin and hi <= on_map + span - margin:
            return on_map
        return lod * int(round(((lo + hi) / 2.0 - span / 2.0) / lod))

    def _window_texture(self, win: GroundWindow) -> np.ndarray:
        """(N, N, 3) uint8 texels of the window: block means of the map, grey outside it."""
        n, lod, span = win.size_texels, win.lod, win.span_px
        tex = np.full((n, n, 3), self.cfg.outside_grey_level, dtype=np.uint8)
        c_lo, c_hi = max(win.col0_px, 0), min(win.col0_px + span, self._map_w)
        r_lo, r_hi = max(win.row0_px, 0), min(win.row0_px + span, self._map_h)
        if c_hi <= c_lo or r_hi <= r_lo:
            return tex
        crop = self._map[r_lo:r_hi, c_lo:c_hi]
        # Texel index range covered (col0/row0 are multiples of lod, so the first block is whole).
        i0 = (c_lo - win.col0_px) // lod
        j0 = (r_lo - win.row0_px) // lod
        i1 = -(-(c_hi - win.col0_px) // lod)
        j1 = -(-(r_hi - win.row0_px) // lod)
        if lod > 1:
            need_w, need_h = (i1 - i0) * lod, (j1 - j0) * lod
            if crop.shape[1] != need_w or crop.shape[0] != need_h:
                padded = np.full((need_h, need_w, 3), self.cfg.outside_grey_level, dtype=np.uint8)
                padded[:crop.shape[0], :crop.shape[1]] = crop
                crop = padded
            crop = cv2.resize(crop, (i1 - i0, j1 - j0), interpolation=cv2.INTER_AREA)
        tex[j0:j1, i0:i1] = crop
        return tex

    def _build(self, win: GroundWindow) -> None:
        """Rebuild the ground scene around ``win`` in a fresh private client."""
        tex = self._window_texture(win)
        self._disconnect()
        cid = p.connect(p.DIRECT)
        if cid < 0:
            raise RuntimeError("pybullet: cannot open a DIRECT client for the camera")
        self._render_client = cid
        self._client_box[0] = cid
        m = self.m_per_px
        half = 0.5 * win.span_px * m
        centre_x = (win.col0_px + 0.5 * win.span_px - 0.5 * self._map_w) * m
        centre_y = (0.5 * self._map_h - win.row0_px - 0.5 * win.span_px) * m
        up_normal = [0.0, 0.0, 1.0]
        # Window quad, counter-clockwise seen from above: SW, SE, NE, NW. TinyRenderer stores loaded
        # images bottom row first, so v = 0 is the south (last) texel row and v = 1 the north (first).
        quad = p.createVisualShape(
            p.GEOM_MESH, vertices=[[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]],
            indices=[0, 1, 2, 0, 2, 3], uvs=[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            normals=[up_normal] * 4, physicsClientId=cid)
        window_body = p.createMultiBody(0.0, -1, quad, [centre_x, centre_y, 0.0], physicsClientId=cid)
        path = os.path.join(self._tmpdir, f"window_{self.window_builds:06d}.bmp")
        if not cv2.imwrite(path, tex[:, :, ::-1]):
            raise RuntimeError(f"{path}: cannot write the ground-window texture")
        try:
            texture = p.loadTexture(path, physicsClientId=cid)
        finally:
            os.remove(path)
        p.changeVisualShape(window_body, -1, textureUniqueId=texture, rgbaColor=[1.0, 1.0, 1.0, 1.0],
                            physicsClientId=cid)
        # Grey frame around the window (a square annulus), drawn after the window.
        outer = half + _FRAME_MARGIN_M
        grey = self.cfg.outside_grey_level / 255.0
        frame = p.createVisualShape(
            p.GEOM_MESH,
            vertices=[[-outer, -outer, 0.0], [outer, -outer, 0.0], [outer, outer, 0.0], [-outer, outer, 0.0],
                      [-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]],
            indices=[0, 1, 5, 0, 5, 4, 1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7],
            uvs=[[0.0, 0.0]] * 8, normals=[up_normal] * 8, rgbaColor=[grey, grey, grey, 1.0],
            physicsClientId=cid)
        frame_body = p.createMultiBody(0.0, -1, frame, [centre_x, centre_y, 0.0], physicsClientId=cid)
        p.changeVisualShape(frame_body, -1, rgbaColor=[grey, grey, grey, 1.0], physicsClientId=cid)
        self.window = win
        self.window_builds += 1
        logger.debug("ground window %d: map px (%d, %d), %d texels x L%d", self.window_builds,
                     win.col0_px, win.row0_px, win.size_texels, win.lod)

    def _disconnect(self) -> None:
        if self._render_client >= 0:
            _disconnect_quietly(self._render_client)
            self._render_client = -1
            self._client_box[0] = -1


def _disconnect_quietly(client_id: int) -> None:
    try:
        p.disconnect(physicsClientId=client_id)
    except p.error as exc:      # already disconnected
        logger.debug("pybullet disconnect %d: %s", client_id, exc)


def _cleanup(tmpdir: str, client_box: list[int]) -> None:
    if client_box[0] >= 0:
        _disconnect_quietly(client_box[0])
        client_box[0] = -1
    shutil.rmtree(tmpdir, ignore_errors=True)
