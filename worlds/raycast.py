"""Ray casting a height field: where does a ray first meet the 3-D city, and what colour is it there.

Surface model (the world's DSM, ``World.dsm_m``): every map pixel (c, r) is a flat-topped prism
(a column) of its height ``h[r, c]`` metres standing on the ground plane z = 0; outside the map the
height is 0. Roofs are the prism tops, walls the vertical faces between neighbouring pixels of
different height (and between a raised edge pixel and the outside). Map pixel coordinates follow
``scenenav/core/frames.py``: ``u = x / m + W / 2``, ``v = H / 2 - y / m`` (row 0 is the north edge).

Method: a two-level 3-D DDA (Amanatides & Woo, "A fast voxel traversal algorithm", Eurographics
1987) over the map grid. The ray starts where it descends through the highest height of the map
(nothing can be hit above it) and walks tiles of ``TILE_PX`` x ``TILE_PX`` pixels whose maximum height
is precomputed; a tile the ray crosses entirely above its maximum is skipped, otherwise the ray walks
its pixels. In each pixel the ray spans the parameter interval [s_in, s_out) and reaches the pixel's
height at ``s_h``: ``s_in >= s_h`` means it enters the column through a wall (the face it crossed),
``s_out > s_h`` means it comes down on the top inside the pixel. Everything is compared in the ray
parameter, so there are no epsilons. A street pixel (height 0) is "ground". Rays that never come down
(``dz >= 0``) miss. A ray starting inside a column (an eye below a roof) hits that column's top at
its origin.

``first_hits`` casts arbitrary rays (the 500 m perspective reference, tests); the camera renderer
(``worlds/view_renderer.py``) calls the same per-ray kernel ``cast_ray`` from its own per-image
kernel. ``shade`` turns hits into colours: ground and roofs sample the top texture (nearest texel,
optionally at a level of detail L: the mean of the L x L block of map pixels, blocks aligned to
multiples of L), walls take the facade colour of their pixel with a procedural window pattern
(see ``FLOOR_HEIGHT_M`` and neighbours) lit by a fixed per-face factor. All kernels are numba
``@njit(cache=True)``, single-threaded and deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
from numba import njit

# Kernels called once per ray or pixel are compiled without numba's reference counting (``_nrt=False``:
# they allocate nothing): with it, every call increments and decrements the arrays passed (atomic
# operations), which measured ~2.5x slower for the ray cast.
NO_NRT: dict[str, Any] = {"cache": True, "_nrt": False}

# Levels of the maximum mipmap (cells up to 2^MIP_LEVELS map pixels on a side).
MIP_LEVELS = 5

# Facade pattern (documented in docs/rendering.md). Storey height ~3 m (typical residential floor to
# floor height), windows 1.2 m wide every 2.5 m along the wall, 1.5 m tall starting 0.9 m above the
# storey's floor (sill height); glass darker than the wall.
FLOOR_HEIGHT_M = 3.0
WINDOW_PITCH_M = 2.5
WINDOW_WIDTH_M = 1.2
WINDOW_SILL_M = 0.9
WINDOW_HEIGHT_M = 1.5
GLASS_FACTOR = 0.45
# Wall colour when the world has no facade colours: the top colour darkened by this factor.
NO_FACADE_FACTOR = 0.7
# Fixed lighting of the walls per face (sun high in the south-west; roofs and ground are 1.0 = their
# texture). Ambient + Lambert with a sun at azimuth 225 deg, elevation 45 deg, ambient 0.45.
_SUN_AZ = math.radians(225.0)
_SUN_EL = math.radians(45.0)
_AMBIENT = 0.45


class Surface(IntEnum):
    """What a ray hit (``RayHits.surface``)."""

    MISS = 0       # the ray never comes down (dz >= 0)
    GROUND = 1     # the ground plane (a pixel of height 0, or outside the map)
    TOP = 2        # the flat top of a raised pixel (roof, tree crown)
    WALL = 3       # a vertical face of a raised pixel


class WallFace(IntEnum):
    """Which vertical face of a pixel's column a wall hit is on, named by its outward normal."""

    NONE = 0
    EAST = 1       # +x face (the column's right edge u = c + 1)
    WEST = 2       # -x face (u = c)
    NORTH = 3      # +y face (v = r, row 0 is north)
    SOUTH = 4      # -y face (v = r + 1)


