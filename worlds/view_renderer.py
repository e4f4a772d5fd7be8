"""The camera renderer of the 3-D city: one numba kernel casts a pinhole camera's pixel rays into the DSM.

``CityRenderer(top_rgb, m_per_px, heights_m, facade_rgb).render(eye, right, up, back, w, h, tan_x,
tan_y)`` returns the (h, w, 3) uint8 image an ideal pinhole camera sees: optical centre ``eye`` (ENU
m), image right/up and the camera back (minus the optical axis) as ENU unit vectors, pixel (c, r)
looking through its centre, ``tan_x``/``tan_y`` the tangents of the half fields of view. World
conventions are those of ``scenenav/core/frames.py``.

Per pixel, in one pass (``_render_kernel``): the pixel ray is cast into the height field
(``worlds.raycast.cast_ray``: buildings lean away from nadir, facades are visible on the far side,
streets behind buildings are occluded). A roof or wall hit is shaded by ``worlds.raycast.shade_hit``
(roofs: the nearest texel of the level-of-detail texture; walls: facade colour, windows, per-face
light). A ray that reaches the ground - and every pixel of a flat world - takes the colour the
previous renderer (pybullet TinyRenderer drawing the ground window as one textured quad, see
``sitl/mesh_camera.py``) gives that pixel, computed the way TinyRenderer computes it: the window
quad and its grey frame are transformed to screen space in float32 with TinyRenderer's operation
order (``bullet3/examples/TinyRenderer/our_gl.cpp``, ``TinyRenderer.cpp``, ``geometry.h``: matrix
products summing from the last term, the viewport matrix, the division by w), the pixel's
barycentrics are computed in double from the float32 screen points, made perspective-correct, cast to
float32, the uv interpolated in float32 and the texel picked with ``int(uv * N)``. The triangle that
covers a pixel, and its texel unless the ground point lies within ``_UV_TOL`` of a texel edge, are
decided from the exact ground point; within a conservative distance of a triangle
edge (the window diagonal, its edges, the frame's outer edge) the pixel is resolved by emulating the
whole TinyRenderer pipeline for it: every triangle in draw order, bounding box, coverage, depth test,
near-plane clipping. So with every height zero the image is TinyRenderer's, pixel for pixel
(``tests/unit/worlds/test_view_renderer.py`` checks it over a grid of poses). Sky (a pixel no
triangle covers) is white, TinyRenderer's clear colour.

The ground window (``worlds.ground_window``) and the level-of-detail textures (block means, built once
per level and kept) make the per-frame cost independent of the map size: a frame touches only the
texels its rays hit. numba compiles the kernels on first use and caches them on disk
(``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worlds.ground_window import FRAME_MARGIN_M, GroundWindow, WindowTracker
from worlds.kernel_cache import drop_stale_kernels
from worlds.raycast import FACE_LIGHT, NO_NRT, HeightField, cast_ray_from, lod_texture, shade_hit

# The kernels below inline raycast.py's walk and shading: numba's cache would not see an edit there.
drop_stale_kernels(__file__, ["raycast.py"])

# Clip planes of the TinyRenderer camera (sitl.mesh_camera uses the same): the near plane stays below
# the lowest camera, the far plane beyond the grey frame seen by a tilted FIXED camera.
NEAR_M = 0.1
FAR_M = 30000.0
# Sky: TinyRenderer's clear colour (TinyRendererVisualShapeConverter::render clears to 255).
SKY_LEVEL = 255
# Conservative float32 error of TinyRenderer's screen-space geometry, relative to the magnitudes
# involved (camera and window coordinates, range), used to send pixels near a triangle edge to the
# full emulation. float32 epsilon is 6e-8; this is ~3000 times that.
_EDGE_TOL_REL = 2e-4
_EDGE_TOL_ABS_M = 1e-3
# Fast texel path: distance (texels) from a texel edge beyond which the texel under the exact ground
# point (double) is the one TinyRenderer's float32 uv picks (its rounding: ~1e-4 texel at N = 2048, a
# float32 ulp of uv times N; measured up to 2e-4 over 180 random poses of both mounts at 3-1000 m);
# nearer pixels are recomputed with the exact emulation.
_UV_TOL = 4e-3
# Image tiles (pixels on a side) that bound their rays' start height together (_cast_kernel).
_TILE = 8
# Mipmap level a camera ray's walk starts at (any level gives the same hit): the tile's start-height
# bound already excludes what a coarser cell would, so walks from level 5 mostly descended (measured:
# ~0.6 fewer steps per ray on an 8000 x 8000 synthetic city from level 3).
_START_LEVEL = 3

_F32 = np.float32


def projection_matrix(tan_x: float, tan_y: float, width_px: int, height_px: int) -> list[float]:
    """OpenGL perspective projection, column-major, principal point at the image centre.

    TinyRenderer rasterises pixel (i, j) at the integer viewport point (i, j), i.e. at a pixel corner,
    not its centre: the image would be shifted by half a pixel (measured). The third column shifts NDC
    by -1/w and -1/h so that every pixel samples the ray through its centre.
    """
    n, f = NEAR_M, FAR_M
    return [1.0 / tan_x, 0.0, 0.0, 0.0,
            0.0, 1.0 / tan_y, 0.0, 0.0,
            1.0 / width_px, 1.0 / height_px, (f + n) / (n - f), -1.0,
            0.0, 0.0, 2.0 * f * n / (n - f), 0.0]


def view_matrix(eye, right, up, back) -> list[float]:
    """OpenGL view matrix (world -> camera), column-major as pybullet expects."""
    tr = -(right[0] * eye[0] + right[1] * eye[1] + right[2] * eye[2])
    tu = -(up[0] * eye[0] + up[1] * eye[1] + up[2] * eye[2])
    tb = -(back[0] * eye[0] + back[1] * eye[1] + back[2] * eye[2])
    return [right[0], up[0], back[0], 0.0,
            right[1], up[1], back[1], 0.0,
            right[2], up[2], back[2], 0.0,
            tr, tu, tb, 1.0]


def window_meshes(half_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground meshes, in the window body's frame: (vertices (V, 3), indices (T*3,), uvs (V, 2)).

    Vertices 0-3: the window quad SW, SE, NE, NW (uv 0..1; TinyRenderer stores loaded images bottom
    row first, so v = 0 is the south texel row); 4-11: the grey frame, a square annulus from the
    window edge to ``FRAME_MARGIN_M`` beyond it (uv 0). Triangles 0-1 are the window, 2-9 the frame,
    in draw order.
    """
    h = half_m
    o = half_m + FRAME_MARGIN_M
    verts = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0],
                      [-o, -o, 0.0], [o, -o, 0.0], [o, o, 0.0], [-o, o, 0.0],
                      [-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    window_idx = [0, 1, 2, 0, 2, 3]
    frame_idx = [0, 1, 5, 0, 5, 4, 1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6, 3, 0, 4, 3, 4, 7]
    idx = np.array(window_idx + [i + 4 for i in frame_idx], dtype=np.int64)
    uvs = np.zeros((12, 2))
    uvs[:4] = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
    return verts, idx, uvs


def frame_grey(outside_grey_level: int) -> int:
    """The frame's colour in TinyRenderer: white (no texture) times the rgba colour, truncated."""
    return int(_F32(255.0) * _F32(outside_grey_level / 255.0))


# ---------------------------------------------------------------------------------------------
# TinyRenderer's float32 geometry (one frame's setup).

@njit(cache=True, inline="always")
def _dot4f(a0, a1, a2, a3, b0, b1, b2, b3):
    """geometry.h ``operator*(vec, vec)``: sum from the last term, in float32."""
    r = np.float32(0.0)
    r = r + a3 * b3
    r = r + a2 * b2
    r = r + a1 * b1
    r = r + a0 * b0
    return r


@njit(cache=True)
def _matmul4f(a, b):
    out = np.empty((4, 4), dtype=np.float32)
    for i in range(4):
        for j in range(4):
            out[i, j] = _dot4f(a[i, 0], a[i, 1], a[i, 2], a[i, 3], b[0, j], b[1, j], b[2, j], b[3, j])
    return out


@njit(cache=True)
def _clip_vertex(pmv, x, y, z):
    c = np.empty(4, dtype=np.float32)
    one = np.float32(1.0)
    for i in range(4):
        c[i] = _dot4f(pmv[i, 0], pmv[i, 1], pmv[i, 2], pmv[i, 3], x, y, z, one)
    return c


@njit(**NO_NRT)
def _screen(vp, c):
    """Viewport transform of clip coords -> (x, y, w) as TinyRenderer: (vp * c) / (vp * c)[3]."""
    s0 = _dot4f(vp[0, 0], vp[0, 1], vp[0, 2], vp[0, 3], c[0], c[1], c[2], c[3])
    s1 = _dot4f(vp[1, 0], vp[1, 1], vp[1, 2], vp[1, 3], c[0], c[1], c[2], c[3])
    w = _dot4f(vp[3, 0], vp[3, 1], vp[3, 2], vp[3, 3], c[0], c[1], c[2], c[3])
    return s0 / w, s1 / w, w


@njit(cache=True)
def _tr_setup(view, proj, cx, cy, verts, idx, width, height):
    """Per triangle: original clip coords (T,3,4), screen points (T,3,2), screen w (T,3); and the
    near-plane-clipped sub-triangles (T,3 max) of those with some w < 0: (T,3,3,4) clip coords,
    count per triangle (-1: not clipped, 0: discarded)."""
    vm = np.empty((4, 4), dtype=np.float32)
    pm = np.empty((4, 4), dtype=np.float32)
    for i in range(4):
        for j in range(4):
            vm[i, j] = view[i + 4 * j]
            pm[i, j] = proj[i + 4 * j]
    model = np.zeros((4, 4), dtype=np.float32)
    for i in range(4):
        model[i, i] = np.float32(1.0)
    model[0, 3] = cx
    model[1, 3] = cy
    mv = _matmul4f(vm, model)
    pmv = _matmul4f(pm, mv)
    vp = np.zeros((4, 4), dtype=np.float32)
    for i in range(4):
        vp[i, i] = np.float32(1.0)
    vp[0, 3] = np.float32(width) / np.float32(2.0)
    vp[1, 3] = np.float32(height) / np.float32(2.0)
    vp[2, 3] = np.float32(0.5)
    vp[0, 0] = np.float32(width) / np.float32(2.0)
    vp[1, 1] = np.float32(height) / np.float32(2.0)
    vp[2, 2] = np.float32(0.5)
    nt = idx.shape[0] // 3
    clip = np.empty((nt, 3, 4), dtype=np.float32)
    pts = np.empty((nt, 3, 2), dtype=np.float32)
    ws = np.empty((nt, 3), dtype=np.float32)
    sub = np.zeros((nt, 4, 3, 4), dtype=np.float32)
    nsub = np.full(nt, -1, dtype=np.int64)
    for t in range(nt):
        for k in range(3):
            vtx = idx[3 * t + k]
            c = _clip_vertex(pmv, verts[vtx, 0], verts[vtx, 1], verts[vtx, 2])
            clip[t, k] = c
            sx, sy, sw = _screen(vp, c)
            pts[t, k, 0] = sx
            pts[t, k, 1] = sy
            ws[t, k] = sw
        w0, w1, w2 = clip[t, 0, 3], clip[t, 1, 3], clip[t, 2, 3]
        if w0 < 0 and w1 < 0 and w2 < 0:
            nsub[t] = 0
        elif w0 >= 0 and w1 >= 0 and w2 >= 0:
            nsub[t] = -1
        else:
            poly = np.empty((6, 4), dtype=np.float32)
            npoly = 0
            for a, b in ((0, 1), (1, 2), (2, 0)):
                v0 = clip[t, a].copy()
                v1 = clip[t, b].copy()
                in0 = v0[3] > 0 and v0[2] > -v0[3]
                in1 = v1[3] > 0 and v1[2] > -v1[3]
                if not (in0 or in1):
                    continue
                if not (in0 and in1):
                    d0 = v0[2] + v0[3]
                    d1 = v1[2] + v1[3]
                    factor = np.float32(1.0 / np.float64(d1 - d0))
                    nv = np.empty(4, dtype=np.float32)
                    for q in range(4):
                        nv[q] = (v0[q] * d1 - v1[q] * d0) * factor
                    if in0:
                        v1 = nv
                    else:
                        v0 = nv
                poly[npoly] = v0      # TinyRenderer's equals() is always false: no dedup
                npoly += 1
                poly[npoly] = v1
                npoly += 1
            if npoly < 3:
                nsub[t] = 0
            else:
                count = 0
                for q in range(1, npoly - 1):
                    if count < 4:
                        sub[t, count, 0] = poly[0]
                        sub[t, count, 1] = poly[q]
                        sub[t, count, 2] = poly[q + 1]
                        count += 1
                nsub[t] = count
    return clip, pts, ws, sub, nsub, vp


@njit(cache=True, inline="always")
def _bary(ax, ay, bx, by, cx, cy, px, py):
    """our_gl.cpp ``barycentric`` in double from float32 points."""
    s0x = np.float64(cx) - np.float64(ax)
    s0y = np.float64(bx) - np.float64(ax)
    s0z = np.float64(ax) - px
    s1x = np.float64(cy) - np.float64(ay)
    s1y = np.float64(by) - np.float64(ay)
    s1z = np.float64(ay) - py
    ux = s0y * s1z - s0z * s1y
    uy = s0z * s1x - s0x * s1z
    uz = s0x * s1y - s0y * s1x
    if abs(uz) > 1e-2:
        return 1.0 - (ux + uy) / uz, uy / uz, ux / uz
    return -1.0, 1.0, 1.0


@njit(cache=True, inline="always")
def _bary_cross(pts, t, px, py):
    """The cross product of ``_bary`` for triangle t (same operations, for the fast path)."""
    ax = np.float64(pts[t, 0, 0])
    ay = np.float64(pts[t, 0, 1])
    s0x = np.float64(pts[t, 2, 0]) - ax
    s0y = np.float64(pts[t, 1, 0]) - ax
    s0z = ax - px
    s1x = np.float64(pts[t, 2, 1]) - ay
    s1y = np.float64(pts[t, 1, 1]) - ay
    s1z = ay - py
    return s0y * s1z - s0z * s1y, s0z * s1x - s0x * s1z, s0x * s1y - s0y * s1x


@njit(cache=True, inline="always")
def _persp(b0, b1, b2, w0, w1, w2):
    c0 = b0 / np.float64(w0)
    c1 = b1 / np.float64(w1)
    c2 = b2 / np.float64(w2)
    s = c0 + c1 + c2
    return c0 / s, c1 / s, c2 / s


@njit(cache=True, inline="always")
def _put_texel(out, r, c, tex, bi, bj, level_w, level_h, grey):
    """Pixel (r, c) takes texel (bi, bj) of the level, or the outside grey beyond the level."""
    if bi < 0 or bj < 0 or bi >= level_w or bj >= level_h:
        out[r, c, 0] = grey
        out[r, c, 1] = grey
        out[r, c, 2] = grey
    else:
        out[r, c, 0] = tex[bj, bi, 0]
        out[r, c, 1] = tex[bj, bi, 1]
        out[r, c, 2] = tex[bj, bi, 2]


@njit(**NO_NRT)
def _texel_colour(t, c0, c1, c2, uvs, idx, tex, n_tex, bcol0, brow0, level_w, level_h, grey, frame_c, out, r, c):
    """Fragment shader: uv in float32 from float32 barycentrics, int(uv * N), texel (or frame grey)."""
    if t >= 2:
        out[r, c, 0] = frame_c
        out[r, c, 1] = frame_c
        out[r, c, 2] = frame_c
        return
    f0 = np.float32(c0)
    f1 = np.float32(c1)
    f2 = np.float32(c2)
    i0 = idx[3 * t]
    i1 = idx[3 * t + 1]
    i2 = idx[3 * t + 2]
    zero = np.float32(0.0)
    uu = zero + uvs[i2, 0] * f2
    uu = uu + uvs[i1, 0] * f1
    uu = uu + uvs[i0, 0] * f0
    vv = zero + uvs[i2, 1] * f2
    vv = vv + uvs[i1, 1] * f1
    vv = vv + uvs[i0, 1] * f0
    # Model::diffuse: wrap to [0, 1) (std::modf), then int(uv * size), TGAImage::get clamps.
    fu = np.float32(np.float64(uu) - math.trunc(np.float64(uu)))
    if fu < 0:
        fu = fu + np.float32(1.0)
    fv = np.float32(np.float64(vv) - math.trunc(np.float64(vv)))
    if fv < 0:
        fv = fv + np.float32(1.0)
    nf = np.float32(n_tex)
    x = int(fu * nf)
    y = int(fv * nf)
    x = min(max(x, 0), n_tex - 1)
    y = min(max(y, 0), n_tex - 1)
    # Loaded textures are flipped vertically: TinyRenderer row y is image row N - 1 - y.
    _put_texel(out, r, c, tex, bcol0 + x, brow0 + (n_tex - 1 - y), level_w, level_h, grey)


@njit(**NO_NRT)
def _emulate_pixel(px, py, clip, pts, ws, sub, nsub, vp, far32, near32, uvs, idx, tex, n_tex, bcol0, brow0,
                   level_w, level_h, grey, frame_c, width, height, out, r, c):
    """The whole TinyRenderer pipeline for one pixel (P = (px, py)): every triangle in draw order."""
    zbuf = -far32
    out[r, c, 0] = 255
    out[r, c, 1] = 255
    out[r, c, 2] = 255
    clamp_x = np.float32(width - 1)
    clamp_y = np.float32(height - 1)
    for t in range(pts.shape[0]):
        if nsub[t] == 0:
            continue
        if nsub[t] < 0:
            nparts = 1
        else:
            nparts = nsub[t]
        for part in range(nparts):
            if nsub[t] < 0:
                ax, ay = pts[t, 0, 0], pts[t, 0, 1]
                bx, by = pts[t, 1, 0], pts[t, 1, 1]
                cx, cy = pts[t, 2, 0], pts[t, 2, 1]
                w0, w1, w2 = ws[t, 0], ws[t, 1], ws[t, 2]
                z0, z1, z2 = clip[t, 0, 2], clip[t, 1, 2], clip[t, 2, 2]
            else:
                sx0, sy0, w0 = _screen(vp, sub[t, part, 0])
                sx1, sy1, w1 = _screen(vp, sub[t, part, 1])
                sx2, sy2, w2 = _screen(vp, sub[t, part, 2])
                ax, ay, bx, by, cx, cy = sx0, sy0, sx1, sy1, sx2, sy2
                z0, z1, z2 = sub[t, part, 0, 2], sub[t, part, 1, 2], sub[t, part, 2, 2]
            # Bounding box (clamped to the image), P.x from int(bboxmin.x).
            bminx = max(np.float32(0.0), min(min(ax, bx), cx))
            bminy = max(np.float32(0.0), min(min(ay, by), cy))
            bmaxx = min(clamp_x, max(max(ax, bx), cx))
            bmaxy = min(clamp_y, max(max(ay, by), cy))
            if not (px >= int(bminx) and np.float32(px) <= bmaxx and py >= int(bminy) and np.float32(py) <= bmaxy):
                continue
            b0, b1, b2 = _bary(ax, ay, bx, by, cx, cy, np.float64(px), np.float64(py))
            c0, c1, c2 = _persp(b0, b1, b2, w0, w1, w2)
            depth = -1.0 * (((0.0 + np.float64(z2) * c2) + np.float64(z1) * c1) + np.float64(z0) * c0)
            if b0 < 0 or b1 < 0 or b2 < 0 or np.float64(zbuf) > depth:
                continue
            if nsub[t] >= 0:
                # Clipped path: uv from the original triangle's screen points; no near/far discard.
                ob0, ob1, ob2 = _bary(pts[t, 0, 0], pts[t, 0, 1], pts[t, 1, 0], pts[t, 1, 1], pts[t, 2, 0],
                                      pts[t, 2, 1], np.float64(px), np.float64(py))
                u0, u1, u2 = _persp(ob0, ob1, ob2, ws[t, 0], ws[t, 1], ws[t, 2])
                _texel_colour(t, u0, u1, u2, uvs, idx, tex, n_tex, bcol0, brow0, level_w, level_h, grey,
                              frame_c, out, r, c)
                zbuf = np.float32(depth)
            else:
                if depth < -np.float64(far32) or depth > np.float64(near32):
                    continue
                _texel_colour(t, c0, c1, c2, uvs, idx, tex, n_tex, bcol0, brow0, level_w, level_h, grey,
                              frame_c, out, r, c)
                zbuf = np.float32(depth)


@njit(cache=True, inline="always")
def _region_max(mip, mip_off, mip_w, nlev, heights, u_lo, u_hi, v_lo, v_hi):
    """An upper bound of the heights over map pixels [u_lo, u_hi] x [v_lo, v_hi] (continuous, clipped to
    the map; 0 when outside), from the coarsest-enough mipmap level (at most 3 x 3 cells)."""
    rows, cols = heights.shape
    c0 = max(int(math.floor(u_lo)), 0)
    c1 = min(int(math.floor(u_hi)), cols - 1)
    r0 = max(int(math.floor(v_lo)), 0)
    r1 = min(int(math.floor(v_hi)), rows - 1)
    if c1 < c0 or r1 < r0:
        return 0.0
    ext = max(c1 - c0, r1 - r0) + 1
    lev = 0
    while lev < nlev and (1 << lev) * 8 < ext:
        lev += 1
    best = 0.0
    if lev == 0:
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                best = max(best, heights[r, c])
        return best
    base = mip_off[lev]
    w = mip_w[lev]
    for cy in range(r0 >> lev, (r1 >> lev) + 1):
        for cx in range(c0 >> lev, (c1 >> lev) + 1):
            best = max(best, mip[base + cy * w + cx])
    return best


@njit(**NO_NRT)
def _cast_kernel(eye, right, up, back, width, height, tan_x, tan_y, heights, mip, mip_off, mip_w, nlev, hmax,
                 m_per_px, map_w, map_h, a_col, s_out, surf_out, face_out, col_out, row_out):
    """Pass 1 (relief only): the first hit of every pixel's ray.

    Image tiles of _TILE x _TILE pixels first bound their rays' start height: every ray of a tile, between
    heights h and 0, stays over the map rectangle spanned by the tile's corner rays at h and at 0 (the
    beam is convex), so nothing above the highest height there can be hit (two refinements).
    """
    ex, ey, ez = eye[0], eye[1], eye[2]
    inv_m = 1.0 / m_per_px
    u0 = ex * inv_m + map_w / 2.0
    v0 = map_h / 2.0 - ey * inv_m
    lev0 = min(_START_LEVEL, nlev)
    for tr in range(0, height, _TILE):
        for tc in range(0, width, _TILE):
            r_hi = min(tr + _TILE, height) - 1
            c_hi = min(tc + _TILE, width) - 1
            # Corner rays of the tile (pixel centres): their map points at heights ht and 0.
            h_tile = hmax
            ok = True
            for _ in range(2):
                u_lo = 1e300
                u_hi = -1e300
                v_lo = 1e300
                v_hi = -1e300
                for rr in (tr, r_hi):
                    b = (1.0 - (2.0 * rr + 1.0) / height) * tan_y
                    for cc in (tc, c_hi):
                        a = ((2.0 * cc + 1.0) / width - 1.0) * tan_x
                        dx = -back[0] + a * right[0] + b * up[0]
                        dy = -back[1] + a * right[1] + b * up[1]
                        dz = -back[2] + a * right[2] + b * up[2]
                        if not dz < 0.0:
                            ok = False
                            break
                        for zz in (h_tile, 0.0):
                            t = (ez - zz) / -dz
                            if t < 0.0:
                                t = 0.0
                            pu = u0 + dx * inv_m * t
                            pv = v0 - dy * inv_m * t
                            u_lo = min(u_lo, pu)
                            u_hi = max(u_hi, pu)
                            v_lo = min(v_lo, pv)
                            v_hi = max(v_hi, pv)
                    if not ok:
                        break
                if not ok:
                    break
                h_tile = min(h_tile, _region_max(mip, mip_off, mip_w, nlev, heights, u_lo - 1.0, u_hi + 1.0,
                                                 v_lo - 1.0, v_hi + 1.0))
            # The last region holds every ray of the tile between h_tile and 0 (a lower start only
            # shrinks it): well inside the map, the rays need no map-entry tests.
            inside = ok and u_lo >= 1.0 and v_lo >= 1.0 and u_hi <= map_w - 1.0 and v_hi <= map_h - 1.0
            if not ok:
                h_tile = hmax
            for r in range(tr, r_hi + 1):
                b = (1.0 - (2.0 * r + 1.0) / height) * tan_y
                for c in range(tc, c_hi + 1):
                    a = a_col[c]
                    dx = -back[0] + a * right[0] + b * up[0]
                    dy = -back[1] + a * right[1] + b * up[1]
                    dz = -back[2] + a * right[2] + b * up[2]
                    s, sf, face, hc, hr = cast_ray_from(u0, v0, ez, dx * inv_m, -dy * inv_m, dz, heights, mip,
                                                        mip_off, mip_w, nlev, h_tile, lev0, inside)
                    s_out[r, c] = s
                    surf_out[r, c] = sf
                    face_out[r, c] = face
                    col_out[r, c] = hc
                    row_out[r, c] = hr


@njit(**NO_NRT)
def _render_kernel(eye, right, up, back, width, height, tan_x, tan_y, relief, m_per_px, map_w, map_h,
                   tex, lod, facade, has_facade, grey, face_light,
                   win_cx, win_cy, half, outer, n_tex, bcol0, brow0, level_w, level_h, frame_c,
                   clip, pts, ws, sub, nsub, vp, far32, near32, uvs, idx,
                   a_col, out, out_flat, s_in, surf_out, face_out, col_out, row_out):
    """Pass 2: roofs and walls shaded from the hits of pass 1 (``relief``), the ground as TinyRenderer."""
    ex, ey, ez = eye[0], eye[1], eye[2]
    inv_m = 1.0 / m_per_px
    u0 = ex * inv_m + map_w / 2.0
    v0 = map_h / 2.0 - ey * inv_m
    scale = abs(ex) + abs(ey) + abs(win_cx) + abs(win_cy) + half + ez
    # The longest pixel direction (|d| is convex in the image tangents: its maximum over the image is at
    # a corner), a little enlarged, bounds every pixel's |d| without a square root per pixel.
    d_max = 0.0
    for ca in (-tan_x, tan_x):
        for cb in (-tan_y, tan_y):
            qx = -back[0] + ca * right[0] + cb * up[0]
            qy = -back[1] + ca * right[1] + cb * up[1]
            qz = -back[2] + ca * right[2] + cb * up[2]
            d_max = max(d_max, math.sqrt(qx * qx + qy * qy + qz * qz))
    d_max *= 1.0 + 1e-9
    # uz of the window triangles' barycentric cross product (the same for every pixel): TinyRenderer
    # draws nothing of a degenerate screen triangle (|uz| <= 1e-2), left to the exact emulation.
    uz_0 = _bary_cross(pts, 0, 0.0, 0.0)[2]
    uz_1 = _bary_cross(pts, 1, 0.0, 0.0)[2]
    # Texels per metre of the window quad (uv 0..1 over its 2 * half metres).
    tex_per_m = n_tex / (2.0 * half)
    # Window triangle 0 = SW, SE, NE (below the SW-NE diagonal, ly < lx), 1 = SW, NE, NW.
    for r in range(height):
        b = (1.0 - (2.0 * r + 1.0) / height) * tan_y
        for c in range(width):
            a = a_col[c]
            dx = -back[0] + a * right[0] + b * up[0]
            dy = -back[1] + a * right[1] + b * up[1]
            dz = -back[2] + a * right[2] + b * up[2]
            if relief:
                sf = surf_out[r, c]
                if sf == 2:
                    # A roof: the nearest texel of the level-of-detail texture (shade_hit's TOP case).
                    hc = col_out[r, c] // lod if lod > 1 else col_out[r, c]
                    hr = row_out[r, c] // lod if lod > 1 else row_out[r, c]
                    out[r, c, 0] = tex[hr, hc, 0]
                    out[r, c, 1] = tex[hr, hc, 1]
                    out[r, c, 2] = tex[hr, hc, 2]
                    continue
                if sf == 3:
                    s = s_in[r, c]
                    hu = u0 + dx * inv_m * s
                    hv = v0 - dy * inv_m * s
                    hz = ez + dz * s
                    shade_hit(sf, face_out[r, c], col_out[r, c], row_out[r, c], hu, hv, hz, tex, map_h, map_w, lod,
                              facade, has_facade, grey, m_per_px, face_light, out_flat, r * width + c)
                    continue
            else:
                surf_out[r, c] = 1 if dz < 0.0 else 0
                face_out[r, c] = 0
                col_out[r, c] = -1
                row_out[r, c] = -1
            # The ground, as TinyRenderer draws it.
            py = height - 1 - r
            t = -1
            fast = False
            if dz < 0.0:
                tg = ez / -dz
                lx = ex + dx * tg - win_cx
                ly = ey + dy * tg - win_cy
                rng = tg * d_max     # an upper bound of the range: only widens the emulated bands
                if not relief:
                    col_out[r, c] = int(math.floor((ex + dx * tg) / m_per_px + map_w / 2.0))
                    row_out[r, c] = int(math.floor(map_h / 2.0 - (ey + dy * tg) / m_per_px))
                tol = _EDGE_TOL_REL * (scale + rng) + _EDGE_TOL_ABS_M
                alx = abs(lx)
                aly = abs(ly)
                if rng < 0.5 * FAR_M:
                    if alx < half - tol and aly < half - tol:
                        d = lx - ly
                        if d > tol * 1.5:
                            t = 0
                            fast = True
                        elif d < -tol * 1.5:
                            t = 1
                            fast = True
                    elif (alx > half + tol or aly > half + tol) and alx < outer - tol and aly < outer - tol:
                        t = 2
                        fast = True
                    elif alx > outer + tol or aly > outer + tol:
                        t = 10
                        fast = True
            if fast:
                if t == 10:
                    out[r, c, 0] = 255
                    out[r, c, 1] = 255
                    out[r, c, 2] = 255
                elif t == 2:
                    out[r, c, 0] = frame_c
                    out[r, c, 1] = frame_c
                    out[r, c, 2] = frame_c
                else:
                    # The texel from the exact ground point (the window quad's uv is linear in it, no
                    # barycentrics); the exact float32 emulation only when it lies within _UV_TOL texels
                    # of a texel edge, where TinyRenderer's float32 screen points and uv could pick the
                    # neighbour.
                    exact = True
                    if abs(uz_0 if t == 0 else uz_1) > 1e-2:
                        au = (lx + half) * tex_per_m
                        av = (ly + half) * tex_per_m
                        if (_UV_TOL < au < n_tex - _UV_TOL and _UV_TOL < av < n_tex - _UV_TOL
                                and abs(au - math.floor(au + 0.5)) > _UV_TOL
                                and abs(av - math.floor(av + 0.5)) > _UV_TOL):
                            exact = False
                            x = int(au)
                            y = int(av)
                            _put_texel(out, r, c, tex, bcol0 + x, brow0 + (n_tex - 1 - y), level_w,
                                       level_h, grey)
                    if exact:
                        b0, b1, b2 = _bary(pts[t, 0, 0], pts[t, 0, 1], pts[t, 1, 0], pts[t, 1, 1], pts[t, 2, 0],
                                           pts[t, 2, 1], np.float64(c), np.float64(py))
                        c0, c1, c2 = _persp(b0, b1, b2, ws[t, 0], ws[t, 1], ws[t, 2])
                        _texel_colour(t, c0, c1, c2, uvs, idx, tex, n_tex, bcol0, brow0, level_w, level_h, grey,
                                      frame_c, out, r, c)
            else:
                _emulate_pixel(c, py, clip, pts, ws, sub, nsub, vp, far32, near32, uvs, idx, tex, n_tex, bcol0,
                               brow0, level_w, level_h, grey, frame_c, width, height, out, r, c)


class CityRenderer:
    """Pinhole images of the 3-D city (see the module docstring).

    Args:
        top_rgb: (H, W, 3) uint8 texture of the ground and the roofs (the orthophoto), row 0 = north;
            kept by reference.
        m_per_px: ground size of a map pixel, m.
        heights_m: (H, W) heights above the ground (the DSM), None or all zero = a flat world.
        facade_rgb: (H, W, 3) uint8 wall colours (black = none at that pixel), or None.
        outside_grey_level: grey of the ground outside the map and of the frame around the window.
        ground_window_px: side of the ground window, texels (``worlds.ground_window``).
    """

    def __init__(self, top_rgb: np.ndarray, m_per_px: float, heights_m: np.ndarray | None = None,
                 facade_rgb: np.ndarray | None = None, outside_grey_level: int = 128,
                 ground_window_px: int = 2048) -> None:
        top = np.asarray(top_rgb)
        if top.ndim == 2:
            top = np.repeat(top[:, :, None], 3, axis=2)
        if top.ndim != 3 or top.shape[2] != 3 or top.dtype != np.uint8 or min(top.shape[:2]) < 1:
            raise ValueError(f"top_rgb: shape {top.shape} dtype {top.dtype}: expected (H, W, 3) uint8")
        if not (m_per_px > 0.0 and math.isfinite(m_per_px)):
            raise ValueError(f"m_per_px = {m_per_px}: expected a number > 0")
        self.top = np.ascontiguousarray(top)
        self.map_h, self.map_w = top.shape[:2]
        self.m_per_px = float(m_per_px)
        self.grey = int(outside_grey_level)
        self.ground_window_px = int(ground_window_px)
        if heights_m is not None and np.asarray(heights_m).shape != top.shape[:2]:
            raise ValueError(f"heights_m: shape {np.asarray(heights_m).shape}: expected {top.shape[:2]}")
        if heights_m is not None and float(np.max(heights_m)) > 0.0:
            self.field: HeightField | None = HeightField(heights_m, m_per_px)
        else:
            self.field = None
        self._heights = self.field.heights_m if self.field else np.zeros((1, 1), np.float32)
        self._mip = self.field.mip if self.field else np.zeros(1, np.float32)
        self._mip_off = self.field.mip_off if self.field else np.zeros(1, np.int64)
        self._mip_w = self.field.mip_w if self.field else np.ones(1, np.int64)
        self._nlev = self.field.levels if self.field else 0
        self._hmax = self.field.max_height_m if self.field else 0.0
        if facade_rgb is not None:
            fac = np.ascontiguousarray(facade_rgb, dtype=np.uint8)
            if fac.shape != top.shape:
                raise ValueError(f"facade_rgb: shape {fac.shape}: expected {top.shape}")
            self._facade, self._has_facade = fac, True
        else:
            self._facade, self._has_facade = np.zeros((1, 1, 3), np.uint8), False
        self._levels: dict[int, np.ndarray] = {1: self.top}
        self._trackers: dict[tuple[int, int, float, float], WindowTracker] = {}
        self._buffers: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}
        self._a_cols: dict[tuple[int, float], np.ndarray] = {}
        self._frame_c = frame_grey(self.grey)
        self._mesh_key: tuple | None = None
        self._mesh: tuple = ()

    @property
    def relief(self) -> bool:
        return self.field is not None

    def level(self, lod: int) -> np.ndarray:
        """The level-of-detail texture (block means of L x L map pixels), built on first use and kept."""
        tex = self._levels.get(lod)
        if tex is None:
            tex = lod_texture(self.top, lod, self.grey)
            self._levels[lod] = tex
        return tex

    def tracker(self, width_px: int, height_px: int, tan_x: float, tan_y: float) -> WindowTracker:
        """The ground window of this camera geometry (one per image size and field of view)."""
        key = (int(width_px), int(height_px), float(tan_x), float(tan_y))
        tr = self._trackers.get(key)
        if tr is None:
            tr = WindowTracker(self.map_w, self.map_h, self.m_per_px, self.ground_window_px, width_px,
                               tan_x, tan_y)
            self._trackers[key] = tr
        return tr

    def render(self, eye_enu_m, right, up, back, width_px: int, height_px: int, tan_x: float,
               tan_y: float) -> np.ndarray:
        """(height_px, width_px, 3) uint8 image from ``eye_enu_m`` (must be above the ground, z > 0)."""
        eye = tuple(float(c) for c in eye_enu_m)
        if not all(math.isfinite(c) for c in eye) or eye[2] <= 0.0:
            raise ValueError(f"eye {eye_enu_m!r}: expected finite ENU metres above the ground")
        r3 = tuple(float(c) for c in right)
        u3 = tuple(float(c) for c in up)
        b3 = tuple(float(c) for c in back)
        tracker = self.tracker(width_px, height_px, tan_x, tan_y)
        tracker.update(eye, r3, u3, b3)   # type: ignore[arg-type]
        win = tracker.window
        assert win is not None
        return self._render(eye, r3, u3, b3, int(width_px), int(height_px), float(tan_x), float(tan_y), win)

    def last_hits(self, width_px: int, height_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(surface, wall_face, col, row) per pixel of the last image of this size (``worlds.raycast``
        ``Surface``/``WallFace`` values and the map pixel hit; for the ground, the pixel under the ground
        point; -1 for sky). Views of internal buffers: the next render overwrites them."""
        buf = self._buffers[(int(width_px), int(height_px))]
        return buf[1], buf[2], buf[3], buf[4]

    def _render(self, eye, right, up, back, width, height, tan_x, tan_y, win: GroundWindow) -> np.ndarray:
        m = self.m_per_px
        cx, cy = win.centre_m(self.map_w, self.map_h, m)
        half = win.half_m(m)
        mesh_key = (half, width, height, tan_x, tan_y)
        if self._mesh_key != mesh_key:    # per window and camera geometry, not per frame
            verts, idx, uvs = window_meshes(half)
            self._mesh = (verts.astype(np.float32), idx, uvs.astype(np.float32),
                          np.array(projection_matrix(tan_x, tan_y, width, height), dtype=np.float32))
            self._mesh_key = mesh_key
        verts32, idx, uvs32, proj = self._mesh
        view = np.array(view_matrix(eye, right, up, back), dtype=np.float32)
        clip, pts, ws, sub, nsub, vp = _tr_setup(view, proj, _F32(cx), _F32(cy), verts32, idx, width, height)
        far32 = _F32(proj[14] / (proj[10] + _F32(1.0)))
        near32 = _F32(proj[14] / (proj[10] - _F32(1.0)))
        tex = self.level(win.lod)
        key = (width, height)
        buf = self._buffers.get(key)
        if buf is None:
            buf = (np.empty((height, width, 3), np.uint8), np.empty((height, width), np.uint8),
                   np.empty((height, width), np.uint8), np.empty((height, width), np.int64),
                   np.empty((height, width), np.int64), np.empty((height, width), np.float64))
            self._buffers[key] = buf
        out, surf, face, col, row, s_buf = buf
        a_key = (width, tan_x)
        a_col = self._a_cols.get(a_key)
        if a_col is None:
            # Horizontal tangent of each pixel column's centre ray, the kernels' per-pixel expression.
            a_col = ((2.0 * np.arange(width, dtype=np.float64) + 1.0) / width - 1.0) * tan_x
            self._a_cols[a_key] = a_col
        e, rt, u, b = np.array(eye), np.array(right), np.array(up), np.array(back)
        if self.field is not None:
            _cast_kernel(e, rt, u, b, width, height, tan_x, tan_y, self._heights, self._mip, self._mip_off,
                         self._mip_w, self._nlev, self._hmax, m, self.map_w, self.map_h, a_col, s_buf, surf, face,
                         col, row)
        _render_kernel(e, rt, u, b, width, height, tan_x, tan_y, self.field is not None, m, self.map_w, self.map_h,
                       tex, win.lod, self._facade, self._has_facade, self.grey, FACE_LIGHT,
                       cx, cy, half, half + FRAME_MARGIN_M, win.size_texels, win.col0_px // win.lod,
                       win.row0_px // win.lod, tex.shape[1], tex.shape[0], self._frame_c,
                       clip, pts, ws, sub, nsub, vp, far32, near32,
                       uvs32, idx, a_col, out, out.reshape(height * width, 3), s_buf, surf, face, col, row)
        return out.copy()
