"""What the matching-area CNN is, without torch: its input size, layer sizes, classes and labellings.

The network itself (``SceneMatchNet``), its weights files and the classifier are in ``perception.cnn``,
which imports torch; this module is what the dataset builder, the command line and the decision rule
need to know of the network, so they start without torch (about 2 s of CPU per process).
"""

from __future__ import annotations

import enum

from scenenav.core.errors import UserError

PAPER_INPUT_PX = 200
"""The paper's image size (section 5.2: 'resized to 200x200 pixels')."""
DEFAULT_INPUT_PX = 48
"""Our default network input: the 200 px dataset images downscaled 200 -> 48 for CPU speed."""
INPUT_MEAN = 0.5
INPUT_STD = 0.25
CONV1_KERNELS = 64
CONV2_KERNELS = 32
KERNEL_PX = 3
POOL_PX = 2
FC1_UNITS = 128
FC2_UNITS = 64
DROPOUT_P = 0.5
BAD_THRESHOLD = 0.5
"""Section 5.4: a capture with P(class 1 = bad) > 0.5 is rejected."""


class MatchClass(enum.IntEnum):
    """CNN output classes. Index = network output; the paper numbers them 1..4."""

    BAD = 0         # paper class 1: bad matching area
    FOUR_ARM = 1    # paper class 2: junction with 4 arms
    THREE_ARM = 2   # paper class 3: junction with 3 arms
    TWO_ARM = 3     # paper class 4: junction with 2 arms

    @property
    def paper_class(self) -> int:
        """The paper's 1-based class number."""
        return int(self) + 1


NUM_CLASSES = len(MatchClass)


class Labelling(str, enum.Enum):
    """How dataset labels were produced (see perception.dataset)."""

    PAPER = "paper"                 # junction arm count / dominant bad land cover (section 5.2)
    MATCHABILITY = "matchability"   # simulated NCC success rate (perception.matchability)


def feature_side_px(input_px: int) -> int:
    """Side of the feature map after conv-pool-conv-pool with 'valid' 3x3 convolutions."""
    side = input_px
    for _ in range(2):
        side = (side - (KERNEL_PX - 1)) // POOL_PX
    return side


def check_input_px(input_px: int) -> None:
    """Raise UserError unless the network can take ``input_px`` x ``input_px`` inputs."""
    if not isinstance(input_px, int) or input_px < 16 or input_px > PAPER_INPUT_PX:
        raise UserError(f"--input-px = {input_px!r}: expected an integer in [16, {PAPER_INPUT_PX}]")
