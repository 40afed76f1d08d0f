"""Solving with the model the run's own held-out edits choose (``engine.calibrate``, sections 4-5).

Each candidate model is solved with every edit; then each of up to ``CV_MAX_HELD_OUT`` edits
is held out and predicted without it (the engine's models by a local solve held at the edits
either side, the candidate's drift model re-estimated without the edit, so the edit cannot
vouch for itself; naive interpolation by interpolating the others):

    r_k = p^_k,-k - c_k,        CV RMSE = sqrt(mean_k |r_k|^2)

and ``calibrate.choose`` keeps the calibrated model unless another predicts better, on the
run-wide scale, by more than the held-out noise allows.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from posefix.core.drift import edit_offsets
from posefix.core.rules import Refusal
from posefix.engine.calibrate import (
    CV_MAX_HELD_OUT,
    MIN_EDITS,
    Calibration,
    bridge_ratio,
    calibration_of,
    candidates,
    choose,
    held_out_picks,
    prior_calibration,
)
from posefix.engine.naive import naive_held_out, naive_solution
from posefix.engine.results import Solution


def solve_calibrated(problem, index: np.ndarray, edit_kf: np.ndarray, edit_c_m: np.ndarray, edit_has_alt: np.ndarray,
                     deleted_kf: np.ndarray, warm_start=None, flags: list[Refusal] | None = None) -> Solution:
    """A full solve with the model the run's own held-out edits choose (``engine.calibrate``).

    Each candidate is scored on up to ``CV_MAX_HELD_OUT`` held-out edits (the engine's models
    by local solves without the edit, naive interpolation in closed form) and the choice made
    on the run-wide scale (``calibrate.choose``).  With fewer than ``MIN_EDITS`` edits the
    prior decides.
    """
    edit_kf = np.asarray(edit_kf, dtype=np.int64)
    edit_c_m = np.asarray(edit_c_m, dtype=float).reshape(-1, 3)
    edit_has_alt = np.asarray(edit_has_alt, dtype=bool)
    m = len(edit_kf)
    args = (index, edit_kf, edit_c_m, edit_has_alt, deleted_kf)
    if m < MIN_EDITS:
        return problem.solve_rows(*args, warm_start, flags, calibration=prior_calibration(m) if m else None)
    picks = held_out_picks(m, CV_MAX_HELD_OUT)
    t_kf = problem.run.t_s[index]
    order = np.argsort(t_kf[edit_kf], kind="stable")  # edits in time order for the process fits
    rank = np.empty(m, dtype=np.int64)
    rank[order] = np.arange(m)
    p_rep = problem.p_enu_m[index]
    e, c = edit_kf[order], edit_c_m[order]
    y = p_rep[e, :2] - c[:, :2]
    bridge = bridge_ratio(t_kf, t_kf[e], y, rank[picks], problem.cfg.user.sigma_h_m)
    solved, residuals = {}, {}
    for name in candidates(problem.cfg.calibration.model, problem.g_enu_m is not None):
        if name == "naive":
            residuals[name] = naive_held_out(t_kf[e], y, rank[picks])
            continue
        sol = problem.solve_rows(*args, warm_start, flags, calibration=Calibration(model=name, cv_rmse_m=float("nan")))
        solved[name] = sol
        residuals[name] = held_out_residuals(problem, sol, *args, picks)
    scores = {name: float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) for name, r in residuals.items()}
    model = choose(residuals, bridge[0])
    d = None
    if problem.g_enu_m is not None:
        g = problem.g_enu_m[index]
        d = edit_offsets(t_kf, p_rep, np.where(np.all(np.isfinite(g), axis=1)[:, None], g, np.nan), e, c)[:, :2]
    calib = calibration_of(model, scores, bridge[0], bridge, t_kf, t_kf[e], d, problem.cfg.user.sigma_h_m)
    if model == "naive":
        return naive_solution(problem, *args, flags, calib)
    sol = solved[model]
    return dataclasses.replace(sol, drift=dataclasses.replace(sol.drift, calibration=calib))


def held_out_residuals(problem, sol: Solution, index, edit_kf, edit_c_m, edit_has_alt, deleted_kf,
                        picks: np.ndarray) -> np.ndarray:
    """(n,2) horizontal error of the prediction of each picked edit by a local solve without it."""
    out = np.zeros((len(picks), 2))
    active_number = np.cumsum(sol.active) - 1
    e_sorted = np.sort(active_number[edit_kf])
    k_act = int(sol.active.sum())
    for n, j in enumerate(picks):
        keep = np.arange(len(edit_kf)) != j
        # the edits either side pin the run: the window reaches them (held there), no further
        at = int(np.searchsorted(e_sorted, active_number[edit_kf[j]]))
        # (an end edit's window runs free to the run's end: -1 and k hold nothing)
        span = (int(e_sorted[at - 1]) if at > 0 else -1, int(e_sorted[at + 1]) if at + 1 < len(e_sorted) else k_act)
        s = problem.solve_rows(index, edit_kf[keep], edit_c_m[keep], edit_has_alt[keep], deleted_kf,
                            warm_start=sol, flags=sol.flags, local=True, span=span)
        out[n] = s.keyframes.p_enu_m[edit_kf[j], :2] - edit_c_m[j, :2]
    return out
