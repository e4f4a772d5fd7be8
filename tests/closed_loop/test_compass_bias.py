"""The compass-bias state (SN_MAG_BIAS_SD) learns a biased compass in a GPS-denied cruise.

``FlightCore`` flies the simulator's core in-process (``support.sim_flight``), GPS off, in a 5 m/s
wind with gusts, on vision fixes (3 m after the climb), with the camera flow and drag fusion, as under the ``realistic``
profile. Its compass reads 5 degrees too much (a residual hard-iron offset at this heading). Without
the bias state the EKF, fusing the compass as white noise (EK3_YAW_M_NSE 0.1), takes most of the 5
degrees for the heading; with it, the fixes and the body-frame velocities correct the heading and
the bias state takes the offset. Truth is used only in the assertions.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.sim_flight import sim_config, vision_cruise

from scenenav.core.frames import wrap_pi
from scenenav.core.rotations import heading_from_quat

WIND_ENU_M_S = (4.0, 3.0, 0.0)
DRAG = {"EK3_DRAG_MCOEF": 0.17, "EK3_DRAG_BCOEF_X": 29, "EK3_DRAG_BCOEF_Y": 29}
BIAS_RAD = math.radians(5.0)
FIX_STD_M = 3.0     # the cruise's fixes: about what the realistic flights' accepted fixes are off


def _heading_errors_deg(seed: int, bias_sd_rad: float) -> tuple[np.ndarray, float]:
    """Estimated minus true heading (deg) each second over the last 10 s of a 40-s cruise, and the
    estimated compass bias at the end (deg)."""
    f = vision_cruise(seed, compass_bias_rad=BIAS_RAD, sim=sim_config(WIND_ENU_M_S, 0.7, gps=False),
                      height_m=30.0, cruise_s=5.0, camera_flow_std_rad_s=0.01, SN_CAM_FLOW=1,
                      EK3_YAW_M_NSE=0.1, SN_MAG_BIAS_SD=bias_sd_rad, **DRAG)
    f.vision_std_m = FIX_STD_M
    f.vision_cov_m2 = np.eye(2) * FIX_STD_M ** 2
    f.run(25.0)
    errors = []
    for _ in range(10):
        f.run(1.0)
        est = f.core.estimate()
        errors.append(math.degrees(wrap_pi(float(est.heading_rad) - heading_from_quat(f.plant.q))))
    bias = math.degrees(f.core.nav.state().compass_bias_rad)
    f.close()
    return np.array(errors), bias


@pytest.mark.parametrize("seed", [1, 2])
def test_the_bias_state_takes_the_compass_offset_off_the_heading(seed):
    off, bias_off = _heading_errors_deg(seed, 0.0)
    on, bias_on = _heading_errors_deg(seed, 0.1)
    assert bias_off == 0.0
    # seeds 1, 2: 2.0 and 2.6 deg without, -0.7 and 0.45 deg with; the state holds 6.0 and 4.4 deg
    assert np.mean(off) > 1.5, off                      # a good part of the compass's 5 deg taken for the heading
    assert abs(np.mean(on)) < 0.5 * np.mean(off), (on, off)
    assert bias_on > 2.5, bias_on                       # the state holds the offset
