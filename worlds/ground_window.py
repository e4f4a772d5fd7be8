"""The ground window: which part of the map, at which level of detail, a camera draws.

Only a window of ``N`` x ``N`` texels of the map is ever drawn, whatever the map size, so the
per-frame cost does not depend on the map. The window covers ``N * L`` x ``N * L`` map pixels, where
L (1, 2, 4, ...) is the level of detail: each texel is the mean of an L x L block of map pixels
(blocks aligned to multiples of L). L follows the altitude so that a texel is about one image pixel
(between 1/2.5 and 1.25 image pixels), which is also what a real camera integrates; L = 1 (full map
resolution) whenever the image is finer than the map. Texels outside the map are plain grey, and a
grey frame surrounds the window (seen only by a tilted FIXED camera).

Before every render the camera footprint (ground intersection of the image corners) is checked
against the window; when it comes within a margin of the edge (or L must change) the window is
re-centred on the footprint, snapped to whole map pixels (multiples of L). The placement depends on
the history of poses (hysteresis on L), exactly as the TinyRenderer camera always did: both
renderers (``worlds.view_renderer.CityRenderer`` and ``sitl.mesh_camera.MeshCamera``) use this one
class, so they draw the same texels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# A tilted FIXED camera sees ground up to the horizon: its footprint is clipped at this many heights.
MAX_RANGE_HEIGHTS = 6.0
# Extent of the grey frame around the window, beyond the window edge, m.
FRAME_MARGIN_M = 10000.0
# Level-of-detail hysteresis, in map pixels per image pixel over L.
LOD_TOO_FINE = 2.5
LOD_TOO_COARSE = 0.8

Vec3 = tuple[float, float, float]


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

    def centre_m(self, map_w: int, map_h: int, m_per_px: float) -> tuple[float, float]:
        """ENU position (x, y) of the window centre."""
        return ((self.col0_px + 0.5 * self.span_px - 0.5 * map_w) * m_per_px,
                (0.5 * map_h - self.row0_px - 0.5 * self.span_px) * m_per_px)

    def half_m(self, m_per_px: float) -> float:
        """Half the window side, m."""
        return 0.5 * self.span_px * m_per_px


def pow2_floor(x: float) -> int:
    return 1 << max(0, int(math.floor(math.log2(max(x, 1.0)))))


def pow2_ceil(x: float) -> int:
    return 1 << max(0, int(math.ceil(math.log2(max(x, 1.0)))))


class WindowTracker:
    """Keeps the current ``GroundWindow`` of one camera and re-places it when the footprint needs it."""

    def __init__(self, map_w: int, map_h: int, m_per_px: float, size_texels: int, width_px: int,
                 tan_x: float, tan_y: float) -> None:
        self.map_w, self.map_h = int(map_w), int(map_h)
        self.m_per_px = float(m_per_px)
        self.size_texels = int(size_texels)
        self.width_px = int(width_px)
        self.tan_x, self.tan_y = float(tan_x), float(tan_y)
        self.margin_texels = max(2, self.size_texels // 32)
        self.window: GroundWindow | None = None
        self.builds = 0

    def footprint(self, eye: Vec3, right: Vec3, up: Vec3, back: Vec3) -> tuple[float, float, float, float, float]:
        """(u_min, u_max, v_min, v_max, map px per image px) of the ground seen, map pixel coordinates."""
        h = eye[2]
        max_range = MAX_RANGE_HEIGHTS * h
        xs, ys = [], []
        centre_range = h
        for a, b in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0), (0.0, 0.0)):
            ax, by = a * self.tan_x, b * self.tan_y
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
        u = [x / m + self.map_w / 2.0 for x in xs]
        v = [self.map_h / 2.0 - y / m for y in ys]
        # Ground sampling along the optical axis, in map pixels per image pixel.
        ratio = 2.0 * centre_range * self.tan_x / m / self.width_px
        return min(u), max(u), min(v), max(v), ratio

    def update(self, eye: Vec3, right: Vec3, up: Vec3, back: Vec3) -> bool:
        """Re-place the window if the footprint needs it; True when it changed."""
        u0, u1, v0, v1, ratio = self.footprint(eye, right, up, back)
        n = self.size_texels
        extent = max(u1 - u0, v1 - v0)
        lod_fit = pow2_ceil(extent / (0.5 * n))
        win = self.window
        if win is not None:
            lod = win.lod
            margin = self.margin_texels * lod
            inside = (u0 >= win.col0_px + margin and u1 <= win.col0_px + win.span_px - margin
                      and v0 >= win.row0_px + margin and v1 <= win.row0_px + win.span_px - margin)
            too_fine = ratio >= LOD_TOO_FINE * lod
            too_coarse = lod > 1 and lod > lod_fit and ratio < LOD_TOO_COARSE * lod
            if inside and not too_fine and not too_coarse:
                return False
        lod = max(pow2_floor(ratio), lod_fit)
        span = n * lod
        margin = self.margin_texels * lod
        col0 = self._place_axis(u0, u1, self.map_w, span, lod, margin)
        row0 = self._place_axis(v0, v1, self.map_h, span, lod, margin)
        self.window = GroundWindow(col0, row0, n, lod)
        self.builds += 1
        return True

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
