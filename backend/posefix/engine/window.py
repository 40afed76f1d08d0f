"""A local solve: re-optimise only the keyframes around what changed (one more edit, a live drag).

The window a..b (changed keyframes plus ``LOCAL_MARGIN``) is solved with a held keyframe on
each side carrying the rest of the run as a boundary condition.  Every term touching a
keyframe outside lo..hi involves only states that did not move, so the full problem's cost is

    C_new = C_old - C_old,window(x0) + C_new,window(x)

exact up to the tolerance of ``terms.changed_keyframes`` on terms outside the window.
"""

from __future__ import annotations

import time

import numpy as np

from posefix.core import terms as T
from posefix.core.solver import Linearisation, SolverResult, position_term_costs, solve_banded, solve_local_newton

LOCAL_MARGIN = 30  # keyframes re-optimised beyond those whose terms changed (local solves) ...
LOCAL_EDGE_M = 0.01  # ... and more (x3 each time) while the keyframes next to the held ones move more than this


def solve_window(terms: T.Terms, old: T.Terms, x0: np.ndarray, old_result: SolverResult, solver_cfg,
                 lin: Linearisation | None = None, span: tuple[int, int] | None = None):
    """Re-optimise only around the keyframes whose terms changed; None if that is most of the run.

    The window a..b (changed keyframes plus ``LOCAL_MARGIN``) is solved with a held
    keyframe on each side (lo = a - 1, hi = b + 1) carrying the rest of the run as a
    boundary condition: a few Gauss-Newton steps from the previous solution (damped
    Levenberg-Marquardt if they do not settle).  Every term touching a keyframe outside
    lo..hi involves only states that did not move, so the full problem's cost is the
    previous solve's cost minus the old window terms' cost plus the new window's
    (exact up to the tolerance of ``changed_keyframes`` on terms outside the window);
    no full-length evaluation is needed.  ``lin``, the previous full solve's model of the
    edit-independent terms, spares linearising the window (held ends are exact: their
    blocks are replaced by the identity).
    """
    # a location term whose target moved by under a centimetre (its sigma is metres) moves the
    # solution by less than that: such changes are left to the next full solve
    changed = T.changed_keyframes(terms, old, tol_m=0.01, tol_rel=0.01)
    if changed is None:
        return None, None
    k = terms.n_keyframes
    hit = np.flatnonzero(changed)
    started = time.perf_counter()
    if len(hit) == 0:
        return x0, SolverResult("converged", "nothing changed", 0, dict(old_result.cost_after),
                                dict(old_result.cost_after), time.perf_counter() - started,
                                "local-window", extra={"window_held": (0, -1)})
    xs = x0.reshape(-1, 6)
    margin, last = LOCAL_MARGIN, None
    while True:
        a = max(int(hit[0]) - margin, 0)
        b = min(int(hit[-1]) + margin, k - 1)
        if span is not None:  # held ends no closer than these keyframes (an edit held out: its neighbours)
            a, b = max(min(a, span[0] + 1), 0), min(max(b, span[1] - 1), k - 1)
        if b - a + 1 > 0.5 * k and span is None:
            return None, None
        lo, hi, fixed = held_window(a, b, k)
        if (lo, hi) == last:  # widened within what ``span`` already bound: the same window, the same answer
            margin *= 3
            continue
        last = (lo, hi)
        sub = T.window_terms(terms, lo, hi)
        x_sub0 = xs[lo:hi + 1].ravel()
        lin_w, before, at_lin = None, None, False
        if lin is not None:
            lin_w = lin.window(lo, hi)
            at_lin = np.array_equal(lin_w.x_lin, x_sub0)  # warm from the solve that built it: costs known
            if at_lin:
                before = {**lin.window_costs(lo, hi, sub.rel_w_t), **position_term_costs(sub, xs[lo:hi + 1, :3])}
        out = solve_local_newton(sub, x_sub0, fixed, linearisation=lin_w, cost_before=before)
        if out is None:
            cfg = solver_cfg
            # a local answer previews a change of metres: stopping when a step gains under
            # 1e-6 of the cost leaves it within about a centimetre of the window's optimum
            out = solve_banded(sub, x_sub0, cfg.max_iterations, max(cfg.ftol, 1e-6), fixed=fixed)
        x_sub, res = out
        # the held keyframes stand in for the rest of the run; if the keyframes beside them
        # still moved by more than LOCAL_EDGE_M, the change reaches further: widen and redo
        if edge_motion(x_sub, x_sub0, fixed) <= LOCAL_EDGE_M:
            break
        margin *= 3
    x = xs.copy()
    x[lo:hi + 1] = x_sub.reshape(-1, 6)
    old_sub = T.window_terms(old, lo, hi)
    if at_lin:  # the previous problem's window costs at the same start, from the kept model too
        old_window = {**lin.window_costs(lo, hi, old_sub.rel_w_t), **position_term_costs(old_sub, xs[lo:hi + 1, :3])}
    else:
        old_window = _window_costs_before(old_sub, sub, x_sub0, res.cost_before)
    rest = {name: old_result.cost_after[name] - old_window[name] for name in T.TERM_NAMES}
    before = {name: rest[name] + res.cost_before[name] for name in T.TERM_NAMES}
    after = {name: rest[name] + res.cost_after[name] for name in T.TERM_NAMES}
    result = SolverResult(res.status, res.message + f" (keyframes {a}..{b} of {k})", res.iterations, before,
                          after, time.perf_counter() - started, res.method + "-window",
                          extra={**res.extra, "window": (a, b), "window_held": (lo, hi)})
    return x.ravel(), result


def held_window(a: int, b: int, k: int) -> tuple[int, int, np.ndarray]:
    """Keyframes a..b with a held keyframe on each side (none past the run's ends): lo, hi and
    which of lo..hi are held."""
    lo, hi = max(a - 1, 0), min(b + 1, k - 1)
    fixed = np.zeros(hi - lo + 1, dtype=bool)
    fixed[0] = lo < a
    fixed[-1] = hi > b
    return lo, hi, fixed


def edge_motion(x_sub: np.ndarray, x_ref: np.ndarray, fixed: np.ndarray) -> float:
    """How far the keyframes next to the held ones moved from ``x_ref`` (metres, largest axis)."""
    moved = np.abs(x_sub.reshape(-1, 6)[:, :3] - x_ref.reshape(-1, 6)[:, :3]).max(axis=1)
    return max(moved[1] if fixed[0] else 0.0, moved[-2] if fixed[-1] else 0.0)


def _window_costs_before(old_sub: T.Terms, new_sub: T.Terms, x_sub0: np.ndarray,
                         new_before: dict[str, float]) -> dict[str, float]:
    """Cost of the previous problem's window terms at the warm start, per term.

    The location and user terms differ between the previous and the new problem, so those
    two are evaluated; the relative and gravity terms are the new window's costs at the same
    start, ``new_before``, unless the edits changed their weights in the window (then all
    are evaluated).
    """
    same = all(T.same_array(a, b) for a, b in (
        (old_sub.rel_w_t, new_sub.rel_w_t), (old_sub.rel_w_r, new_sub.rel_w_r), (old_sub.grav_w, new_sub.grav_w)))
    if not same:
        return T.evaluate(old_sub, x_sub0, with_jac=False).costs()
    return {**new_before, **position_term_costs(old_sub, x_sub0.reshape(-1, 6)[:, :3])}
