"""Derive an orientation from the track when the input has none.

Heading (yaw) comes from the horizontal direction of travel over a short time window
around each sample, measured in the ENU frame at that sample (through ECEF, so long runs
stay right). Roll and pitch are set to zero. Where the vehicle does not move far enough
to tell a direction, the nearest moving sample's heading is used.
"""

from __future__ import annotations

import warnings

import numpy as np

from posefix.core.geodesy import geodetic_to_ecef, rotation_ecef_to_enu
from posefix.io._quat import yaw_to_quat
from posefix.io.errors import OrientationDerivedWarning

__all__ = ["derive_heading_quaternions", "warn_orientation_derived"]

HALF_WINDOW_S = 0.5  # heading from the displacement over ±0.5 s (≥ one neighbour each side)
MIN_BASELINE_M = 0.5  # below this horizontal displacement the direction is noise


def derive_heading_quaternions(t_s: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray,
                               alt_m: np.ndarray) -> np.ndarray:
    """Yaw-only body->ENU quaternions (n, 4) from the direction of travel.

    ``yaw = atan2(d_north, d_east)`` of the displacement between the samples ``HALF_WINDOW_S``
    before and after (at least the immediate neighbours), expressed in the local ENU frame.
    """
    n = t_s.shape[0]
    if n < 2:
        return np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    p_ecef = geodetic_to_ecef(lat_deg, lon_deg, alt_m)
    idx = np.arange(n)
    lo = np.minimum(np.searchsorted(t_s, t_s - HALF_WINDOW_S, side="left"), np.maximum(idx - 1, 0))
    hi = np.maximum(np.searchsorted(t_s, t_s + HALF_WINDOW_S, side="right") - 1, np.minimum(idx + 1, n - 1))
    d_ecef = p_ecef[hi] - p_ecef[lo]
    r = rotation_ecef_to_enu(lat_deg, lon_deg)  # (n,3,3)
    d_enu = np.einsum("nij,nj->ni", r, d_ecef)
    baseline = np.hypot(d_enu[:, 0], d_enu[:, 1])
    yaw = np.arctan2(d_enu[:, 1], d_enu[:, 0])
    moving = baseline >= MIN_BASELINE_M
    if not moving.any():
        yaw = np.zeros(n)
    elif not moving.all():
        # nearest moving sample's heading: forward fill then back fill of indices
        good = np.where(moving, idx, -1)
        prev = np.maximum.accumulate(good)
        nxt = np.where(moving, idx, n)
        nxt = np.minimum.accumulate(nxt[::-1])[::-1]
        use_prev = (prev >= 0) & ((nxt >= n) | (idx - prev <= nxt - idx))
        src = np.where(use_prev, prev, nxt)
        yaw = yaw[src]
    return yaw_to_quat(yaw)


def warn_orientation_derived(source: str) -> None:
    """Say that the orientation was derived (roll and pitch zero)."""
    warnings.warn(
        f"{source}: no orientation in the input; heading derived from the track "
        "(roll and pitch set to zero)",
        OrientationDerivedWarning,
        stacklevel=3,
    )