def _face_light(face: WallFace) -> float:
    """Ambient + Lambert factor of a wall face under the fixed sun (see ``_SUN_AZ``)."""
    # Sun direction (toward the sun), ENU: azimuth clockwise from north.
    sx = math.sin(_SUN_AZ) * math.cos(_SUN_EL)
    sy = math.cos(_SUN_AZ) * math.cos(_SUN_EL)
    normal = {WallFace.EAST: (1.0, 0.0), WallFace.WEST: (-1.0, 0.0),
              WallFace.NORTH: (0.0, 1.0), WallFace.SOUTH: (0.0, -1.0)}[face]
    lambert = max(0.0, normal[0] * sx + normal[1] * sy)
    return min(1.0, _AMBIENT + (1.0 - _AMBIENT) * lambert)


# Indexed by WallFace value.
FACE_LIGHT = np.array([1.0] + [_face_light(f) for f in (WallFace.EAST, WallFace.WEST,
                                                        WallFace.NORTH, WallFace.SOUTH)], dtype=np.float64)


@dataclass(frozen=True, eq=False)
class HeightField:
    """A DSM ready for ray casting: (H, W) float32 heights (m above ground) and their maximum mipmap.

    Level k of the mipmap (k = 1 .. ``levels``) holds the maximum height of each 2^k x 2^k block of
    map pixels (blocks aligned to multiples of 2^k, zero outside the map), all levels packed in the 1-D
    ``mip`` at offsets ``mip_off[k]`` with row length ``mip_w[k]``. ``heights_m`` is kept by reference
    when it already is a C-contiguous float32 array.
    """

    heights_m: np.ndarray
    m_per_px: float
    mip: np.ndarray
    mip_off: np.ndarray
    mip_w: np.ndarray
    levels: int
    max_height_m: float

    def __init__(self, heights_m: np.ndarray, m_per_px: float) -> None:
        h = np.ascontiguousarray(heights_m, dtype=np.float32)
        if h.ndim != 2 or min(h.shape) < 1:
            raise ValueError(f"heights_m: shape {h.shape}: expected (H, W) with H, W >= 1")
        if not np.all(np.isfinite(h)) or float(h.min()) < 0.0:
            raise ValueError("heights_m: expected finite heights >= 0 m")
        if not (m_per_px > 0.0 and math.isfinite(m_per_px)):
            raise ValueError(f"m_per_px = {m_per_px}: expected a number > 0")
        levels = max(0, min(MIP_LEVELS, int(math.ceil(math.log2(max(h.shape))))))
        parts = [np.zeros(0, np.float32)]
        offs = [0]
        widths = [h.shape[1]]
        cur = h
        total = 0
        for _ in range(levels):
            r, c = cur.shape
            pr, pc = r + (r & 1), c + (c & 1)
            pad = np.zeros((pr, pc), dtype=np.float32)
            pad[:r, :c] = cur
            cur = pad.reshape(pr // 2, 2, pc // 2, 2).max(axis=(1, 3))
            offs.append(total)
            widths.append(cur.shape[1])
            parts.append(cur.ravel())
            total += cur.size
        object.__setattr__(self, "heights_m", h)
        object.__setattr__(self, "m_per_px", float(m_per_px))
        object.__setattr__(self, "mip", np.ascontiguousarray(np.concatenate(parts), dtype=np.float32))
        object.__setattr__(self, "mip_off", np.array(offs, dtype=np.int64))
        object.__setattr__(self, "mip_w", np.array(widths, dtype=np.int64))
        object.__setattr__(self, "levels", int(levels))
        object.__setattr__(self, "max_height_m", float(h.max()))

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.heights_m.shape[0]), int(self.heights_m.shape[1]))

    @property
    def flat(self) -> bool:
        return self.max_height_m <= 0.0


@dataclass(frozen=True, eq=False)
class RayHits:
    """First intersections of N rays with the surface (arrays of length N).

    ``u_px``, ``v_px``: continuous map pixel coordinates of the hit point (NaN for misses);
    ``height_m``: its height above the ground; ``surface``: ``Surface`` values (uint8);
    ``wall_face``: ``WallFace`` values (uint8, NONE unless a wall); ``col_px``, ``row_px``: the map
    pixel whose column was hit (for ground hits, the pixel under the hit point, possibly outside the
    map; -1 for misses) — a wall hit lies exactly on a pixel edge, so use these, not floor(u, v);
    ``range_s``: the ray parameter of the hit (distance in units of the direction's length).
    """

    u_px: np.ndarray
    v_px: np.ndarray
    height_m: np.ndarray
    surface: np.ndarray
    wall_face: np.ndarray
    col_px: np.ndarray
    row_px: np.ndarray
    range_s: np.ndarray

    @property
    def miss(self) -> np.ndarray:
        """Boolean mask of the rays that never reach the surface (upward or horizontal rays)."""
        return self.surface == Surface.MISS

    def __len__(self) -> int:
        return int(self.surface.shape[0])


