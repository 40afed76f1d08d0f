"""Solving with the model the run's own held-out edits choose (``engine.calibrate``, sections 4-5).

Each candidate model is solved with every edit; then each of up to ``CV_MAX_HELD_OUT`` edits
is held out and predicted without it (the engine's models by a local solve held at the edits
either side, the candidate's drift model re-estimated without the edit, so the edit cannot
vouch for itself; naive interpolation by interpolating the others):

    r_k = p^_k,-k - c_k,        CV RMSE = sqrt(mean_k |r_k|^2)

and ``calibrate.choose`` keeps the calibrated model unless another predicts better, on the
run-wide scale, by more than the held-out noise allows.  The chosen model's reported accuracy
is its held-out RMSE carried to the real spacing (``calibrate.spacing_ratio``, section 6).

Cost: only the first engine model (``gnss``; without raw GNSS ``relative``) is solved by
Levenberg-Marquardt. The others (``plain``, ``relative``) differ from it by metres in position
and well under a milliradian in orientation, so Newton steps on its model of the relative and
gravity terms reach their answers (``Problem.solve_rows(newton=True)``); one chosen is then
solved in full as the first was. Their terms away from the edits do not depend on the edits,
so their held-out solves share one model of the run with edit j's term taken out
(``held_out_fixed_terms``: the same windows and steps as a refit, without a solve each).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from posefix.core import terms as T
from posefix.core.drift import edit_offsets
from posefix.core.rules import Refusal
from posefix.core.solver import linearise_fixed_terms
from posefix.engine.calibrate import (
    CV_MAX_HELD_OUT,
    MIN_EDITS,
    Calibration,
    bridge_ratio,
    calibration_of,
    candidates,
    choose,
    held_out_picks,
    naive_ratio,
    pose_jitter_m2,
    prior_calibration,
    spacing_ratio,
)
from posefix.engine.naive import naive_held_out, naive_solution
from posefix.engine.results import Solution


def solve_calibrated(problem, index: np.ndarray, edit_kf: np.ndarray, edit_c_m: np.ndarray, edit_has_alt: np.ndarray,
                     deleted_kf: np.ndarray, warm_start=None, flags: list[Refusal] | None = None,
                     edit_sigma_m: np.ndarray | None = None) -> Solution:
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
        return problem.solve_rows(*args, warm_start, flags, calibration=prior_calibration(m) if m else None,
                                  edit_sigma_m=edit_sigma_m)
    picks = held_out_picks(m, CV_MAX_HELD_OUT)
    t_kf = problem.run.t_s[index]
    order = np.argsort(t_kf[edit_kf], kind="stable")  # edits in time order for the process fits
    rank = np.empty(m, dtype=np.int64)
    rank[order] = np.arange(m)
    p_rep = problem.p_enu_m[index]
    e, c = edit_kf[order], edit_c_m[order]
    y = p_rep[e, :2] - c[:, :2]
    # the edits' noise: the configured sigma for all (operators' clicks), else each edit's own
    sigma_e = problem.cfg.user.sigma_h_m if edit_sigma_m is None else problem.edit_sigma_h(edit_sigma_m)[order]
    bridge = bridge_ratio(t_kf, t_kf[e], y, rank[picks], sigma_e)
    # edits that carry their noise: naive interpolation passes it through, scaled on its own
    sigma_rms = problem.cfg.user.sigma_h_m if edit_sigma_m is None else float(np.sqrt(np.mean(np.square(sigma_e))))
    f_naive = None if edit_sigma_m is None else naive_ratio(t_kf, t_kf[e], bridge[1], sigma_rms**2, rank[picks])
    solved, residuals = {}, {}
    base = None  # the first engine model's full solve (with its linearisation): the others start from it
    for name in candidates(problem.cfg.calibration.model, problem.g_enu_m is not None):
        if name == "naive":
            residuals[name] = naive_held_out(t_kf[e], y, rank[picks])
            continue
        calib = Calibration(model=name, cv_rmse_m=float("nan"))
        if base is None:
            sol = problem.solve_rows(*args, warm_start, flags, calibration=calib, edit_sigma_m=edit_sigma_m)
            base = with_linearisation(sol)
        else:
            # another model's answer lies metres from the first's with the orientations within a
            # milliradian: Newton steps on the first's model of the relative and gravity terms
            # reach it (within a millimetre) for a fraction of a Levenberg-Marquardt solve
            sol = problem.solve_rows(*args, base, flags, calibration=calib, newton=True, edit_sigma_m=edit_sigma_m)
        solved[name] = sol
        r = None
        if name in ("plain", "relative"):  # no drift model, no bends: one model serves every held-out edit
            if sol.linearisation is not None and not np.array_equal(sol.linearisation.x_lin, sol.x):
                sol = with_linearisation(dataclasses.replace(sol, linearisation=None))
            r = held_out_fixed_terms(with_linearisation(sol), edit_kf, picks)
        residuals[name] = r if r is not None else held_out_residuals(problem, sol, *args, picks, edit_sigma_m=edit_sigma_m)
    scores = {name: float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) for name, r in residuals.items()}
    model = choose(residuals, bridge[0], f_naive)
    d = None
    if problem.g_enu_m is not None:
        g = problem.g_enu_m[index]
        d = edit_offsets(t_kf, p_rep, np.where(np.all(np.isfinite(g), axis=1)[:, None], g, np.nan), e, c)[:, :2]
    spacing = spacing_ratio(problem.run.t_s, t_kf, t_kf[e], y, np.sort(rank[picks]), sigma_rms,
                            _pose_jitter(problem))
    calib = calibration_of(model, scores, bridge[0], bridge, t_kf, t_kf[e], d, sigma_e, spacing)
    if model == "naive":
        return naive_solution(problem, *args, flags, calib)
    sol = solved[model]
    if sol.solver.method == "local-newton":
        # chosen: solved as the first model was (from the caller's warm start), since without a
        # location term the height is held only where it starts
        sol = problem.solve_rows(*args, warm_start, flags, calibration=sol.drift.calibration)
    return dataclasses.replace(sol, drift=dataclasses.replace(sol.drift, calibration=calib))


def _pose_jitter(problem) -> float:
    """``calibrate.pose_jitter_m2`` of the run's reported horizontal positions, once per problem."""
    key = ("pose_jitter",)
    if key not in problem._static:
        problem._static[key] = pose_jitter_m2(problem.p_enu_m[:, :2])
    return problem._static[key]


