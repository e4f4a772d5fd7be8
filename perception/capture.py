"""Captures for perception's offline tools: what the camera sees at a pose, and the map it is matched on.

The dataset builder, the matchability labelling, the labelling comparison and the assistant-map
builder all need "the nadir camera image over map position (u, v) at heading h from altitude a".
:class:`CaptureScene` is the one place that image is made:

* **relief** (``CaptureSettings.relief``, default true): when the world has a surface model
  (``World.dsm_m``) the capture is rendered in true perspective from the camera's pose by
  ``worlds.view_renderer.CityRenderer`` (ray casting the DSM: buildings lean away from the nadir
  point, facades show, streets behind blocks are hidden, trees stand above the ground). On a flat
  world, or with relief off, it is exactly today's image: one bilinear warp of the orthophoto
  (``perception.matchability.render_camera``; dataset crops ``perception.dataset_images.render_crop``).
* **reference** (``CaptureSettings.reference``): the map the capture is matched against:
  ``default`` (the kind the world's manifest names), ``orthophoto`` (``reference.png``, the other day
  as a true orthophoto) or ``perspective`` (``reference_perspective.png``, taken from
  ``manifest.reference.camera_height_m`` above the map centre, as the paper's 500 m reference).
* **misregistration**: the reference draws the ground point at world (x, y) at (x, y) +
  ``manifest.reference.offset_m(x, y)``; ``true_match_uv`` is where a perfect match of a capture over
  (u, v) lands, and every error these tools measure is against it.

Pose conventions (scenenav/core/frames.py): the camera looks straight down; image up is the compass
heading h (clockwise from north), so in world ENU image right = (cos h, -sin h, 0), image up =
(sin h, cos h, 0) and minus the optical axis = (0, 0, 1); the footprint side is ``2 a tan(fov / 2)``
(scenenav/core/camera_geometry.py).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from perception.alignment import to_gray_float32
from scenenav.core import frames
from scenenav.core.errors import UserError
from scenenav.core.formats.world_manifest import ReferenceInfo, ReferenceKind

log = logging.getLogger(__name__)

#: Grey level the relief renderer gives rays that leave the map (mid grey, like sitl.camera).
OUTSIDE_GREY_LEVEL = 128


class ReferenceChoice(str, Enum):
    """Which reference map the captures are matched against."""

    DEFAULT = "default"            # the manifest's reference.kind
    ORTHOPHOTO = "orthophoto"
    PERSPECTIVE = "perspective"


@dataclass(frozen=True)
class CaptureSettings:
    """How offline tools capture: with relief (when the world has a DSM) and against which reference."""

    relief: bool = True
    reference: ReferenceChoice = ReferenceChoice.DEFAULT

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "reference", ReferenceChoice(self.reference))
        except ValueError:
            raise UserError(f"reference = {self.reference!r}: expected default, orthophoto or "
                            f"perspective") from None


def nadir_axes(heading_rad: float) -> tuple[tuple[float, float, float], ...]:
    """World ENU directions (right, up, back) of a nadir camera's image at compass ``heading_rad``."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return (c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)


