"""Naive interpolation as one of the engine's models: the reported pose kept, the edit offsets
(edit minus reported position) interpolated linearly in time between edits, constant beyond
the first and last.  It is the simplest tool an operator has, so it is always a candidate the
run's held-out edits may choose (``engine.calibrate``); its held-out residuals need no solve:

    r_k = y_k - y^_k,-k    (the prediction p~_k - y^_k,-k minus the edit c_k),

with y_k = p~_k - c_k the pose's error at edit k and y^_k,-k the other edits' interpolated at t_k.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from posefix.core.drift import no_drift
from posefix.core.keyframes import KeyframeSet
from posefix.core.solver import SolverResult
from posefix.engine.results import Solution


def interpolate_offsets(t_s: np.ndarray, edit_t_s: np.ndarray, offsets_m: np.ndarray) -> np.ndarray:
    """Offsets (m,d) at sorted edit times interpolated linearly at ``t_s`` (n,), constant outside."""
    out = np.zeros((len(t_s), offsets_m.shape[1]))
    if len(edit_t_s) == 0:
        return out
    for j in range(offsets_m.shape[1]):
        out[:, j] = np.interp(t_s, edit_t_s, offsets_m[:, j])
    return out


def naive_held_out(edit_t_s: np.ndarray, offsets_m: np.ndarray, picks: np.ndarray) -> np.ndarray:
    """(n,d) residual of each picked edit (sorted by time) predicted from the others' offsets."""
    m = len(edit_t_s)
    out = np.zeros((len(picks), offsets_m.shape[1]))
    for n, k in enumerate(picks):
        keep = np.arange(m) != k
        out[n] = offsets_m[k] - interpolate_offsets(edit_t_s[k:k + 1], edit_t_s[keep], offsets_m[keep])[0]
    return out


def naive_solution(problem, index: np.ndarray, edit_kf: np.ndarray, edit_c_m: np.ndarray, edit_has_alt: np.ndarray,
                   deleted_kf: np.ndarray, flags, calibration) -> Solution:
    """The keyframe solution of naive interpolation (rotations as reported, nothing optimised).

    Horizontal offsets from every edit; the vertical one only from edits that set an altitude
    (none: the reported altitude stays)."""
    started = time.perf_counter()
    k = len(index)
    deleted = np.zeros(k, dtype=bool)
    deleted[np.asarray(deleted_kf, dtype=np.int64)] = True
    active = ~deleted if problem.cfg.rules.deleted == "remove" else np.ones(k, dtype=bool)
    t_kf = problem.run.t_s[index]
    p_rep = problem.p_enu_m[index]
    edit_kf = np.asarray(edit_kf, dtype=np.int64)
    order = np.argsort(t_kf[edit_kf], kind="stable")
    e, c, alt = edit_kf[order], np.asarray(edit_c_m, dtype=float).reshape(-1, 3)[order], np.asarray(edit_has_alt)[order]
    off = np.zeros((k, 3))
    off[:, :2] = interpolate_offsets(t_kf, t_kf[e], c[:, :2] - p_rep[e, :2])
    if np.any(alt):
        off[:, 2] = interpolate_offsets(t_kf, t_kf[e[alt]], (c[alt, 2] - p_rep[e[alt], 2])[:, None])[:, 0]
    p = p_rep + off
    q = problem.anchored_quat(index)
    x = np.concatenate([p[active], np.zeros((int(active.sum()), 3))], axis=1).ravel()
    edited = np.zeros(k, dtype=bool)
    edited[edit_kf] = True
    kfs = KeyframeSet(index=index, t_s=t_kf, p_enu_m=p, q_wxyz=q.copy(), reported_p_enu_m=p_rep, reported_q_wxyz=q,
                      edited=edited, deleted=deleted)
    result = SolverResult("converged", "naive interpolation of the edit offsets", 0, {}, {},
                          time.perf_counter() - started, "naive")
    drift = no_drift(int(active.sum()))
    if calibration is not None:
        drift = dataclasses.replace(drift, calibration=calibration)
    return Solution(kfs, result, drift, x, active, list(flags or []), None, None)
