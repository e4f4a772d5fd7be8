"""Fixtures of the perception unit tests."""

import numpy as np
import pytest
from test_pipeline import make_synthetic_world


@pytest.fixture(scope="module")
def world() -> tuple[np.ndarray, np.ndarray]:
    """(reference RGB uint8, flight-day grey float32) of the synthetic lake-and-texture world."""
    return make_synthetic_world()
