"""Rotations and headings: quaternions (Hamilton, w x y z), Euler angles, compass headings.

Conventions (docs/architecture.md, ``scenenav.core.frames``): world ENU, body FLU, ``q_wxyz``
rotates body vectors into the world frame; a compass heading is clockwise from north in radians in
[0, 2 pi); an ENU yaw is counter-clockwise from east. Plain floats are used because for 4-vectors they
are several times faster than numpy calls. The one place for these helpers: every package imports them
from here.
"""

from __future__ import annotations

import math

import numpy as np

_TWO_PI = 2.0 * math.pi


# are used because for 4-vectors they are several times faster than numpy calls.

def quat_multiply(a, b) -> tuple[float, float, float, float]:
    """Hamilton product a * b (R(a * b) = R(a) R(b))."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def quat_conjugate(q) -> tuple[float, float, float, float]:
    return (q[0], -q[1], -q[2], -q[3])


def quat_normalise(q) -> tuple[float, float, float, float]:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0.0:
        n = -n  # keep w >= 0 (same rotation)
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def quat_from_rotation_vector(rx: float, ry: float, rz: float) -> tuple[float, float, float, float]:
    """Exp map: rotation vector (axis * angle, rad) -> unit quaternion."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < 1e-9:
        return quat_normalise((1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz))
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), rx * s, ry * s, rz * s)


def quat_to_rotation_matrix(q) -> np.ndarray:
    """3x3 rotation matrix (body -> world) of a unit quaternion."""
    w, x, y, z = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return np.array([[1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
                     [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
                     [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)]])


def quat_rotate(q, v) -> tuple[float, float, float]:
    """Rotate the 3-vector v by q (body -> world for the attitude quaternion)."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 * (q_vec x v); v' = v + w t + q_vec x t
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty),
            vy + w * ty + (z * tx - x * tz),
            vz + w * tz + (x * ty - y * tx))


def quat_from_euler_zyx(yaw_rad: float, pitch_rad: float, roll_rad: float) -> tuple[float, float, float, float]:
    """q = Rz(yaw) Ry(pitch) Rx(roll) about the world-ENU / body-FLU axes (yaw CCW from east).

    FLU signs: positive roll (about forward x) lowers the right side; positive pitch (about left y) lowers
    the nose.
    """
    cy, sy = math.cos(0.5 * yaw_rad), math.sin(0.5 * yaw_rad)
    cp, sp = math.cos(0.5 * pitch_rad), math.sin(0.5 * pitch_rad)
    cr, sr = math.cos(0.5 * roll_rad), math.sin(0.5 * roll_rad)
    return (cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy)


def quat_from_aviation_euler(roll_rad: float, pitch_rad: float, heading_rad: float) -> tuple[float, float, float, float]:
    """Aviation Euler angles -> q_wxyz (body FLU -> world ENU).

    roll: positive = right wing down; pitch: positive = nose up; heading: compass, clockwise from north.
    """
    return quat_from_euler_zyx(0.5 * math.pi - heading_rad, -pitch_rad, roll_rad)


def aviation_euler_from_quat(q) -> tuple[float, float, float]:
    """q_wxyz -> (roll, pitch, heading) in the aviation convention of ``quat_from_aviation_euler``."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    sin_pitch_flu = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    pitch_flu = math.asin(sin_pitch_flu)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, -pitch_flu, (0.5 * math.pi - yaw) % _TWO_PI


def heading_from_quat(q) -> float:
    """Compass heading (clockwise from north, [0, 2 pi)) of the body x axis."""
    w, x, y, z = q
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (0.5 * math.pi - yaw) % _TWO_PI


def yaw_from_quat(q) -> float:
    """ENU yaw (rad, counter-clockwise from east, [-pi, pi]) of the body +x axis projected on the ground."""
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_from_yaw(yaw_enu_rad: float) -> tuple[float, float, float, float]:
    """Level attitude with body +x at ENU yaw ``yaw_enu_rad`` (counter-clockwise from east)."""
    half = 0.5 * yaw_enu_rad
    return (math.cos(half), 0.0, 0.0, math.sin(half))