def with_linearisation(sol: Solution) -> Solution:
    """``sol`` with the model of its relative and gravity terms at its answer (``solver.Linearisation``),
    built here when the solve did not keep one (a long run: see ``LINEARISE_MAX_KEYFRAMES``)."""
    if sol.linearisation is not None or sol.terms is None or not np.all(np.isfinite(sol.x)):
        return sol
    ev = T.add_jacobians(sol.terms, T.evaluate(sol.terms, sol.x, with_jac=False))
    return dataclasses.replace(sol, linearisation=linearise_fixed_terms(sol.terms, ev))


def held_out_residuals(problem, sol: Solution, index, edit_kf, edit_c_m, edit_has_alt, deleted_kf,
                        picks: np.ndarray, edit_sigma_m: np.ndarray | None = None) -> np.ndarray:
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
                            warm_start=sol, flags=sol.flags, local=True, span=span,
                            edit_sigma_m=None if edit_sigma_m is None else edit_sigma_m[keep])
        out[n] = s.keyframes.p_enu_m[edit_kf[j], :2] - edit_c_m[j, :2]
    return out



def held_out_fixed_terms(sol: Solution, edit_kf: np.ndarray, picks: np.ndarray) -> np.ndarray | None:
    """``held_out_residuals`` for a model whose terms away from the edits do not depend on them
    (``plain``, ``relative``: no drift model, no bends), without a solve per edit: dropping edit j
    changes only its own user term, so each held-out solve is the window Newton steps of
    ``window.solve_window`` (the same windows, held ends, widening and tolerances) on one model
    of the whole run built once: ``sol.linearisation`` with every edit's term, from which edit
    j's is subtracted (exact: the user term is linear).  None when ``sol`` kept no linearisation
    at its own answer, or a window's steps do not settle (then refit each edit).
    """
    from posefix.core.solver import BAND_U, _model_from_linearisation, _newton_on_model
    from posefix.engine.window import LOCAL_EDGE_M, LOCAL_MARGIN, edge_motion, held_window

    terms, lin = sol.terms, sol.linearisation
    if terms is None or lin is None or not lin.matches(terms) or not np.array_equal(lin.x_lin, sol.x):
        return None
    k = terms.n_keyframes
    x_lin, ab, g = _model_from_linearisation(terms, lin.window(0, k - 1))
    xs = sol.x.reshape(-1, 6)
    active_number = np.cumsum(sol.active) - 1
    e_act = active_number[np.asarray(edit_kf, dtype=np.int64)]
    e_sorted = np.sort(e_act)
    user_at = {int(i): n for n, i in enumerate(terms.user_idx)}
    out = np.zeros((len(picks), 2))
    for n, j in enumerate(picks):
        kj = int(e_act[j])
        at = int(np.searchsorted(e_sorted, kj))
        span = (int(e_sorted[at - 1]) if at > 0 else -1, int(e_sorted[at + 1]) if at + 1 < len(e_sorted) else k)
        u = user_at[kj]
        w2 = terms.user_w[u] ** 2
        c = terms.user_c_m[u]
        margin, last = LOCAL_MARGIN, None
        while True:
            a = max(min(max(kj - margin, 0), span[0] + 1), 0)
            b = min(max(min(kj + margin, k - 1), span[1] - 1), k - 1)
            lo, hi, fixed = held_window(a, b, k)
            if (lo, hi) == last:  # widened past what the neighbouring edits already bound: the same window
                margin *= 3
                continue
            last = (lo, hi)
            sub = T.window_terms(terms, lo, hi)
            ab_w = np.array(ab[:, 6 * lo:6 * hi + 6], order="F", copy=True)
            g_w = g[6 * lo:6 * hi + 6].copy()
            col = 6 * (kj - lo) + np.arange(3)
            ab_w[BAND_U, col] -= w2  # edit j's user term out of the model
            g_w[col] -= w2 * np.where(w2 > 0, x_lin[6 * kj:6 * kj + 3] - c, 0.0)
            x0 = sol.x[6 * lo:6 * hi + 6]
            x_sub, _ = _newton_on_model(sub, ab_w, g_w, x_lin[6 * lo:6 * hi + 6], x0, fixed, 8, 0.02)
            if x_sub is None or float(np.max(np.abs((x_sub - x0).reshape(-1, 6)[:, 3:]), initial=0.0)) >= 1e-3:
                return None
            if edge_motion(x_sub, xs[lo:hi + 1], fixed) <= LOCAL_EDGE_M:
                break
            margin *= 3
        out[n] = x_sub[6 * (kj - lo):6 * (kj - lo) + 2] - c[:2]
    return out
