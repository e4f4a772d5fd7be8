"""The launcher's pre-flight warning when the simulated flow module reaches beyond RNGFND1_MAX_CM."""

from __future__ import annotations

import logging

import pytest

from scenenav.app.preflight import _warn_rangefinder_limits
from scenenav.app.scenario import load_scenario

FLOW_100M = ("flight.mode=autopilot", "sim.flow.enabled=true", "sim.flow.range_max_m=100",
             "autopilot.params.FLOW_TYPE=10")


@pytest.mark.parametrize(("extra", "warned"), [
    ((), True),                                             # default RNGFND1_MAX_CM 3000 < 100 m
    (("autopilot.params.RNGFND1_MAX_CM=10000",), False),
    (("autopilot.params.FLOW_TYPE=0",), False),             # the autopilot does not use the module
    (("sim.flow.range_max_m=30",), False),                  # the default module: 30 m = 3000 cm
])
def test_warns_only_when_the_module_reaches_beyond_the_autopilots_limit(caplog, extra, warned):
    cfg = load_scenario(None, FLOW_100M + extra)
    with caplog.at_level(logging.WARNING, logger="scenenav.app.preflight"):
        _warn_rangefinder_limits(cfg)
    lines = [r.getMessage() for r in caplog.records]
    assert bool(lines) == warned, lines
    if warned:
        assert "RNGFND1_MAX_CM to 10000" in lines[0]


def test_the_realistic_scenario_uses_its_whole_range_finder(caplog):
    cfg = load_scenario("scenarios/gps_denied_realistic.yaml")
    with caplog.at_level(logging.WARNING, logger="scenenav.app.preflight"):
        _warn_rangefinder_limits(cfg)
    # 200 m: it reaches the street from the 100 m survey (docs/realism.md "Velocity between fixes")
    assert cfg.sim.flow.range_max_m == 200 and not caplog.records
