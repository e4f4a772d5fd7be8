"""A GPS-denied climb in wind with the optical-flow module (``sim.flow``, FLOW_TYPE, EK3_SRC1_VELXY 5).

``FlightCore`` flies the simulator's core in-process (``support.sim_flight``), GPS off, no vision
fix below SN_VIS_MIN_ALT: the climb has no position aiding. A 5 m/s wind (4 east, 3 north) with
0.7 m/s gusts pushes the vehicle while it holds the *estimate* over the take-off point; drag fusion
(the Iris's EK3_DRAG_* of scenarios/gps_denied.yaml) bounds the air-relative velocity, but the wind
estimate starts at zero. The flow module (range finder up to 30 m) measures the velocity over the
ground. Measured (EK3_FLOW_M_NSE 0.1), horizontal error at 30 m over seeds 1-3: 2.8 / 3.4 / 0.6 m
with flow, 8.3 / 9.4 / 0.1 m without. Truth is used only in the assertions.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.sim_flight import CoreFlight, sim_config

from autopilot_bridge.modes import CopterMode
from sitl.config import FlowConfig

WIND_ENU_M_S = (4.0, 3.0, 0.0)
DRAG = {"EK3_DRAG_MCOEF": 0.17, "EK3_DRAG_BCOEF_X": 29, "EK3_DRAG_BCOEF_Y": 29, "EK3_GBIAS_P_NSE": 1e-4}


def _climb_to(height_m: float, seed: int, flow_type: int, **params: float) -> tuple[float, CoreFlight]:
    sim = dataclasses.replace(sim_config(WIND_ENU_M_S, 0.7, gps=False), flow=FlowConfig(enabled=True))
    f = CoreFlight(seed, gps=False, sim=sim, EK3_SRC1_POSXY=6, SN_VIS_TIMEOUT=0, SN_VIS_MIN_ALT=71,
                   FLOW_TYPE=flow_type, EK3_SRC1_VELXY=5, EK3_FLOW_M_NSE=0.1, **DRAG, **params)
    c = f.core
    c.set_vision_available(True)
    f.run(1.5)
    assert c.aligned and c.set_mode(CopterMode.GUIDED).ok
    while not c.arm(False).ok:        # EK3_GBIAS_P_NSE 1e-4: the bias takes about a minute to learn
        f.run(0.5)
        assert f.t < 150.0
    assert c.takeoff(70.0).ok
    while f.p[2] < height_m:
        f.tick()
        assert f.t < 250.0, "the climb did not reach its height"
    err = float(np.linalg.norm(np.asarray(c.estimate().position_enu_m[:2]) - f.p[:2]))
    f.close()
    return err, f


@pytest.mark.parametrize("seed", [1, 2])
def test_flow_keeps_the_climb_on_its_point(seed):
    err, f = _climb_to(30.0, seed, flow_type=10)
    assert f.core.stats["flow_fused"] > 150, f.core.stats
    assert err < 5.0, err


def test_flow_type_0_ignores_the_module():
    err, f = _climb_to(30.0, 2, flow_type=0)
    assert f.core.stats["flow_fused"] == 0 and f.core.stats["flow_unusable"] == 0
    assert err > 5.0, err         # seed 2 without flow: 9.4 m


def test_readings_beyond_rngfnd1_max_cm_are_not_fused():
    """The module measures to 30 m; with RNGFND1_MAX_CM 500 the autopilot uses it only below 5 m."""
    err, f = _climb_to(30.0, 2, flow_type=10, RNGFND1_MAX_CM=500)
    s = f.core.stats
    assert s["flow_out_of_range"] > 50 and s["flow_fused"] > 0, s          # 10 Hz, 5 -> 30 m
    assert s["flow_fused"] < s["flow_out_of_range"], s
