"""A NavState for controller tests."""

from __future__ import annotations

import math

import numpy as np

from autopilot_bridge.ekf import NavState


def nav_state(position=(0.0, 0.0, 10.0), velocity=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0)) -> NavState:
    w, x, y, z = q
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return NavState(position_enu_m=np.array(position, dtype=float), velocity_enu_m_s=np.array(velocity, dtype=float),
                    q_wxyz=np.array(q, dtype=float), gyro_bias=np.zeros(3), accel_bias=np.zeros(3),
                    position_std_m=np.full(3, 0.1), velocity_std_m_s=np.full(3, 0.05),
                    heading_rad=(math.pi / 2 - yaw) % (2 * math.pi))
