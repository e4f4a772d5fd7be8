"""The camera's flow (VisionFix version 3, SN_CAM_FLOW) holds the dead-reckoned velocity when the
vision fixes stop.

``FlightCore`` flies the simulator's core in-process (``support.sim_flight``), GPS off, in a 5 m/s
wind (4 east, 3 north) with 0.7 m/s gusts. It cruises north at 30 m on vision fixes, then the fixes
stop for 20 s. The camera flow is the true image motion at the image centre over flat ground with the
body rotation in it, 10 Hz, 0.01 rad/s of noise (``CoreFlight.camera_flow_std_rad_s``); the core has
to remove the rotation with its own gyro and divide by the height it estimates, so a sign or frame
error in either makes the drift larger, not smaller. Truth is used only in the assertions.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.sim_flight import CoreFlight, sim_config, vision_cruise

WIND_ENU_M_S = (4.0, 3.0, 0.0)
DRAG = {"EK3_DRAG_MCOEF": 0.17, "EK3_DRAG_BCOEF_X": 29, "EK3_DRAG_BCOEF_Y": 29}
GAP_S = 20.0


def _fly_gap(seed: int, cam_flow: int, flow_std: float | None = 0.01) -> tuple[float, float, CoreFlight]:
    """Horizontal estimate error (m) at the start and at the end of the fix gap, and the flight."""
    f = vision_cruise(seed, sim=sim_config(WIND_ENU_M_S, 0.7, gps=False), height_m=30.0, cruise_s=10.0,
                      camera_flow_std_rad_s=flow_std, SN_VIS_TIMEOUT=0, SN_CAM_FLOW=cam_flow, **DRAG)
    c = f.core

    def err() -> float:
        return float(np.linalg.norm(np.asarray(c.estimate().position_enu_m[:2]) - f.p[:2]))

    before = err()
    f.vision = False
    f.run(GAP_S)
    after = err()
    f.close()
    return before, after, f


@pytest.mark.parametrize("seed", [1, 2])
def test_camera_flow_bounds_the_drift_of_a_fix_gap(seed):
    before_on, after_on, on = _fly_gap(seed, cam_flow=1)
    before_off, after_off, off = _fly_gap(seed, cam_flow=0)
    s = on.core.stats
    assert s["camera_flow_fused"] > 2 * 10 * GAP_S, s          # both axes, 10 Hz, the whole gap
    assert s["camera_flow_rejected"] < 0.05 * s["camera_flow_fused"], s
    assert off.core.stats["camera_flow_fused"] == 0
    assert before_on < 3.0 and before_off < 3.0
    assert after_on < 0.75 * after_off, (after_on, after_off)     # seeds 1, 2: 3.5 against 7.8, 1.3 against 4.9 m


def test_low_quality_and_missing_flows_are_not_fused():
    f = CoreFlight(3, gps=False, EK3_SRC1_POSXY=6, SN_VIS_MIN_ALT=10, SN_VIS_TIMEOUT=0, SN_CAM_FLOW=1,
                   SN_CAM_FLOW_QMIN=0.95)
    from autopilot_bridge.fusion import CameraFlowReading
    f.core.on_camera_flow(CameraFlowReading(0.1, (math.nan, 0.0), 0.1, 0.9))
    f.core.on_camera_flow(CameraFlowReading(0.1, (0.0, 0.0), 0.0, 0.9))
    f.core.on_camera_flow(CameraFlowReading(0.1, (0.0, 0.0), 1e6, 0.9))       # not consecutive frames
    f.core.on_camera_flow(CameraFlowReading(0.1, (0.0, 0.0), 0.1, 1.5))       # quality beyond 1
    assert f.core.stats["camera_flow_nan"] == 4
    f.vision = True
    f.camera_flow_std_rad_s = 0.01          # quality 0.9 < SN_CAM_FLOW_QMIN 0.95
    f.core.set_vision_available(True)
    f.arm_in_guided()
    assert f.core.takeoff(30.0).ok
    assert f.run(60.0, until=lambda: f.p[2] > 29.0)
    s = f.core.stats
    assert s["camera_flow_low_quality"] > 50 and s["camera_flow_fused"] == 0, s
    f.close()