@dataclass(eq=False)
class CaptureScene:
    """A world as the offline tools capture it (see the module docstring).

    ``camera_gray``: the day the camera sees (the orthophoto), grey float32 in [0, 1];
    ``reference_gray``: the chosen reference map, grey float32; ``heights_m``: the DSM when captures
    are rendered with relief, else None (today's flat warp); ``camera_rgb`` / ``facade_rgb``: what the
    relief renderer draws roofs, ground and walls with.
    """

    camera_gray: np.ndarray
    reference_gray: np.ndarray
    m_per_px: float
    heights_m: np.ndarray | None = None
    camera_rgb: np.ndarray | None = None
    facade_rgb: np.ndarray | None = None
    reference_info: ReferenceInfo = field(default_factory=ReferenceInfo)
    reference_kind: ReferenceKind = ReferenceKind.ORTHOPHOTO
    _renderer: object = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.heights_m is not None and self.camera_rgb is None:
            raise ValueError("a relief scene needs camera_rgb (the texture the renderer draws)")

    @classmethod
    def flat(cls, camera_gray: np.ndarray, reference_gray: np.ndarray, m_per_px: float) -> "CaptureScene":
        """Today's scene: the camera sees ``camera_gray`` lying flat; no misregistration stated."""
        return cls(camera_gray=camera_gray, reference_gray=reference_gray, m_per_px=float(m_per_px))

    @classmethod
    def from_world(cls, world, settings: CaptureSettings | None = None) -> "CaptureScene":
        """The scene of a ``worlds.world.World`` under ``settings`` (default: relief on, default reference)."""
        st = settings or CaptureSettings()
        info = world.manifest.reference
        kind = info.kind if st.reference is ReferenceChoice.DEFAULT else ReferenceKind(st.reference.value)
        reference = world.reference_map(kind)
        relief = st.relief and world.dsm_m is not None
        return cls(camera_gray=to_gray_float32(world.orthophoto), reference_gray=to_gray_float32(reference),
                   m_per_px=float(world.m_per_px), heights_m=world.dsm_m if relief else None,
                   camera_rgb=world.orthophoto if relief else None,
                   facade_rgb=world.facade_rgb if relief else None,
                   reference_info=info, reference_kind=kind)

    def with_reference(self, reference_gray: np.ndarray, kind: ReferenceKind) -> "CaptureScene":
        """The same captures (and the same renderer, built once) matched against another reference."""
        return replace(self, reference_gray=reference_gray, reference_kind=kind, _renderer=self.renderer())

    @property
    def relief(self) -> bool:
        """Captures are rendered in perspective from a DSM (False: today's flat warp)."""
        return self.heights_m is not None

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.camera_gray.shape[0]), int(self.camera_gray.shape[1]))

    def renderer(self):
        """The relief renderer of this scene (built on first use; None on a flat scene)."""
        if self.heights_m is None:
            return None
        if self._renderer is None:
            from worlds.view_renderer import CityRenderer
            self._renderer = CityRenderer(self.camera_rgb, self.m_per_px, heights_m=self.heights_m,
                                          facade_rgb=self.facade_rgb, outside_grey_level=OUTSIDE_GREY_LEVEL)
        return self._renderer

    # ------------------------------------------------------------------------------ captures
    def camera_image(self, u: float, v: float, heading_rad: float, altitude_m: float, fov_deg: float,
                     camera_px: int) -> np.ndarray:
        """The ``camera_px`` x ``camera_px`` nadir capture (grey float32 [0, 1]) over continuous map
        pixel (u, v) at compass ``heading_rad`` from ``altitude_m`` above the ground."""
        if self.heights_m is None:
            from perception.matchability import render_camera
            return render_camera(self.camera_gray, u, v, heading_rad, altitude_m, fov_deg, self.m_per_px,
                                 camera_px)
        return self._relief_view(u, v, heading_rad, altitude_m, fov_deg, camera_px)

    def footprint_image(self, u: float, v: float, crop_px: int, out_px: int, fov_deg: float,
                        angle_rad: float = 0.0, scale: float = 1.0, flip: bool = False) -> np.ndarray:
        """A dataset image: the ground square of side ``crop_px * scale`` map pixels centred on (u, v),
        image up at compass ``angle_rad``, optionally mirrored, as ``out_px`` x ``out_px`` grey float32.

        Flat: ``render_crop`` (today's crop). Relief: the nadir capture whose footprint is that square
        (altitude ``crop_px * scale * m_per_px / (2 tan(fov / 2))``), mirrored left-right when ``flip``.
        """
        if self.heights_m is None:
            from perception.dataset_images import render_crop
            return render_crop(self.camera_gray, u, v, crop_px, out_px, angle_rad, scale, flip)
        altitude = crop_px * scale * self.m_per_px / (2.0 * math.tan(math.radians(fov_deg) / 2.0))
        img = self._relief_view(u, v, angle_rad, altitude, fov_deg, out_px)
        return np.ascontiguousarray(img[:, ::-1]) if flip else img

    def _relief_view(self, u: float, v: float, heading_rad: float, altitude_m: float, fov_deg: float,
                     px: int) -> np.ndarray:
        h, w = self.shape
        x, y = frames.pixel_to_world(u, v, w, h, self.m_per_px)
        right, up, back = nadir_axes(heading_rad)
        t = math.tan(math.radians(fov_deg) / 2.0)
        rgb = self.renderer().render((float(x), float(y), float(altitude_m)), right, up, back, px, px, t, t)
        return to_gray_float32(rgb)

    # ------------------------------------------------------------------------------ truth
    def true_match_uv(self, u, v):
        """Where a perfect match of a capture over continuous map pixel (u, v) lands in the reference
        (the stated misregistration applied); works on floats and arrays."""
        info = self.reference_info
        if not info.warp and info.shift_east_m == 0.0 and info.shift_north_m == 0.0:
            return u, v                   # no misregistration: exactly (u, v), no round trip
        h, w = self.shape
        x, y = frames.pixel_to_world(u, v, w, h, self.m_per_px)
        dx, dy = info.offset_m(x, y)
        return frames.world_to_pixel(x + dx, y + dy, w, h, self.m_per_px)