# ---------------------------------------------------------------------------------------------
# The per-ray kernel. Ray in map pixel space: u(s) = u0 + du s, v(s) = v0 + dv s, z(s) = z0 + dz s.

_INF = np.inf
# Array indices that are never negative are cast to unsigned: numba then drops its negative-index
# wrap-around (a shift, an and and an add on every load), which lies on the walk's chain of dependent
# loads (measured: cast pass 3-4 % faster).
_U = np.uint64


@njit(cache=True, inline="always")
def _slab(p0, d, inv_d, hi):
    """Parameter interval where p0 + d s lies in [0, hi] (``inv_d`` = 1 / d); (inf, -inf) when never."""
    if d == 0.0:
        if 0.0 <= p0 <= hi:
            return -_INF, _INF
        return _INF, -_INF
    a = (0.0 - p0) * inv_d
    b = (hi - p0) * inv_d
    if a > b:
        a, b = b, a
    return a, b


@njit(inline="always", **NO_NRT)
def cast_ray(u0, v0, z0, du, dv, dz, heights, mip, mip_off, mip_w, nlev, hmax):
    """First hit of one ray. Returns (s, surface, face, col, row) — see ``RayHits``.

    ``heights`` (H, W) float32; ``mip``/``mip_off``/``mip_w``/``nlev`` the maximum mipmap
    (``HeightField``); ``hmax`` the global maximum height (or any upper bound of the heights the ray
    can meet).
    """
    return cast_ray_from(u0, v0, z0, du, dv, dz, heights, mip, mip_off, mip_w, nlev, hmax, nlev, False)


