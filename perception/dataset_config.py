"""What determines a CNN dataset (``DatasetConfig``, the augmentation recipe) and its checks.

See ``perception.dataset`` for how a dataset is built.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from enum import Enum

from perception.capture import CaptureSettings
from perception.cnn_spec import PAPER_INPUT_PX, Labelling, MatchClass
from perception.matchability import MatchabilityConfig, footprint_px
from scenenav.core.errors import UserError

log = logging.getLogger(__name__)


EVAL_WORLD_SEEDS: tuple[int, ...] = (9001, 9002)
"""World seeds reserved for held-out evaluation (``scenenav cnn compare``); never used for training."""


WORLD_SEEDS_PER_DATASET_SEED = 1000


class CropGeometry(str, Enum):
    """How a base crop is cut (docs/cnn.md, "Two ways to cut the crops").

    ``FOOTPRINT``: the camera footprint at the flight altitude (217 px = 115 m at 100 m, 60 deg,
    0.53 m/px), what the network sees in flight; in a city grid it holds several junctions.
    ``INTERSECTION``: the paper's way (5.2, "cropped ... for real intersections"): a smaller square
    around one junction with no other junction inside it, so the arm count is the image's.
    """

    FOOTPRINT = "footprint"
    INTERSECTION = "intersection"


class ArmLabels(str, Enum):
    """Which junction crops are kept (docs/cnn.md, "Why three-arm junctions are confused").

    ``GRAPH``: every junction, labelled by its road-graph degree (what the generator built).
    ``VISIBLE``: only junctions whose crop shows that many arms in the road raster
    (``perception.dataset_arms``: roads connected to the junction that reach the circle at 45 % of
    the crop side, no square or parking lot filling the ring), as a person labelling by eye would
    keep them; the others are dropped and counted in the manifest.
    """

    GRAPH = "graph"
    VISIBLE = "visible"


class IntersectionView(str, Enum):
    """From where an intersection crop is captured (relief worlds; flat worlds look the same).

    ``CROP``: the nadir camera whose 60 deg footprint is the crop square (43 m up for a 50 m crop):
    roofs lean far over the streets near the crop border.
    ``FLIGHT``: the central square of the flight camera's image at ``altitude_m`` (100 m), i.e. the
    junction as the drone sees it (a narrower field of view from the flight altitude).
    """

    CROP = "crop"
    FLIGHT = "flight"


@dataclass(frozen=True)
class AugmentRecipe:
    """Random transforms of one augmented copy (uniform ranges)."""

    rotation_deg: tuple[float, float] = (0.0, 360.0)
    flip_probability: float = 0.5
    scale: tuple[float, float] = (0.9, 1.1)
    log_gamma: tuple[float, float] = (-0.3, 0.3)
    gain: tuple[float, float] = (0.75, 1.25)
    offset: tuple[float, float] = (-0.08, 0.08)
    blur_sigma_px: tuple[float, float] = (0.0, 1.2)
    noise_sigma: tuple[float, float] = (0.0, 0.03)


@dataclass(frozen=True)
class DatasetConfig:
    """Everything that determines a dataset (stored in its manifest)."""

    n_worlds: int = 12
    seed: int = 0
    labelling: Labelling = Labelling.PAPER
    base_crops: int = 1500
    augment_to: int = 3920
    world_width_px: int = 2000
    world_height_px: int = 2000
    m_per_px: float = 0.53
    altitude_m: float = 100.0
    fov_deg: float = 60.0
    image_px: int = PAPER_INPUT_PX
    bad_min_share: float = 0.6
    junction_jitter_px: float = 40.0
    crop: CropGeometry = CropGeometry.FOOTPRINT
    # INTERSECTION crops: side in metres (median junction spacing in generated cities is ~59 m, so a
    # 50 m square holds one junction ~96 % of the time) and the centre jitter in map pixels.
    intersection_crop_m: float = 50.0
    intersection_jitter_px: float = 10.0
    intersection_view: IntersectionView = IntersectionView.CROP
    arms: ArmLabels = ArmLabels.GRAPH
    max_crops_per_junction: int = 3
    bad_min_spacing_px: int = 24
    validate_global_n: int = 16
    matchability_extra_positions: int = 2000
    augment: AugmentRecipe = field(default_factory=AugmentRecipe)
    matchability: MatchabilityConfig = field(default_factory=MatchabilityConfig)
    # Captures with relief when the world has a DSM (false: today's flat crops), matched against
    # the default / orthophoto / perspective reference (perception/capture.py).
    capture: CaptureSettings = field(default_factory=CaptureSettings)

    def world_seeds(self) -> tuple[int, ...]:
        return training_world_seeds(self.seed, self.n_worlds)

    def crop_px(self) -> int:
        """Side of a base crop in map pixels."""
        if self.crop is CropGeometry.INTERSECTION:
            return max(8, round(self.intersection_crop_m / self.m_per_px))
        return footprint_px(self.altitude_m, self.fov_deg, self.m_per_px)

    def crop_fov_deg(self) -> float:
        """Field of view the crops are captured with (``footprint_image``'s altitude follows from it)."""
        if self.crop is CropGeometry.INTERSECTION and self.intersection_view is IntersectionView.FLIGHT:
            return math.degrees(2.0 * math.atan(self.crop_px() * self.m_per_px / (2.0 * self.altitude_m)))
        return self.fov_deg

    def jitter_px(self) -> float:
        """Uniform jitter of a junction crop's centre, map pixels."""
        return self.intersection_jitter_px if self.crop is CropGeometry.INTERSECTION else self.junction_jitter_px

    def isolated_junctions_only(self) -> bool:
        """Junction crops only where no other junction lies inside the crop."""
        return self.crop is CropGeometry.INTERSECTION


def training_world_seeds(seed: int, n_worlds: int) -> tuple[int, ...]:
    """World seeds used for a dataset built with ``--seed seed --worlds n_worlds``."""
    return tuple(1 + WORLD_SEEDS_PER_DATASET_SEED * seed + i for i in range(n_worlds))


def check_config(cfg: DatasetConfig) -> None:
    """One-line UserError for out-of-range settings."""
    if cfg.n_worlds < 1 or cfg.n_worlds >= WORLD_SEEDS_PER_DATASET_SEED:
        raise UserError(f"--worlds = {cfg.n_worlds}: expected an integer in [1, {WORLD_SEEDS_PER_DATASET_SEED - 1}]")
    if cfg.seed < 0:
        raise UserError(f"--seed = {cfg.seed}: expected an integer >= 0")
    clash = sorted(set(cfg.world_seeds()) & set(EVAL_WORLD_SEEDS))
    if clash:
        raise UserError(f"--seed {cfg.seed} --worlds {cfg.n_worlds}: world seed {clash[0]} is reserved for "
                        f"held-out evaluation (use another --seed)")
    if cfg.base_crops < len(MatchClass):
        raise UserError(f"--base-crops = {cfg.base_crops}: expected at least {len(MatchClass)}")
    if cfg.augment_to < cfg.base_crops:
        raise UserError(f"--augment-to = {cfg.augment_to}: expected >= --base-crops ({cfg.base_crops})")
    if cfg.crop is CropGeometry.INTERSECTION and cfg.labelling is Labelling.MATCHABILITY:
        raise UserError("--crop intersection with --labelling matchability: the matchability labelling scores "
                        "camera footprints; use --crop footprint (or --labelling paper)")
    if cfg.crop is CropGeometry.INTERSECTION and not 5.0 <= cfg.intersection_crop_m <= 500.0:
        raise UserError(f"--intersection-crop-m = {cfg.intersection_crop_m}: expected metres in [5, 500]")
    if cfg.crop is not CropGeometry.INTERSECTION and (cfg.arms is not ArmLabels.GRAPH
                                                      or cfg.intersection_view is not IntersectionView.CROP):
        raise UserError("--arms visible / --intersection-view flight: for --crop intersection only (a footprint "
                        "holds several junctions)")
    crop = cfg.crop_px()
    jitter = cfg.jitter_px()
    if min(cfg.world_width_px, cfg.world_height_px) < crop + 2 * jitter + 8:
        raise UserError(f"world size {cfg.world_width_px}x{cfg.world_height_px} px: expected both sides > "
                        f"{crop + 2 * jitter + 8:.0f} px (a crop is {crop} px)")
