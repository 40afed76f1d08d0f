"""Small rotation helpers for the readers (Hamilton quaternions, w first).

Quaternion <-> matrix conversion is the engine's (``posefix.core.rotations``); the
Euler-angle conventions of particular formats live here.
"""

from __future__ import annotations

import numpy as np

from posefix.core.rotations import matrix_to_quat, quat_to_matrix

__all__ = ["matrix_to_quat", "quat_to_matrix", "yaw_to_quat", "rpy_to_matrix"]


def yaw_to_quat(yaw_rad: np.ndarray) -> np.ndarray:
    """Rotation about the up axis by ``yaw_rad`` (from east, counter-clockwise) -> (n, 4)."""
    half = 0.5 * np.asarray(yaw_rad, dtype=float)
    zero = np.zeros_like(half)
    return np.stack([np.cos(half), zero, zero, np.sin(half)], axis=-1)


def rpy_to_matrix(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """Body->ENU matrices ``Rz(yaw) Ry(pitch) Rx(roll)`` (n, 3, 3) (OXTS/KITTI convention)."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    r = np.empty(np.shape(roll_rad) + (3, 3))
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r