@njit(inline="always", **NO_NRT)
def cast_ray_from(u0, v0, z0, du, dv, dz, heights, mip, mip_off, mip_w, nlev, hmax, lev0, inside):
    """``cast_ray`` starting its walk at mipmap level ``lev0`` (0 .. nlev; any level gives the same hit).

    ``inside``: the caller knows the ray stays over the map between heights ``hmax`` and 0 (its points
    there are inside the map, away from the edge), so the map-entry tests are skipped: they would give
    the start at height ``hmax`` and the end at the ground anyway.
    """
    rows, cols = heights.shape
    if not dz < 0.0:
        return np.nan, 0, 0, -1, -1
    inv_dz = 1.0 / -dz
    s_ground = z0 * inv_dz
    if s_ground < 0.0:
        s_ground = 0.0
    if hmax > 0.0:
        s_start = (z0 - hmax) * inv_dz
        if s_start < 0.0:
            s_start = 0.0
        inv_du = 1.0 / du if du != 0.0 else _INF
        inv_dv = 1.0 / dv if dv != 0.0 else _INF
        if inside:
            s_in = s_start
            s_out = s_ground
            su0 = sv0 = s_start
        else:
            su0, su1 = _slab(u0, du, inv_du, float(cols))
            sv0, sv1 = _slab(v0, dv, inv_dv, float(rows))
            s_in = max(su0, sv0)
            s_out = min(su1, sv1)
        s_a = max(s_start, s_in)
        s_end = min(s_out, s_ground)
        if s_a <= s_end and s_in <= s_out:
            # Axis crossed when entering the map at s_a (wall of an edge column), or -1.
            axis = -1
            if s_in > s_start:
                axis = 0 if su0 >= sv0 else 1
            um = u0 + du * s_a
            vm = v0 + dv * s_a
            col = int(math.floor(um))
            row = int(math.floor(vm))
            if du < 0.0 and um == math.floor(um):
                col -= 1
            if dv < 0.0 and vm == math.floor(vm):
                row -= 1
            col = min(max(col, 0), cols - 1)
            row = min(max(row, 0), rows - 1)
            step_c = 1 if du > 0.0 else -1
            step_r = 1 if dv > 0.0 else -1
            ou = 1 if du > 0.0 else 0
            ov = 1 if dv > 0.0 else 0
            s_cur = s_a
            lev = lev0
            if axis < 0 and heights[_U(row), _U(col)] >= z0 + dz * s_a:
                # The start point is already on or below its pixel's top (typically the tallest roof
                # under the ray's start height): the walk would descend to this pixel and stop there.
                h = heights[_U(row), _U(col)]
                if s_a >= (z0 - h) * inv_dz:
                    return s_a, 2 if h > 0.0 else 1, 0, col, row
            while True:
                if lev > 0:
                    size = 1 << lev
                    cx = col >> lev
                    cy = row >> lev
                    hm = mip[_U(mip_off[_U(lev)] + cy * mip_w[_U(lev)] + cx)]
                    s_hm = (z0 - hm) * inv_dz
                    if s_cur >= s_hm:
                        lev -= 1     # already below this cell's maximum: look at the finer level
                        continue
                    st_u = ((cx + ou) * size - u0) * inv_du if du != 0.0 else _INF
                    st_v = ((cy + ov) * size - v0) * inv_dv if dv != 0.0 else _INF
                    st_exit = min(st_u, st_v)
                    if st_exit <= s_hm:
                        # Above everything in this cell: jump to the next cell of this level.
                        if st_exit >= s_end:
                            break
                        if st_u <= st_v:
                            col = (cx + ou) * size - 1 + ou
                            vm = v0 + dv * st_u
                            row = min(max(int(math.floor(vm)), cy * size), cy * size + size - 1)
                            axis = 0
                        else:
                            row = (cy + ov) * size - 1 + ov
                            um = u0 + du * st_v
                            col = min(max(int(math.floor(um)), cx * size), cx * size + size - 1)
                            axis = 1
                        if st_exit > s_cur:
                            s_cur = st_exit
                        if col < 0 or col >= cols or row < 0 or row >= rows:
                            break
                        if lev < nlev:
                            lev += 1
                        continue
                    # The ray comes below this cell's maximum inside it: nothing can be hit before it
                    # reaches that height, so advance to there, then look at the finer level.
                    if s_hm >= s_end:
                        break
                    s_cur = s_hm
                    um = u0 + du * s_cur
                    vm = v0 + dv * s_cur
                    col = min(max(int(math.floor(um)), cx * size), cx * size + size - 1, cols - 1)
                    row = min(max(int(math.floor(vm)), cy * size), cy * size + size - 1, rows - 1)
                    axis = -1
                    # Often the pixel there is the one that holds the maximum: its roof is hit.
                    if heights[_U(row), _U(col)] >= hm:
                        return s_cur, 2 if hm > 0.0 else 1, 0, col, row
                    lev -= 1
                    continue
                # A map pixel: [s_cur, s_next) inside it, reaching its height at s_h.
                h = heights[_U(row), _U(col)]
                s_h = (z0 - h) * inv_dz
                sp_u = (col + ou - u0) * inv_du if du != 0.0 else _INF
                sp_v = (row + ov - v0) * inv_dv if dv != 0.0 else _INF
                s_next = min(sp_u, sp_v)
                if s_cur >= s_h:
                    if axis < 0:
                        return s_cur, 2 if h > 0.0 else 1, 0, col, row
                    if axis == 0:
                        face = 2 if du > 0.0 else 1
                    else:
                        face = 3 if dv > 0.0 else 4
                    return s_cur, 3, face, col, row
                if s_next >= s_h or s_next >= s_end:
                    if s_h <= s_end:
                        return s_h, 2 if h > 0.0 else 1, 0, col, row
                    break    # leaves the map before coming down to this pixel's height
                # Never backwards: a point found by rounding onto a pixel edge (um = 587.0000001 going
                # west) has that edge's crossing an ulp behind it; stepping back there put the ray
                # under the coarser cell's maximum again, which sent it forward to the same point:
                # an endless loop on DSMs with equal neighbouring heights (whole centimetres).
                if s_next > s_cur:
                    s_cur = s_next
                if sp_u <= sp_v:
                    col += step_c
                    axis = 0
                else:
                    row += step_r
                    axis = 1
                if col < 0 or col >= cols or row < 0 or row >= rows:
                    break
                if nlev > 0:
                    lev = 1
    # The ground: outside the map, or the march left the map above every column.
    ug = u0 + du * s_ground
    vg = v0 + dv * s_ground
    return s_ground, 1, 0, int(math.floor(ug)), int(math.floor(vg))


