"""Settings of CNN training and of the labelling comparison, without torch (perception.training
trains; these are also the command line's defaults, which must not cost a torch import)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from perception.cnn_spec import DEFAULT_INPUT_PX, check_input_px
from perception.dataset_config import EVAL_WORLD_SEEDS
from scenenav.core.errors import UserError


class SplitMethod(str, Enum):
    """How the 80/20 split is drawn."""

    GROUPED = "grouped"   # whole spatial tiles, stratified by class (no augmented copy straddles the split)
    RANDOM = "random"     # image-level, stratified by class (the paper's presumable Keras split; leaks copies)


@dataclass(frozen=True)
class TrainConfig:
    """Training hyper-parameters (stored in the training record)."""

    epochs: int = 30
    seed: int = 0
    input_px: int = DEFAULT_INPUT_PX
    batch_size: int = 32
    learning_rate: float = 1e-3
    val_share: float = 0.2
    num_threads: int = 2
    split: str = "grouped"           # SplitMethod value
    online_dihedral: bool = True      # random rot90 / mirror per training batch
    weight_decay: float = 0.0
    cosine_lr: bool = True            # learning rate decays to 0 over the epochs (cosine)

    def check(self) -> None:
        if self.epochs < 1:
            raise UserError(f"--epochs = {self.epochs}: expected a positive integer")
        if self.seed < 0:
            raise UserError(f"--seed = {self.seed}: expected an integer >= 0")
        check_input_px(self.input_px)
        if self.batch_size < 1:
            raise UserError(f"--batch-size = {self.batch_size}: expected a positive integer")
        if not 0.0 < self.val_share < 1.0:
            raise UserError(f"val_share = {self.val_share}: expected a number in (0, 1)")
        if self.split not in {m.value for m in SplitMethod}:
            raise UserError(f"--split = {self.split!r}: expected one of {[m.value for m in SplitMethod]}")
        if not 1 <= self.num_threads <= 2:
            raise UserError(f"--threads = {self.num_threads}: expected 1 or 2 (the machine is shared)")


class PositionSet(str, Enum):
    """Where the held-out captures are taken."""

    UNIFORM = "uniform"   # uniformly random positions (what an assistant map covers)
    PAPER = "paper"       # junction-centred and bad-area positions (the paper's dataset positions)


class CnnMode(str, Enum):
    """What the CNN looks at."""

    ONLINE = "online"                 # the raw 200 x 200 camera capture (paper 5.4, online classification)
    ASSISTANT_MAP = "assistant_map"   # the north-up REFERENCE crop at the true position (offline map)


@dataclass(frozen=True)
class CompareConfig:
    """Held-out evaluation of the two labellings."""

    eval_world_seeds: tuple[int, ...] = EVAL_WORLD_SEEDS
    uniform_positions_per_world: int = 300
    paper_positions_per_world: int = 120
    captures_per_position: int = 4
    seed: int = 0
    epochs: int = TrainConfig.epochs
    input_px: int = DEFAULT_INPUT_PX
    num_threads: int = 2
