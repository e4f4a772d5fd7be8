"""Land-cover classes and junction ground truth for scenenav worlds.

A world's ``landcover`` raster is an (H, W) uint8 array of :class:`LandCover` values, aligned
pixel for pixel with the orthophoto (see ``scenenav/core/frames.py`` for the pixel convention).
Junctions are road-graph nodes with two or more arms, in continuous pixel coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, IntEnum

import numpy as np


class LandCover(IntEnum):
    """Ground-truth surface class of one pixel (value stored in ``landcover.png``)."""

    UNKNOWN = 0            # unclassified / other ground: sidewalks, kerbs, paved yards, beaches
    ROAD = 1               # carriageway incl. lane markings and crossings (cars do not change it)
    BUILDING_UNIFORM = 2   # large flat roofs of one tone without details (identical halls)
    BUILDING_TEXTURED = 3  # roofs with tones, ridges, HVAC boxes, parapets
    SQUARE = 4             # large paved pedestrian square
    PARKING = 5            # parking lot surface incl. stall lines
    GRASS = 6              # lawns, parks, courtyard gardens
    FOREST = 7             # tree canopy (forests, tree clusters)
    WATER = 8              # lakes and rivers


#: Surfaces that give a flat or ambiguous correlation surface (seed paper, section 4.2).
BAD_MATCHING_COVERS: frozenset[LandCover] = frozenset({
    LandCover.SQUARE, LandCover.GRASS, LandCover.FOREST, LandCover.WATER,
    LandCover.BUILDING_UNIFORM,
})

#: Display colours (RGB) used by previews and documented in docs/worlds.md.
LANDCOVER_COLOURS_RGB: dict[LandCover, tuple[int, int, int]] = {
    LandCover.UNKNOWN: (200, 200, 200),
    LandCover.ROAD: (60, 60, 60),
    LandCover.BUILDING_UNIFORM: (150, 60, 200),
    LandCover.BUILDING_TEXTURED: (220, 90, 60),
    LandCover.SQUARE: (240, 200, 80),
    LandCover.PARKING: (120, 120, 170),
    LandCover.GRASS: (120, 210, 90),
    LandCover.FOREST: (20, 110, 40),
    LandCover.WATER: (50, 110, 220),
}


def colourise(landcover: np.ndarray) -> np.ndarray:
    """(H, W) LandCover values -> (H, W, 3) uint8 RGB display image (unknown values -> black)."""
    lut = np.zeros((256, 3), dtype=np.uint8)
    for cover, rgb in LANDCOVER_COLOURS_RGB.items():
        lut[int(cover)] = rgb
    return lut[np.asarray(landcover, dtype=np.uint8)]


def cover_shares(landcover: np.ndarray) -> dict[LandCover, float]:
    """Fraction of pixels of each class (all classes present as keys, summing to 1)."""
    counts = np.bincount(np.asarray(landcover, dtype=np.uint8).ravel(), minlength=256)
    total = max(int(counts.sum()), 1)
    return {cover: float(counts[int(cover)]) / total for cover in LandCover}


class JunctionKind(str, Enum):
    """Shape of a road-graph node with two or more arms."""

    CROSS = "cross"    # four or more arms
    TEE = "tee"        # three arms, two of them roughly opposite, the third roughly perpendicular
    WYE = "wye"        # three arms otherwise (a fork, or one arm at an acute angle)
    CORNER = "corner"  # two arms meeting at a sharp angle (below ~120 degrees)
    BEND = "bend"      # two arms meeting at an obtuse angle (~120..155 degrees)


@dataclass(frozen=True)
class Junction:
    """One road junction, from the road graph (not from image analysis).

    ``u_px, v_px`` are continuous pixel coordinates (column, row; row 0 north) of the node,
    ``arms`` the number of roads leaving it, ``kind`` its shape.
    """

    u_px: float
    v_px: float
    arms: int
    kind: JunctionKind

    def to_dict(self) -> dict:
        return {"u_px": self.u_px, "v_px": self.v_px, "arms": self.arms, "kind": self.kind.value}

    @classmethod
    def from_dict(cls, data: dict) -> "Junction":
        """Build from a mapping; raises KeyError/ValueError/TypeError on malformed input."""
        u = float(data["u_px"])
        v = float(data["v_px"])
        arms = data["arms"]
        if isinstance(arms, bool) or not isinstance(arms, int) or arms < 2:
            raise ValueError(f"arms = {arms!r}: expected an integer >= 2")
        if not (np.isfinite(u) and np.isfinite(v)):
            raise ValueError("u_px/v_px must be finite numbers")
        return cls(u_px=u, v_px=v, arms=arms, kind=JunctionKind(data["kind"]))


#: Angle limits (degrees) used by :func:`classify_arms`.
STRAIGHT_MIN_DEG = 155.0   # two arms at least this far apart are a (curving) road, not a junction
CORNER_MAX_DEG = 120.0     # two arms closer than this are a corner, else a bend
TEE_OPPOSITE_MIN_DEG = 150.0
TEE_SIDE_MIN_DEG = 65.0


def classify_arms(arm_angles_rad) -> JunctionKind | None:
    """Junction kind from the directions of the arms leaving a node (any angle convention).

    Returns None for nodes that are not junctions (fewer than two arms, or a straight road).
    """
    angles = np.sort(np.mod(np.asarray(arm_angles_rad, dtype=float), 2.0 * np.pi))
    n = angles.size
    if n < 2:
        return None
    if n >= 4:
        return JunctionKind.CROSS
    gaps = np.degrees(np.diff(np.concatenate([angles, angles[:1] + 2.0 * np.pi])))
    if n == 2:
        between = min(gaps[0], gaps[1])
        if between >= STRAIGHT_MIN_DEG:
            return None
        return JunctionKind.CORNER if between < CORNER_MAX_DEG else JunctionKind.BEND
    if gaps.max() >= TEE_OPPOSITE_MIN_DEG and gaps.min() >= TEE_SIDE_MIN_DEG:
        return JunctionKind.TEE
    return JunctionKind.WYE
