"""Propagation of the keyframe correction to every full-rate sample (issue section 5).

For a sample s between keyframes a and b (rows a <= s <= b) with fraction alpha in [0, 1]
(distance travelled since a over distance a..b along the reported track: "distance", the
default; or elapsed time over a..b: "time"):

1. rotation first: the world-frame correction of each keyframe, ``C_k = R_k R~_k^T``, is
   interpolated by slerp, ``C_s = C_a Exp(alpha Log(C_a^T C_b))``, and applied,
   ``R_s = C_s R~_s``;
2. then translation: the sample keeps its offset from the reported chord between a and b,
   rotated by ``C_s``, around the corrected chord:
   ``p_s = (1 - alpha) p_a + alpha p_b + C_s (p~_s - (1 - alpha) p~_a - alpha p~_b)``.

At a keyframe alpha is 0 or 1, so the sample lands exactly on the corrected keyframe:
the corrected run is continuous.  Between keyframes the local shape (the sample's deviation
from the chord) is kept up to the small rotation C_s; a stopped vehicle (no distance
travelled) receives no spurious motion under "distance".  Everything is vectorised.
"""

from __future__ import annotations

import numpy as np

from posefix.core import rotations as rot


def interpolation_fraction(
    t_s: np.ndarray, along_m: np.ndarray | None, kf_index: np.ndarray, mode: str = "distance"
) -> tuple[np.ndarray, np.ndarray]:
    """Segment (keyframe a, so b = a + 1) and fraction alpha of every row, shapes (n,), (n,).

    ``along_m`` is the cumulative distance travelled (n,), needed for "distance"; segments
    without travel fall back to time.
    """
    n = len(t_s)
    k = len(kf_index)
    seg = np.searchsorted(kf_index, np.arange(n), side="right") - 1
    seg = np.clip(seg, 0, max(k - 2, 0))
    if k < 2:
        return seg, np.zeros(n)
    a, b = kf_index[seg], kf_index[seg + 1]
    dt = t_s[b] - t_s[a]
    alpha = (t_s - t_s[a]) / np.where(dt > 0, dt, 1.0)
    if mode == "distance":
        if along_m is None:
            raise ValueError("distance-weighted propagation needs the distance travelled")
        dl = along_m[b] - along_m[a]
        moving = dl > 1e-6
        alpha = np.where(moving, (along_m - along_m[a]) / np.where(moving, dl, 1.0), alpha)
    elif mode != "time":
        raise ValueError(f"propagation mode must be 'distance' or 'time', got {mode!r}")
    return seg, np.clip(alpha, 0.0, 1.0)


def propagate_corrections(
    t_s: np.ndarray,
    p_rep_enu_m: np.ndarray,
    kf_index: np.ndarray,
    kf_p_enu_m: np.ndarray,
    c_kf_wxyz: np.ndarray,
    mode: str = "distance",
    along_m: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected positions (n,3) and the world-frame rotation correction C_s (n,4) of every sample.

    ``c_kf_wxyz`` (k,4) is each keyframe's correction ``C_k = q_k q~_k^-1``; the corrected
    orientation of a sample is ``C_s q~_s``.
    """
    t_s = np.asarray(t_s, dtype=float)
    p_rep = np.asarray(p_rep_enu_m, dtype=float)
    kf_index = np.asarray(kf_index, dtype=np.int64)
    c_kf = np.where(c_kf_wxyz[:, :1] < 0, -c_kf_wxyz, c_kf_wxyz)
    if mode == "distance" and along_m is None:
        along_m = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p_rep, axis=0), axis=1))])
    if len(kf_index) < 2:
        c_s = np.broadcast_to(c_kf[0], (len(t_s), 4))
        r0 = p_rep[kf_index[0]]
        return kf_p_enu_m[0] + rot.rotate(c_s, p_rep - r0), np.array(c_s)
    seg, alpha = interpolation_fraction(t_s, along_m, kf_index, mode)
    phi_seg = rot.log_quat(rot.quat_multiply(rot.quat_conjugate(c_kf[:-1]), c_kf[1:]))
    c_s = rot.quat_multiply(c_kf[seg], rot.exp_quat(alpha[:, None] * phi_seg[seg]))
    a, b = kf_index[seg], kf_index[seg + 1]
    w_a, w_b = (1.0 - alpha)[:, None], alpha[:, None]
    chord_rep = w_a * p_rep[a] + w_b * p_rep[b]
    chord_new = w_a * kf_p_enu_m[seg] + w_b * kf_p_enu_m[seg + 1]
    return chord_new + rot.rotate(c_s, p_rep - chord_rep), c_s


def propagate(
    t_s: np.ndarray,
    p_rep_enu_m: np.ndarray,
    q_rep_wxyz: np.ndarray,
    kf_index: np.ndarray,
    kf_p_enu_m: np.ndarray,
    kf_q_wxyz: np.ndarray,
    mode: str = "distance",
    along_m: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected positions (n,3) metres and orientations (n,4) of every sample.

    Parameters
    ----------
    t_s : (n,) sample times, s.         p_rep_enu_m, q_rep_wxyz : (n,3), (n,4) reported poses.
    kf_index : (k,) keyframe rows, sorted, including the first and last rows to correct.
    kf_p_enu_m, kf_q_wxyz : (k,3), (k,4) corrected keyframe poses (same frame as the input).
    mode : "distance" | "time".        along_m : (n,) distance travelled, computed if None.
    """
    q_rep = np.asarray(q_rep_wxyz, dtype=float)
    kf_index = np.asarray(kf_index, dtype=np.int64)
    c_kf = rot.quat_multiply(kf_q_wxyz, rot.quat_conjugate(q_rep[kf_index]))
    p_out, c_s = propagate_corrections(t_s, p_rep_enu_m, kf_index, kf_p_enu_m, c_kf, mode, along_m)
    return p_out, rot.quat_multiply(c_s, q_rep)
