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


#: Modules whose flights take minutes, first in the run: pytest-xdist (--dist loadscope) hands out
#: modules in collection order, and a long module started last leaves the other worker idle at the
#: end. Listed by measured duration, longest first (make test's --durations report).
LONG_MODULES = (
    "tests/e2e/test_guidance_flight.py",
    "tests/campaign/test_campaign_flights.py",
    "tests/e2e/test_json_commands.py",
    "tests/e2e/test_autopilot_node.py",
    "tests/e2e/test_external_node.py",
    "tests/e2e/test_run_e2e.py",
    "tests/faults/test_fault_two_runs.py",
    "tests/e2e/test_replan_determinism.py",
)


def pytest_collection_modifyitems(config, items):
    """Run the LONG_MODULES first (stable order otherwise)."""
    def rank(item) -> int:
        path = item.nodeid.split("::", 1)[0]
        return LONG_MODULES.index(path) if path in LONG_MODULES else len(LONG_MODULES)
    items.sort(key=rank)
