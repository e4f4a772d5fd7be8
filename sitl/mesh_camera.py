"""The independent reference renderer: the ground and the DSM as pybullet meshes drawn by TinyRenderer.

This was the simulator's camera until the 3-D city (issue 11); ``sitl.camera.GroundCamera`` now renders
with ``worlds.view_renderer.CityRenderer`` (a height-field ray caster) and this module is what that
renderer is checked against (``tests/unit/worlds/test_view_renderer.py``, ``scenenav bench render``).
It shares nothing with the ray caster but the ground-window placement (``worlds.ground_window``, so
both draw the same texels) and the camera matrices.

Ground model (world conventions of scenenav/core/frames.py): the ground window of
``ground_window_px`` x ``ground_window_px`` texels at level of detail L (``worlds.ground_window``) is one
textured quad (``createVisualShape(GEOM_MESH, vertices, indices, uvs, normals)``) with a grey frame
around it; texels outside the map are grey.

Relief: when given heights, every run of equal-height raised pixels in a map row becomes a box (top
and four walls, no bottom), for the map pixels inside the ground window; all boxes are one mesh
textured with a small palette image, each face's uvs at the centre of its palette texel so that it is
drawn in one flat colour. ``box_colours="shaded"``: roofs the mean orthophoto colour of the run, walls
the facade colour (or the darkened roof colour) times the per-face light of ``worlds.raycast``
(no window pattern); ``box_colours="labels"``: label colours (``label_colour``) that identify the face
and the run exactly, for pixel-exact comparisons.

Rebuild = a fresh private DIRECT client with the bodies and the window texture written to a temporary
BMP and loaded with ``loadTexture``. The private client is deliberate: in DIRECT mode TinyRenderer
ignores ``changeTexture`` (verified with pybullet 3.2.7: the rendered image does not change), and every
``loadTexture`` keeps its pixels until the client disconnects (``resetSimulation`` does not free them),
so re-centring inside a long-lived client would leak ~40 MB per re-centre at N = 2048.

Camera model: ideal pinhole, ``fov_deg`` across the image width, square pixels, principal point at the
image centre (``worlds.view_renderer.projection_matrix``: TinyRenderer samples at a pixel corner, the
projection shifts the principal point by half a pixel so that pixels sample their centres).
Lighting is ambient-only (ambient 1, diffuse 0, specular 0, no shadows), so rendered colours are the
texel colours. It costs ~8 ms a frame on the flat world, far more with many boxes.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
import weakref

import cv2
import numpy as np
import pybullet as p

from sitl.camera import MIN_HEIGHT_M, camera_axes
from sitl.config import CameraConfig
from worlds.ground_window import GroundWindow, WindowTracker
from worlds.raycast import FACE_LIGHT, NO_FACADE_FACTOR, WallFace
from worlds.view_renderer import projection_matrix, view_matrix, window_meshes

logger = logging.getLogger(__name__)

# Label colours (box_colours="labels"): red channel = the face class, green/blue = the run index.
LABEL_ROOF = 200
LABEL_WALL = {WallFace.EAST: 210, WallFace.WEST: 220, WallFace.NORTH: 230, WallFace.SOUTH: 240}
# TinyRenderer limits the vertices of one createVisualShape mesh; boxes are split in chunks of this.
_MAX_BOX_VERTICES = 40000


def label_colour(face_class: int, run_index: int) -> tuple[int, int, int]:
    """The label colour of a face: class (``LABEL_ROOF`` or ``LABEL_WALL[face]``) and run index."""
    return face_class, run_index % 256, (run_index // 256) % 256


def height_runs(heights_m: np.ndarray, col_lo: int, col_hi: int, row_lo: int, row_hi: int) -> np.ndarray:
    """Runs of equal-height raised pixels in each row of the map window [row_lo, row_hi) x [col_lo, col_hi).

    Returns (runs, heights): (K, 3) int64 rows of (row, first col, last col + 1) and their (K,) heights;
    a run's index is its position in the arrays.
    """
    runs = []
    hts = []
    for r in range(row_lo, row_hi):
        row = heights_m[r, col_lo:col_hi]
        change = np.flatnonzero(np.diff(row) != 0) + 1
        starts = np.concatenate(([0], change))
        ends = np.concatenate((change, [row.shape[0]]))
        for a, b in zip(starts, ends, strict=True):
            if row[a] > 0.0:
                runs.append((r, col_lo + a, col_lo + b))
                hts.append(float(row[a]))
    return np.array(runs, dtype=np.int64).reshape(-1, 3), np.array(hts, dtype=np.float64)


def run_index_map(shape: tuple[int, int], runs: np.ndarray) -> np.ndarray:
    """(H, W) int64 run index of every map pixel (-1 where not raised) for ``height_runs`` output."""
    out = np.full(shape, -1, dtype=np.int64)
    for k, (r, a, b) in enumerate(runs):
        out[r, a:b] = k
    return out


def hit_labels(rgb: np.ndarray, surface: np.ndarray, wall_face: np.ndarray, col: np.ndarray, row: np.ndarray,
               run_index: np.ndarray) -> np.ndarray:
    """The label image of a ray-cast render (``CityRenderer.render`` + ``last_hits``) in the colours
    ``box_colours="labels"`` gives: ground and sky keep their rendered colour, roofs and walls get the
    label colour of their face class and run (``run_index`` from ``run_index_map``)."""
    out = rgb.copy()
    rows, cols = run_index.shape
    raised = (surface == 2) | (surface == 3)
    inside = raised & (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    k = np.where(inside, run_index[np.clip(row, 0, rows - 1), np.clip(col, 0, cols - 1)], 0)
    cls = np.zeros(surface.shape, dtype=np.int64)
    cls[surface == 2] = LABEL_ROOF
    for face, code in LABEL_WALL.items():
        cls[(surface == 3) & (wall_face == face)] = code
    out[inside, 0] = cls[inside]
    out[inside, 1] = k[inside] % 256
    out[inside, 2] = (k[inside] // 256) % 256
    return out


def agreement_share(labels: np.ndarray, reference: np.ndarray) -> float:
    """Share of pixels whose label (colour) the reference has at the same pixel or one of its 8
    neighbours: the "agrees within 1 px" measure of the renderer checks."""
    h, w = labels.shape[:2]
    pad = np.pad(reference, ((1, 1), (1, 1), (0, 0)), mode="edge")
    ok = np.zeros((h, w), dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ok |= np.all(labels == pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w], axis=2)
    return float(ok.mean())


class MeshCamera:
    """Renders (h, w, 3) uint8 RGB images of the orthophoto (and the DSM as boxes) with TinyRenderer.

    Args:
        orthophoto_rgb: (H, W, 3) uint8 map, row 0 = north edge; kept by reference, not copied.
        m_per_px: ground size of one map pixel, m.
        cfg: camera configuration (image size, field of view, mount, window size, outside grey).
        heights_m: (H, W) DSM, m above ground (None: flat).
        facade_rgb: (H, W, 3) wall colours (black: none), for ``box_colours="shaded"``.
        box_colours: "shaded" or "labels" (see the module docstring).
    """

    def __init__(self, orthophoto_rgb: np.ndarray, m_per_px: float, cfg: CameraConfig,
                 heights_m: np.ndarray | None = None, facade_rgb: np.ndarray | None = None,
                 box_colours: str = "shaded") -> None:
        ortho = np.asarray(orthophoto_rgb)
        if ortho.ndim == 2:
            ortho = np.repeat(ortho[:, :, None], 3, axis=2)
        if ortho.ndim != 3 or ortho.shape[2] != 3 or ortho.dtype != np.uint8 or min(ortho.shape[:2]) < 1:
            raise ValueError(f"orthophoto: shape {ortho.shape} dtype {ortho.dtype}: expected (H, W, 3) uint8")
        if not (m_per_px > 0.0 and math.isfinite(m_per_px)):
            raise ValueError(f"m_per_px = {m_per_px}: expected a number > 0")
        if box_colours not in ("shaded", "labels"):
            raise ValueError(f"box_colours = {box_colours!r}: expected 'shaded' or 'labels'")
        self.cfg = cfg
        self.m_per_px = float(m_per_px)
        self._map = ortho
        self._map_h, self._map_w = ortho.shape[:2]
        self._heights = None if heights_m is None else np.asarray(heights_m, dtype=np.float32)
        self._facade = facade_rgb
        self._box_colours = box_colours
        self._render_client = -1
        self._closed = False
        self._tmpdir = tempfile.mkdtemp(prefix="scenenav-ground-")
        self._client_box = [-1]      # the render client id, shared with the finalizer
        self._finalizer = weakref.finalize(self, _cleanup, self._tmpdir, self._client_box)
        self._tan_x = math.tan(math.radians(cfg.fov_deg) / 2.0)
        self._tan_y = self._tan_x * cfg.height_px / cfg.width_px
        self._projection = projection_matrix(self._tan_x, self._tan_y, cfg.width_px, cfg.height_px)
        self._tracker = WindowTracker(self._map_w, self._map_h, self.m_per_px, cfg.ground_window_px,
                                      cfg.width_px, self._tan_x, self._tan_y)
        self.box_count = 0

    @property
    def window(self) -> GroundWindow | None:
        return self._tracker.window

    @property
    def window_builds(self) -> int:
        return self._tracker.builds

    # ------------------------------------------------------------------ public
    def render(self, position_enu_m: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
        """(height_px, width_px, 3) uint8 RGB image seen from the vehicle pose (ENU m, body->ENU quat)."""
        x, y, z = (float(c) for c in position_enu_m)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise ValueError(f"camera position {position_enu_m!r}: expected finite ENU metres")
        eye = (x, y, max(z, MIN_HEIGHT_M))
        right, up, back = camera_axes(q_wxyz, self.cfg.mount)
        return self.render_view(eye, right, up, back)

    def render_view(self, eye, right, up, back) -> np.ndarray:
        """The image from an optical centre and the camera axes (as ``CityRenderer.render``)."""
        if self._closed:
            raise RuntimeError("MeshCamera.render after close()")
        if self._tracker.update(eye, right, up, back):
            assert self._tracker.window is not None
            self._build(self._tracker.window)
        view = view_matrix(eye, right, up, back)
        cfg = self.cfg
        out = p.getCameraImage(cfg.width_px, cfg.height_px, view, self._projection,
                               lightAmbientCoeff=1.0, lightDiffuseCoeff=0.0, lightSpecularCoeff=0.0,
                               shadow=0, flags=p.ER_NO_SEGMENTATION_MASK, renderer=p.ER_TINY_RENDERER,
                               physicsClientId=self._render_client)
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(cfg.height_px, cfg.width_px, 4)
        return np.ascontiguousarray(rgba[:, :, :3])

    def close(self) -> None:
        """Disconnect the private render client and remove the temporary directory (idempotent)."""
        self._finalizer()
        self._render_client = -1
        self._closed = True

    def __enter__(self) -> "MeshCamera":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # ------------------------------------------------------------------ ground window
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

    def _load_texture(self, cid: int, name: str, rgb: np.ndarray) -> int:
        path = os.path.join(self._tmpdir, f"{name}_{self._tracker.builds:06d}.bmp")
        if not cv2.imwrite(path, rgb[:, :, ::-1]):
            raise RuntimeError(f"{path}: cannot write a texture")
        try:
            return p.loadTexture(path, physicsClientId=cid)
        finally:
            os.remove(path)

    def _build(self, win: GroundWindow) -> None:
        """Rebuild the scene around ``win`` in a fresh private client."""
        tex = self._window_texture(win)
        self._disconnect()
        cid = p.connect(p.DIRECT)
        if cid < 0:
            raise RuntimeError("pybullet: cannot open a DIRECT client for the camera")
        self._render_client = cid
        self._client_box[0] = cid
        m = self.m_per_px
        half = win.half_m(m)
        centre_x, centre_y = win.centre_m(self._map_w, self._map_h, m)
        verts, idx, uvs = window_meshes(half)
        up_normal = [0.0, 0.0, 1.0]
        quad = p.createVisualShape(p.GEOM_MESH, vertices=verts[:4].tolist(), indices=idx[:6].tolist(),
                                   uvs=uvs[:4].tolist(), normals=[up_normal] * 4, physicsClientId=cid)
        window_body = p.createMultiBody(0.0, -1, quad, [centre_x, centre_y, 0.0], physicsClientId=cid)
        texture = self._load_texture(cid, "window", tex)
        p.changeVisualShape(window_body, -1, textureUniqueId=texture, rgbaColor=[1.0, 1.0, 1.0, 1.0],
                            physicsClientId=cid)
        # Grey frame around the window (a square annulus), drawn after the window.
        grey = self.cfg.outside_grey_level / 255.0
        frame = p.createVisualShape(
            p.GEOM_MESH, vertices=verts[4:12].tolist(), indices=(idx[6:] - 4).tolist(), uvs=uvs[4:12].tolist(),
            normals=[up_normal] * 8, rgbaColor=[grey, grey, grey, 1.0], physicsClientId=cid)
        frame_body = p.createMultiBody(0.0, -1, frame, [centre_x, centre_y, 0.0], physicsClientId=cid)
        p.changeVisualShape(frame_body, -1, rgbaColor=[grey, grey, grey, 1.0], physicsClientId=cid)
        if self._heights is not None:
            self._build_boxes(cid, win)
        logger.debug("ground window %d: map px (%d, %d), %d texels x L%d, %d boxes", self._tracker.builds,
                     win.col0_px, win.row0_px, win.size_texels, win.lod, self.box_count)

    def _box_palette(self, runs: np.ndarray, heights: np.ndarray) -> np.ndarray:
        """(K, 5, 3) uint8 colours per run: roof, then walls E, W, N, S."""
        k = runs.shape[0]
        colours = np.zeros((k, 5, 3), dtype=np.uint8)
        faces = (WallFace.EAST, WallFace.WEST, WallFace.NORTH, WallFace.SOUTH)
        for i, (r, a, b) in enumerate(runs):
            if self._box_colours == "labels":
                colours[i, 0] = label_colour(LABEL_ROOF, i)
                for j, f in enumerate(faces):
                    colours[i, 1 + j] = label_colour(LABEL_WALL[f], i)
                continue
            roof = self._map[r, a:b].reshape(-1, 3).mean(axis=0)
            colours[i, 0] = np.clip(np.rint(roof), 0, 255)
            wall = None
            if self._facade is not None:
                fac = self._facade[r, a:b].reshape(-1, 3)
                lit = fac[fac.any(axis=1)]
                if lit.shape[0]:
                    wall = lit.mean(axis=0)
            if wall is None:
                wall = NO_FACADE_FACTOR * roof
            for j, f in enumerate(faces):
                colours[i, 1 + j] = np.clip(np.rint(wall * FACE_LIGHT[f]), 0, 255)
        return colours

    def _build_boxes(self, cid: int, win: GroundWindow) -> None:
        """The DSM inside the window as boxes (one per run of equal height in a row), one palette texture."""
        assert self._heights is not None
        c_lo, c_hi = max(win.col0_px, 0), min(win.col0_px + win.span_px, self._map_w)
        r_lo, r_hi = max(win.row0_px, 0), min(win.row0_px + win.span_px, self._map_h)
        self.box_count = 0
        if c_hi <= c_lo or r_hi <= r_lo:
            return
        runs, heights = height_runs(self._heights, c_lo, c_hi, r_lo, r_hi)
        self.box_count = runs.shape[0]
        if not runs.shape[0]:
            return
        colours = self._box_palette(runs, heights).reshape(-1, 3)
        side = int(math.ceil(math.sqrt(colours.shape[0])))
        palette = np.zeros((side * side, 3), dtype=np.uint8)
        palette[:colours.shape[0]] = colours
        palette_img = palette.reshape(side, side, 3)
        m = self.m_per_px
        # Map pixel edges -> ENU: x = (u - W/2) m, y = (H/2 - v) m.
        verts: list[list[float]] = []
        uvs: list[list[float]] = []
        normals: list[list[float]] = []
        indices: list[int] = []
        chunks: list[tuple[list, list, list, list]] = []

        def uv_of(slot: int) -> list[float]:
            row, col = divmod(slot, side)
            # TinyRenderer flips loaded images: its texel row y is image row side - 1 - y.
            return [(col + 0.5) / side, (side - 1 - row + 0.5) / side]

        def quad(corners, normal, slot) -> None:
            base = len(verts)
            uv = uv_of(slot)
            for c in corners:
                verts.append(c)
                uvs.append(uv)
                normals.append(normal)
            indices.extend([base, base + 1, base + 2, base, base + 2, base + 3])

        for i, ((r, a, b), h) in enumerate(zip(runs, heights, strict=True)):
            x0, x1 = (a - self._map_w / 2.0) * m, (b - self._map_w / 2.0) * m
            y1, y0 = (self._map_h / 2.0 - r) * m, (self._map_h / 2.0 - r - 1) * m   # y1 north edge
            s = 5 * i
            # Counter-clockwise seen from outside (TinyRenderer culls back faces).
            quad([[x0, y0, h], [x1, y0, h], [x1, y1, h], [x0, y1, h]], [0.0, 0.0, 1.0], s)
            quad([[x1, y0, 0.0], [x1, y1, 0.0], [x1, y1, h], [x1, y0, h]], [1.0, 0.0, 0.0], s + 1)    # east
            quad([[x0, y1, 0.0], [x0, y0, 0.0], [x0, y0, h], [x0, y1, h]], [-1.0, 0.0, 0.0], s + 2)   # west
            quad([[x1, y1, 0.0], [x0, y1, 0.0], [x0, y1, h], [x1, y1, h]], [0.0, 1.0, 0.0], s + 3)    # north
            quad([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y0, h], [x0, y0, h]], [0.0, -1.0, 0.0], s + 4)   # south
            if len(verts) >= _MAX_BOX_VERTICES:
                chunks.append((verts, uvs, normals, indices))
                verts, uvs, normals, indices = [], [], [], []
        if verts:
            chunks.append((verts, uvs, normals, indices))
        texture = self._load_texture(cid, "palette", palette_img)
        for cv, cu, cn, ci in chunks:
            shape = p.createVisualShape(p.GEOM_MESH, vertices=cv, indices=ci, uvs=cu, normals=cn,
                                        physicsClientId=cid)
            body = p.createMultiBody(0.0, -1, shape, [0.0, 0.0, 0.0], physicsClientId=cid)
            p.changeVisualShape(body, -1, textureUniqueId=texture, rgbaColor=[1.0, 1.0, 1.0, 1.0],
                                physicsClientId=cid)

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