@njit(**NO_NRT)
def _first_hits_kernel(u0, v0, z0, du, dv, dz, heights, mip, mip_off, mip_w, nlev, hmax,
                       out_s, out_surf, out_face, out_col, out_row):
    for i in range(u0.shape[0]):
        s, surf, face, col, row = cast_ray(u0[i], v0[i], z0[i], du[i], dv[i], dz[i], heights, mip, mip_off, mip_w,
                                           nlev, hmax)
        out_s[i] = s
        out_surf[i] = surf
        out_face[i] = face
        out_col[i] = col
        out_row[i] = row


def first_hits(field: HeightField, origins_enu_m: np.ndarray, directions_enu: np.ndarray) -> RayHits:
    """First intersection of each ray (origin ENU m, direction ENU, any length) with the surface."""
    o = np.asarray(origins_enu_m, dtype=np.float64)
    d = np.asarray(directions_enu, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(f"origins {o.shape} / directions {d.shape}: expected two (N, 3) arrays")
    rows, cols = field.shape
    m = field.m_per_px
    u0 = np.ascontiguousarray(o[:, 0] / m + cols / 2.0)
    v0 = np.ascontiguousarray(rows / 2.0 - o[:, 1] / m)
    z0 = np.ascontiguousarray(o[:, 2])
    du = np.ascontiguousarray(d[:, 0] / m)
    dv = np.ascontiguousarray(-d[:, 1] / m)
    dz = np.ascontiguousarray(d[:, 2])
    n = o.shape[0]
    s = np.empty(n, dtype=np.float64)
    surf = np.empty(n, dtype=np.uint8)
    face = np.empty(n, dtype=np.uint8)
    col = np.empty(n, dtype=np.int64)
    row = np.empty(n, dtype=np.int64)
    _first_hits_kernel(u0, v0, z0, du, dv, dz, field.heights_m, field.mip, field.mip_off, field.mip_w,
                       field.levels, field.max_height_m,
                       s, surf, face, col, row)
    with np.errstate(invalid="ignore"):
        u = u0 + du * s
        v = v0 + dv * s
        z = z0 + dz * s
    hit_h = np.where(surf == Surface.MISS, np.nan, np.maximum(z, 0.0))
    # Tops and ground sit exactly at the column height (the formula can be off by an ulp).
    top = (surf == Surface.TOP) | (surf == Surface.GROUND)
    inside = top & (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    hit_h[top] = 0.0
    hit_h[inside] = field.heights_m[row[inside], col[inside]]
    return RayHits(u_px=u, v_px=v, height_m=hit_h, surface=surf, wall_face=face,
                   col_px=col, row_px=row, range_s=s)


# ---------------------------------------------------------------------------------------------
# Shading.

@njit(cache=True, inline="always")
def window_glass(along_m, z_m):
    """True where the facade point (along-wall metres, height metres) is a window pane."""
    fz = z_m - math.floor(z_m / FLOOR_HEIGHT_M) * FLOOR_HEIGHT_M
    if fz < WINDOW_SILL_M or fz >= WINDOW_SILL_M + WINDOW_HEIGHT_M:
        return False
    fa = along_m - math.floor(along_m / WINDOW_PITCH_M) * WINDOW_PITCH_M
    lo = 0.5 * (WINDOW_PITCH_M - WINDOW_WIDTH_M)
    return lo <= fa < lo + WINDOW_WIDTH_M


@njit(**NO_NRT)
def shade_hit(surf, face, col, row, u, v, z, top_rgb, rows, cols, lod, facade_rgb, has_facade, grey, m_per_px,
              face_light, out, k):
    """Write the colour of one hit into ``out[k]`` (see ``shade``).

    ``top_rgb`` is the texture at level of detail ``lod`` (``lod_texture``) of a map of ``rows`` x
    ``cols`` pixels; ``col``/``row`` are map pixel indices.
    """
    if surf == 0:
        out[k, 0] = grey
        out[k, 1] = grey
        out[k, 2] = grey
        return
    if surf != 3:
        if col < 0 or col >= cols or row < 0 or row >= rows:
            out[k, 0] = grey
            out[k, 1] = grey
            out[k, 2] = grey
            return
        if lod > 1:
            tr = row // lod
            tc = col // lod
        else:
            tr = row
            tc = col
        out[k, 0] = top_rgb[tr, tc, 0]
        out[k, 1] = top_rgb[tr, tc, 1]
        out[k, 2] = top_rgb[tr, tc, 2]
        return
    if has_facade:
        r = float(facade_rgb[row, col, 0])
        g = float(facade_rgb[row, col, 1])
        b = float(facade_rgb[row, col, 2])
        if r == 0.0 and g == 0.0 and b == 0.0:
            has = False
        else:
            has = True
    else:
        has = False
    if not has:
        # No facade colour: the top colour of the pixel (at the level of detail), darkened.
        if lod > 1:
            tr = row // lod
            tc = col // lod
        else:
            tr = row
            tc = col
        r = NO_FACADE_FACTOR * float(top_rgb[tr, tc, 0])
        g = NO_FACADE_FACTOR * float(top_rgb[tr, tc, 1])
        b = NO_FACADE_FACTOR * float(top_rgb[tr, tc, 2])
    if face == 1 or face == 2:
        along = v * m_per_px
    else:
        along = u * m_per_px
    f = face_light[face]
    if window_glass(along, z):
        f *= GLASS_FACTOR
    out[k, 0] = min(255, int(r * f + 0.5))
    out[k, 1] = min(255, int(g * f + 0.5))
    out[k, 2] = min(255, int(b * f + 0.5))


@njit(**NO_NRT)
def _shade_kernel(surf, face, col, row, u, v, z, top_rgb, rows, cols, lod, facade_rgb, has_facade, grey,
                  m_per_px, face_light, out):
    for k in range(surf.shape[0]):
        shade_hit(surf[k], face[k], col[k], row[k], u[k], v[k], z[k], top_rgb, rows, cols, lod, facade_rgb,
                  has_facade, grey, m_per_px, face_light, out, k)


def lod_texture(top_rgb: np.ndarray, lod: int, outside_grey_level: int = 128) -> np.ndarray:
    """Level-of-detail texture: the mean of each L x L block of map pixels (blocks aligned to multiples
    of L, a partial block at the east/south edge padded with ``outside_grey_level``), via
    ``cv2.resize(INTER_AREA)`` exactly as ``sitl.camera``'s ground windows."""
    import cv2

    if lod <= 1:
        return top_rgb
    rows, cols = top_rgb.shape[:2]
    pr, pc = -(-rows // lod) * lod, -(-cols // lod) * lod
    src = top_rgb
    if (pr, pc) != (rows, cols):
        src = np.full((pr, pc, 3), outside_grey_level, dtype=np.uint8)
        src[:rows, :cols] = top_rgb
    return np.ascontiguousarray(cv2.resize(src, (pc // lod, pr // lod), interpolation=cv2.INTER_AREA))


def shade(hits: RayHits, top_rgb: np.ndarray, facade_rgb: np.ndarray | None = None, *, m_per_px: float,
          lod: int = 1, outside_grey_level: int = 128, lod_rgb: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) uint8 colours of the hits.

    Ground and roofs: the nearest texel of ``top_rgb`` ((H, W, 3) uint8) at level of detail ``lod``
    (``lod_rgb`` = ``lod_texture(top_rgb, lod)`` if already computed); outside the map and misses:
    ``outside_grey_level``. Walls: ``facade_rgb`` at the wall's pixel (black = none there; with no
    facade colour the top colour times ``NO_FACADE_FACTOR``) times the face's light factor
    (``FACE_LIGHT``), and times ``GLASS_FACTOR`` on window panes (``window_glass``).
    """
    top = np.ascontiguousarray(top_rgb, dtype=np.uint8)
    tex = lod_rgb if lod_rgb is not None else lod_texture(top, lod, outside_grey_level)
    fac = (np.ascontiguousarray(facade_rgb, dtype=np.uint8) if facade_rgb is not None
           else np.zeros((1, 1, 3), dtype=np.uint8))
    out = np.empty((len(hits), 3), dtype=np.uint8)
    z = np.nan_to_num(hits.height_m, nan=0.0)
    u = np.nan_to_num(hits.u_px, nan=0.0)
    v = np.nan_to_num(hits.v_px, nan=0.0)
    _shade_kernel(hits.surface, hits.wall_face, hits.col_px, hits.row_px, u, v, z,
                  tex, top.shape[0], top.shape[1], lod, fac, facade_rgb is not None, int(outside_grey_level),
                  float(m_per_px), FACE_LIGHT, out)
    return out

