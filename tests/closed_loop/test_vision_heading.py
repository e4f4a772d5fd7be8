"""The fixes' heading (VisionFix v2) as external-navigation yaw (EK3_SRC1_YAW 6) on the in-process
flight (``CoreFlight``: the flight core on the simulator's core, GPS off, EK3_SRC1_POSXY 6, fixes
from truth + 0.7 m noise every 0.1 s, here with the true heading + 1 degree of noise).

The compass reads 8 degrees too much from the start. With the compass as the yaw source (1) the
EKF keeps most of that error through the cruise; with external navigation (6) the fixes' heading
replaces the compass while it keeps coming, and the estimate's heading is within 2 degrees. Truth
is used only in the assertions."""

from __future__ import annotations

import math

from support.sim_flight import CoreFlight, vision_cruise

from scenenav.core.frames import wrap_pi
from scenenav.core.rotations import heading_from_quat

BIAS_RAD = math.radians(8.0)


def _heading_error_deg(f: CoreFlight) -> float:
    est = f.core.estimate()
    assert est is not None
    return abs(math.degrees(wrap_pi(heading_from_quat(est.q_wxyz) - heading_from_quat(f.plant.q))))


def test_the_fixes_heading_replaces_a_biased_compass():
    on = vision_cruise(6, compass_bias_rad=BIAS_RAD, vision_heading_std_rad=math.radians(1.0),
                       EK3_SRC1_YAW=6)
    assert _heading_error_deg(on) < 2.0, _heading_error_deg(on)
    assert on.core.stats["vision_yaw_fused"] > 100, on.core.stats
    on.close()
    off = vision_cruise(6, compass_bias_rad=BIAS_RAD, vision_heading_std_rad=math.radians(1.0))
    assert _heading_error_deg(off) > 5.0, _heading_error_deg(off)      # the compass source: ignored
    assert off.core.stats["vision_yaw_fused"] == 0
    off.close()


def test_fixes_without_a_heading_leave_the_compass_in_charge():
    f = vision_cruise(6, compass_bias_rad=BIAS_RAD, EK3_SRC1_YAW=6)
    assert f.core.stats["vision_yaw_fused"] == 0 and f.core.stats["ext_nav_yaw_fused"] == 0
    assert _heading_error_deg(f) > 5.0, _heading_error_deg(f)
    f.close()
