"""Shared fixtures for every test kind: free ports, the default world, small generated worlds.

Test kinds live in their own folders: ``unit/<package>``, ``bus`` (real Zenoh peers), ``mavlink``
(the MAVLink server over real TCP), ``interop`` (real ground-station clients), ``fuzz``, ``e2e``
(whole ``scenenav`` runs). Helpers used by several kinds are in ``support/``.
"""

from __future__ import annotations

import pytest
from support.fake_vehicle import free_port


@pytest.fixture
def tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    return free_port()


@pytest.fixture(scope="session")
def default_world():
    """The default world (generated and cached on first use)."""
    from worlds.default import load_default_world
    return load_default_world()


@pytest.fixture(scope="session")
def small_world():
    """A 600x600 px generated city (seed 3), shared by the tests of one session."""
    from worlds.generator import CityConfig, generate_world
    return generate_world(CityConfig(seed=3, width_px=600, height_px=600))
