"""Operator-weighted consensus of positions: per-operator accuracy by EM (Dawid-Skene for
positions), robust inverse-variance fusion per keyframe, and a chi-square test of each
submission against the others (numpy/scipy only).

Model. Submission ``i`` (operator ``o = o(i)``) places keyframe ``k`` of its run at
``x_ik`` (local East-North metres, 2-D); the truth is ``t_k``. A submission errs by

    x_ik = t_k + b_i + e_ik / sqrt(u_ik),   e_ik ~ N(0, s_o^2 I_2),   u_ik ~ Gamma(nu/2, nu/2),
    b_i ~ N(0, tau_o^2 I_2)

i.e. a steady offset ``b_i`` of the whole submission (work shifted to one side, or left on a
biased input) plus a 2-D Student-t with ``nu`` degrees of freedom and per-axis scale ``s_o``
(the operator's accuracy), independent over keyframes. The t tails are the robust loss: a
keyframe far from the others gets a small ``u_ik`` and hardly moves the estimate. ``tau_o``
is how far the operator's work is steadily off: an honest operator's is near zero, so the
level of the truth comes from them, while a submission shifted as a whole still tells the
shape of the track (and so which of its partners is accurate).

E-step (keyframes of one run, given every ``s_o`` and ``tau_o``; iterated):

    u_ik = (nu + 2) / (nu + |x_ik - b_i - t_k|^2 / s_o^2)
    t_k  = sum_i w_ik (x_ik - b_i) / sum_i w_ik,   w_ik = u_ik / s_o^2
    b    = A^-1 c,  A_ij = delta_ij (sum_k w_ik + 1/tau_i^2) - sum_k w_ik w_jk / W_k,
                    c_i = sum_k w_ik (x_ik - xbar_k),  W_k = sum_i w_ik,  xbar_k = sum_i w_ik x_ik / W_k
                    (the offsets' posterior mean with the t_k eliminated; variance V_i = (A^-1)_ii)
    P_k  = (1 + a_k' A^-1 a_k W_k) / W_k,  a_k = w_k / W_k   (per-axis variance of t_k)
    Q_ik = 1/W_k + e' A^-1 e,  e = delta_i - a_k   (per-axis variance of the residual x_ik - b_i - t_k)
    sigma_k = sqrt(P_k (nu + 2) / nu)   (the fused uncertainty: u is at most (nu + 2) / nu, a
                                         Gaussian's information 1)

M-step (Dawid-Skene generalised to positions: the truth is unknown, every operator is
scored against the weighted estimate of all the others, pooled over the runs they shared),
posterior modes under priors of ``n0_o`` pseudo-positions of scale ``s0_o`` and one
pseudo-submission of offset ``TAU0_M``:

    s_o^2   = (n0_o s0_o^2 + 1/2 sum_{i in o} sum_k u_ik (|x_ik - b_i - t_k|^2 + 2 Q_ik)) / (n0_o + n_o)
    tau_o^2 = (TAU0_M^2 + 1/2 sum_{i in o} (|b_i|^2 + 2 V_i)) / (1 + m_o)

``n_o`` is the number of positions of operator ``o``, ``m_o`` its submissions. The prior comes from gold runs (the
operator's measured mean error ``g``: for a 2-D Gaussian E|e| = s sqrt(pi/2), so
``s0 = g / sqrt(pi/2)``, worth ``GOLD_POSITIONS`` positions a gold run) or, for an operator
never measured, the median scale of the others worth one position. Submissions a reviewer
rejected enter the M-step at ``u = 1`` (their whole error counts against the operator). They
stay in the E-step at their own (large) scale: their errors are independent of everyone
else's, and without them two agreeing operators left alone on a run are indistinguishable
(only the sum of their variances shows). What is merged never includes them (``fuse`` over
the contributors).

Test of a submission ``i`` against the others (leave-one-out, so it cannot vouch for itself):

    r_ik = x_ik - t_k^(-i),   T_i = sum_k |r_ik - mean_k r_ik|^2 / (s_i^2 + P_k^(-i))  ~  chi^2 with 2 n_i - 2 dof

``s_i`` is the operator's accuracy measured elsewhere (gold runs, other runs), never fitted
to this very run. That measurement is itself uncertain: estimated from ``d_i`` squared
residuals, ``s_i^2 ~ s^2 chi^2_{d_i} / d_i``, so ``T_i`` over its dof follows an F distribution
with ``(2 n_i - 2, d_i)`` degrees of freedom (the chi-square above when ``d_i`` is infinite). A
submission whose ratio is beyond the ``1 - alpha`` quantile is off the consensus by more
than its operator's accuracy explains; an operator measured on little evidence must be
further off before the test says so. The others are fused with their steady offsets, and
``P_k^(-i)`` is their scatter alone. A second test looks for a steady offset, the mean residual
``|mean_k r_ik|^2 / (mean_k v_ik / n_i + TAU0_M^2 + L)  ~ chi^2_2``, with ``s_i^2`` in ``v``
at its 95 % upper bound ``s_i^2 d_i / chi^2_{d_i, 0.05}`` and ``L`` how unsure the others'
level is (their offsets' scales and the spread of their own mean residuals): work placed
consistently to one side is off however large its operator's measured scale (an adversary
measured by agreement alone would otherwise be excused as merely inaccurate). The smaller
p-value, doubled (Bonferroni), is the submission's.

With nothing known (no gold, fewer than three submissions) the fusion falls back to the
geometric median (``posefix.tasks.consensus``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from posefix.tasks.consensus import geometric_median

__all__ = [
    "NU", "GOLD_POSITIONS", "SIGMA_FLOOR_M", "RunObs", "Fused", "Estimate", "sigma_from_mean_error",
    "fuse", "estimate", "chi2_test", "ChiTest",
]

NU = 4.0                 # t degrees of freedom: Gaussian near the centre, 1/r^2 weight beyond ~2 s
GOLD_POSITIONS = 20.0    # a gold run's mean error counts as this many positions (its errors are correlated along the run)
SIGMA_FLOOR_M = 0.2      # no one places a keyframe better than the imagery's pixel (~0.2-0.3 m at zoom 19)
TAU0_M = SIGMA_FLOOR_M   # an honest operator's steady offset: the imagery's registration, about a pixel
SQRT_HALF_PI = float(np.sqrt(np.pi / 2))


def sigma_from_mean_error(mean_error_m: float) -> float:
    """Per-axis scale of a 2-D Gaussian whose mean radial error is ``mean_error_m``."""
    return max(float(mean_error_m) / SQRT_HALF_PI, SIGMA_FLOOR_M)


@dataclass
class RunObs:
    """The submissions of one run: positions, which take part, whose, and which pull the truth.

    x_m : (m, k, 2) metres;  valid : (m, k) bool;  op : (m,) operator index;
    truth : (m,) bool, False for work a reviewer rejected.
    """

    x_m: np.ndarray
    valid: np.ndarray
    op: np.ndarray
    truth: np.ndarray


@dataclass
class Fused:
    """t_m (k, 2) fused positions; sigma_m (k,) their per-axis standard deviation;
    w (m, k) each position's weight u/s^2 (0 where not valid or not truth); p_m2 (k,) the
    posterior variance of t_k; b_m (m, 2) each submission's steady offset and b_var_m2 (m,)
    its per-axis posterior variance (zero without an offset model); q_m2 (m, k) the posterior
    variance of each residual x_ik - b_i - t_k (what the M-step needs)."""

    t_m: np.ndarray
    sigma_m: np.ndarray
    w: np.ndarray
    p_m2: np.ndarray
    b_m: np.ndarray | None = None
    b_var_m2: np.ndarray | None = None
    q_m2: np.ndarray | None = None


def fuse(x_m: np.ndarray, valid: np.ndarray, sigma_m: np.ndarray, *, tau_m: np.ndarray | None = None, nu: float = NU,
         iters: int = 100, tol_m: float = 1e-4, t0_m: np.ndarray | None = None) -> Fused:
    """Robust inverse-variance fusion per keyframe (the E-step), started at ``t0_m`` or the
    weighted geometric median, so a far outlier never seeds the iteration. With ``tau_m``
    (m,) each submission also has a steady offset of that prior scale (None: no offsets)."""
    x = np.asarray(x_m, dtype=float)
    v = np.asarray(valid, dtype=bool)
    s2 = np.maximum(np.asarray(sigma_m, dtype=float), SIGMA_FLOOR_M) ** 2
    m, k, _ = x.shape
    inv_tau2 = None if tau_m is None else 1.0 / np.maximum(np.asarray(tau_m, dtype=float), SIGMA_FLOOR_M) ** 2
    t = geometric_median(x, v, 1.0 / s2) if t0_m is None else np.asarray(t0_m, dtype=float)
    t = np.where(np.isnan(t), 0.0, t)
    b = np.zeros((m, 2))
    w = np.zeros((m, k))
    a_inv = np.zeros((m, m))
    xv = np.where(v[..., None], x, 0.0)
    for _ in range(iters):
        r2 = np.sum((xv - b[:, None] - t[None]) ** 2, axis=2)
        u = (nu + 2.0) / (nu + r2 / s2[:, None])
        w = np.where(v, u / s2[:, None], 0.0)
        wsum = w.sum(axis=0)
        has = wsum > 0
        if inv_tau2 is not None and k:
            # offsets and positions at once for these weights (alternating would crawl along the
            # level the data leave free): with t_k eliminated, A b = c, A_ij = delta_ij
            # (sum_k w_ik + 1/tau_i^2) - sum_k w_ik w_jk / W_k, c_i = sum_k w_ik (x_ik - xbar_k)
            a_k = np.where(has, 1.0 / np.maximum(wsum, 1e-300), 0.0)
            xbar = np.einsum("ik,ikd->kd", w, xv) * a_k[:, None]
            a_mat = np.diag(w.sum(axis=1) + inv_tau2) - np.einsum("ik,jk->ij", w, w * a_k[None])
            a_inv = np.linalg.inv(a_mat)
            b_new = a_inv @ np.einsum("ik,ikd->id", w, np.where(v[..., None], xv - xbar[None], 0.0))
        else:
            b_new = b
        t_new = np.einsum("ik,ikd->kd", w, xv - b_new[:, None]) / np.maximum(wsum, 1e-300)[:, None]
        t_new = np.where(has[:, None], t_new, t)
        step = np.max(np.linalg.norm(t_new - t, axis=1)) if k else 0.0
        t, b = t_new, b_new
        if step < tol_m:
            break
    wsum = w.sum(axis=0)
    p_m2 = np.where(wsum > 0, 1.0 / np.maximum(wsum, 1e-300), 0.0)
    b_var = np.zeros(m)
    q_m2 = np.broadcast_to(p_m2[None], (m, k)).copy()
    if inv_tau2 is not None and k:
        # exact posterior variances of the linear model at the final weights: t_k's adds the
        # offsets' uncertainty through its weights a_k = w_k / W_k (a_k' A^-1 a_k)
        share = w * p_m2[None]
        p_m2 = np.where(wsum > 0, p_m2 + np.einsum("ik,ij,jk->k", share, a_inv, share), 0.0)
        b_var = np.diag(a_inv).copy()
        # each residual x_ik - b_i - t_k: Var(b_i + t_k) = 1/W_k + e' A^-1 e, e = delta_i - a_k
        # (b_i and t_k trade against each other, so their variances do not simply add)
        ainv_a = a_inv @ share                                             # (m, k)
        q_m2 = (1.0 / np.maximum(wsum, 1e-300))[None] + np.diag(a_inv)[:, None] - 2.0 * ainv_a \
            + np.einsum("ik,ik->k", share, ainv_a)[None]
    sigma = np.where(wsum > 0, np.sqrt(p_m2 * (nu + 2.0) / nu), np.nan)
    t = np.where((wsum > 0)[:, None], t, np.nan)
    return Fused(t, sigma, w, p_m2, b, b_var, np.maximum(q_m2, 0.0))


@dataclass
class Estimate:
    """sigma_m (n_ops,) per-axis accuracy of each operator; n_positions (n_ops,) positions
    behind it (prior pseudo-positions included); tau_m (n_ops,) each operator's steady-offset
    scale and n_submissions (n_ops,) the submissions behind it; fused: one Fused per run."""

    sigma_m: np.ndarray
    n_positions: np.ndarray
    fused: list[Fused]
    tau_m: np.ndarray | None = None
    n_submissions: np.ndarray | None = None


def estimate(runs: list[RunObs], prior_sigma_m: np.ndarray, prior_n: np.ndarray, *, nu: float = NU,
             iters: int = 100, tol: float = 1e-4) -> Estimate:
    """EM over operator accuracies, their steady offsets and the true positions of every run
    (see the module text). Offset scales start from the model without offsets, whose scales
    count an operator's offsets as error: where a run's level is ambiguous (no partner known
    to be steady), the operators steadiest elsewhere then set it, not a local optimum.

    prior_sigma_m : (n_ops,) NaN where the operator was never measured;
    prior_n : (n_ops,) pseudo-positions of that prior (0 where NaN).
    """
    plain = _em(runs, prior_sigma_m, prior_n, None, nu=nu, iters=iters, tol=tol)
    # scales start alike (but for gold-measured operators): without offsets two operators left
    # alone beside shifted work split their variance arbitrarily, and the offset model, which
    # reads the shifted work's shape, is to settle it, not inherit the split
    gold = ~np.isnan(np.asarray(prior_sigma_m, dtype=float)) & (np.asarray(prior_n, dtype=float) > 0)
    s_start = np.where(gold, plain.sigma_m, float(np.median(plain.sigma_m)))
    return _em(runs, prior_sigma_m, prior_n, plain.sigma_m, nu=nu, iters=iters, tol=tol, s_start=s_start)


def _em(runs: list[RunObs], prior_sigma_m: np.ndarray, prior_n: np.ndarray, tau_start: np.ndarray | None, *,
        nu: float, iters: int, tol: float, s_start: np.ndarray | None = None,
        fused_start: list[Fused] | None = None) -> Estimate:
    """The EM; offsets only with ``tau_start`` (their starting scales)."""
    prior_s = np.asarray(prior_sigma_m, dtype=float)
    n0 = np.where(np.isnan(prior_s), 0.0, np.asarray(prior_n, dtype=float))
    n_ops = len(prior_s)
    s = np.where(np.isnan(prior_s), np.nan, np.maximum(prior_s, SIGMA_FLOOR_M))
    if np.all(np.isnan(s)):
        s[:] = _pairwise_scale(runs)
    s = np.where(np.isnan(s), np.nanmedian(s), s)
    if s_start is not None:
        s = np.asarray(s_start, dtype=float).copy()
    tau = None if tau_start is None else np.asarray(tau_start, dtype=float).copy()
    fused: list[Fused] = []
    fused_prev: list[Fused] = list(fused_start or [])
    n_pos = np.zeros(n_ops)
    for _ in range(iters):
        ss = np.zeros(n_ops)
        n_pos = np.zeros(n_ops)
        bb = np.zeros(n_ops)
        n_sub = np.zeros(n_ops)
        fused = []
        for j, run in enumerate(runs):
            f = fuse(run.x_m, run.valid, s[run.op], tau_m=None if tau is None else tau[run.op], nu=nu,
                     t0_m=fused_prev[j].t_m if fused_prev else None)
            fused.append(f)
            b = f.b_m if f.b_m is not None else np.zeros((len(run.op), 2))
            r2 = np.sum((run.x_m - b[:, None] - np.nan_to_num(f.t_m)[None]) ** 2, axis=2)
            s2 = s[run.op][:, None] ** 2
            u = np.where(run.truth[:, None], (nu + 2.0) / (nu + r2 / s2), 1.0)
            # the truth's own uncertainty counts only where the truth is defined
            here = run.valid & ~np.isnan(f.t_m[:, 0])[None]
            term = np.where(here, u * (r2 + 2.0 * f.q_m2), 0.0)
            np.add.at(ss, run.op, term.sum(axis=1))
            np.add.at(n_pos, run.op, here.sum(axis=1))
            took = here.any(axis=1)
            if f.b_var_m2 is not None:
                np.add.at(bb, run.op, np.where(took, np.sum(b ** 2, axis=1) + 2.0 * f.b_var_m2, 0.0))
            np.add.at(n_sub, run.op, took.astype(float))
        # operators never measured borrow the others' median scale, as one position
        known = (n0 > 0) | (n_pos > 0)
        pop = np.median(s[known]) if known.any() else float(np.nanmedian(s))
        s0 = np.where(n0 > 0, prior_s, pop)
        n0_eff = np.where(n0 > 0, n0, 1.0)
        s_new = np.sqrt((n0_eff * s0 ** 2 + 0.5 * ss) / (n0_eff + n_pos))
        s_new = np.maximum(np.nan_to_num(s_new, nan=pop), SIGMA_FLOOR_M)
        change = float(np.max(np.abs(s_new - s) / s))
        tau_new = tau
        if tau is not None:
            tau_new = np.maximum(np.sqrt((TAU0_M ** 2 + 0.5 * bb) / (1.0 + n_sub)), SIGMA_FLOOR_M)
            change = max(change, float(np.max(np.abs(tau_new - tau) / tau)))
        done = change < tol
        s, tau = s_new, tau_new
        fused_prev = fused
        if done:
            break
    return Estimate(s, n_pos + n0, fused, tau, n_sub)


def _pairwise_scale(runs: list[RunObs]) -> float:
    """A starting scale when nothing is known: half the median pairwise distance / sqrt(2)."""
    d = []
    for run in runs:
        x, v = run.x_m, run.valid
        for a in range(len(x)):
            for b in range(a + 1, len(x)):
                both = v[a] & v[b]
                if both.any():
                    d.append(np.median(np.linalg.norm(x[a][both] - x[b][both], axis=1)))
    return max(float(np.median(d)) / 2.0, SIGMA_FLOOR_M) if d else 1.0


@dataclass
class ChiTest:
    """statistic (m,), dof (m,), p (m,) upper-tail probability; distance_m (m,) mean distance
    to the leave-one-out consensus; expected_m (m,) the mean distance the model expects."""

    statistic: np.ndarray
    dof: np.ndarray
    p: np.ndarray
    distance_m: np.ndarray
    expected_m: np.ndarray


def chi2_test(x_m: np.ndarray, valid: np.ndarray, sigma_fit_m: np.ndarray, sigma_ref_m: np.ndarray,
              *, dof_ref: np.ndarray | None = None, contributes: np.ndarray | None = None,
              tau_fit_m: np.ndarray | None = None, tau_level_m: np.ndarray | None = None, nu: float = NU) -> ChiTest:
    """Each submission against the robust fusion of the others that ``contributes`` (weights
    ``sigma_fit_m``, steady offsets of scale ``tau_fit_m``), scaled by its operator's accuracy
    measured elsewhere (``sigma_ref_m``, measured with ``dof_ref`` (m,) degrees of freedom,
    default infinite). The spread is tested about the submission's own mean residual and the
    mean residual (its steady offset) apart; how much each other sets the level is judged by
    ``tau_level_m`` (the operators' steadiness measured elsewhere; default ``tau_fit_m``)."""
    tau_level_m = tau_fit_m if tau_level_m is None else tau_level_m
    x = np.asarray(x_m, dtype=float)
    v = np.asarray(valid, dtype=bool)
    m = len(x)
    stat, dof, p = np.zeros(m), np.zeros(m), np.ones(m)
    dist, expect = np.full(m, np.nan), np.full(m, np.nan)
    s_ref = np.maximum(np.asarray(sigma_ref_m, dtype=float), SIGMA_FLOOR_M)
    d_ref = np.full(m, np.inf) if dof_ref is None else np.asarray(dof_ref, dtype=float)
    pull = np.ones(m, dtype=bool) if contributes is None else np.asarray(contributes, dtype=bool)
    for i in range(m):
        others = (np.arange(m) != i) & pull
        if not others.any():
            continue
        f = fuse(x[others], v[others], np.asarray(sigma_fit_m, dtype=float)[others], nu=nu,
                 tau_m=None if tau_fit_m is None else np.asarray(tau_fit_m, dtype=float)[others])
        ok = v[i] & ~np.isnan(f.t_m[:, 0])
        if ok.sum() < 2:
            continue
        wsum = f.w[:, ok].sum(axis=0)
        shape_var = (nu + 2.0) / nu / wsum                       # the others' scatter at each keyframe
        level_var = float(np.mean(f.p_m2[ok] - 1.0 / wsum))      # how unsure their common level is
        r = x[i][ok] - f.t_m[ok]
        r_mean = np.mean(r, axis=0)
        var = s_ref[i] ** 2 + shape_var
        stat[i] = float(np.sum(np.sum((r - r_mean) ** 2, axis=1) / var))
        dof[i] = 2.0 * (ok.sum() - 1)
        p_spread = (stats.chi2.sf(stat[i], dof[i]) if np.isinf(d_ref[i])
                    else stats.f.sf(stat[i] / dof[i], dof[i], max(d_ref[i], 1.0)))
        # a steady offset (the same direction all along the run) is no accuracy at all, however
        # large the operator's measured scale or offsets: the mean residual of n honest
        # positions has per-axis variance mean(var) / n, plus how unsure the others' level is
        # (their offsets' scales, and the spread of their own mean residuals: two adversaries
        # cannot make the honest one look offset)
        # An operator's scale known from d_i residuals enters at its 95 % upper bound
        # s^2 d / chi2_{d, 0.05}: the other terms are known as they are, so no F test here.
        s_up2 = s_ref[i] ** 2 * (1.0 if np.isinf(d_ref[i]) else max(d_ref[i], 1.0) / stats.chi2.ppf(0.05, max(d_ref[i], 1.0)))
        offset = float(np.sum(r_mean ** 2) / (np.mean(s_up2 + shape_var) / ok.sum() + TAU0_M ** 2 + level_var
                                              + _others_offset_var(x[others], v[others], f, ok,
                                                                   None if tau_level_m is None else np.asarray(tau_level_m)[others])))
        p_offset = stats.chi2.sf(offset, 2.0)
        p[i] = float(min(1.0, 2.0 * min(p_spread, p_offset)))  # two tests: Bonferroni
        dist[i] = float(np.mean(np.linalg.norm(r, axis=1)))
        expect[i] = float(np.mean(np.sqrt(var + level_var))) * SQRT_HALF_PI
    return ChiTest(stat, dof, p, dist, expect)


def _others_offset_var(x_m: np.ndarray, valid: np.ndarray, f: Fused, ok: np.ndarray,
                       tau_m: np.ndarray | None = None) -> float:
    """Per-axis variance of the consensus's own steady offset: the spread of the contributing
    submissions' mean residuals about it (0 when they share one), each weighted by how much
    it sets the level: its share of the weight, or with offsets in the model its level
    precision 1 / (tau^2 + 1 / sum_k w_k)."""
    w = np.where(valid[:, ok], f.w[:, ok], 0.0)
    share = w.sum(axis=1)
    if share.sum() <= 0:
        return 0.0
    if tau_m is not None:
        share = np.where(share > 0, 1.0 / (np.maximum(np.asarray(tau_m, dtype=float), SIGMA_FLOOR_M) ** 2
                                           + 1.0 / np.maximum(share, 1e-300)), 0.0)
    share = share / share.sum()
    r = np.where(valid[:, ok, None], x_m[:, ok] - f.t_m[None, ok], 0.0)
    mean = r.sum(axis=1) / np.maximum(valid[:, ok].sum(axis=1), 1)[:, None]     # (m, 2)
    return float(np.sum(share * np.sum(mean ** 2, axis=1)) / 2.0)
