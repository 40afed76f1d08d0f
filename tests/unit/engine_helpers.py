"""Small synthetic keyframe problems shared by the engine's unit tests."""

from __future__ import annotations

import numpy as np

from posefix.core import rotations as rot
from posefix.core import terms as T


def curvy_drive(k: int = 60, seed: int = 0, step_m: float = 10.0):
    """Truth keyframe poses of a smooth drive: p (k,3) metres, q (k,4) body-to-ENU, yaw following the path."""
    rng = np.random.default_rng(seed)
    yaw = np.cumsum(rng.normal(0.0, 0.05, k)) + 0.3
    step = np.stack([np.cos(yaw), np.sin(yaw), rng.normal(0, 0.01, k)], 1) * step_m
    p = np.cumsum(step, axis=0) - step[0]
    roll = rng.normal(0, 0.02, k)
    pitch = rng.normal(0, 0.02, k)
    q = rot.quat_multiply(
        rot.exp_quat(np.stack([np.zeros(k), np.zeros(k), yaw], 1)),
        rot.quat_multiply(rot.exp_quat(np.stack([np.zeros(k), pitch, np.zeros(k)], 1)),
                          rot.exp_quat(np.stack([roll, np.zeros(k), np.zeros(k)], 1))),
    )
    return p, q


def random_terms(k: int = 12, seed: int = 1, loss: str = "cauchy", n_user: int = 3) -> T.Terms:
    """Terms with non-trivial measurements, edits with a free vertical axis, mixed sigmas."""
    rng = np.random.default_rng(seed)
    p, q = curvy_drive(k, seed)
    loc_idx = np.arange(k)
    g = p + rng.normal(0, 4.0, (k, 3))
    user_idx = np.sort(rng.choice(k, n_user, replace=False))
    c = p[user_idx] + rng.normal(0, 2.0, (n_user, 3))
    user_sigma = np.tile([0.5, 0.5, np.inf], (n_user, 1))
    user_sigma[0, 2] = 0.5
    return T.build_terms(
        p, q, loc_idx, g, np.tile([3.0, 3.0, 6.0], (k, 1)), user_idx, c, user_sigma,
        sigma_rt_m=0.1 + rng.random(k - 1) * 0.1, sigma_rr_rad=0.01, sigma_g=0.02, loss=loss, loss_scale=1.0,
    )
