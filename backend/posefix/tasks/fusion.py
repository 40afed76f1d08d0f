"""Operator-weighted consensus of positions: per-operator accuracy by EM (Dawid-Skene for
positions), robust inverse-variance fusion per keyframe, and a chi-square test of each
submission against the others (numpy/scipy only).

Model. Submission ``i`` (operator ``o = o(i)``) places keyframe ``k`` of its run at
``x_ik`` (local East-North metres, 2-D); the truth is ``t_k``. A submission errs by

    x_ik = t_k + e_ik / sqrt(u_ik),   e_ik ~ N(0, s_o^2 I_2),   u_ik ~ Gamma(nu/2, nu/2)

i.e. a 2-D Student-t with ``nu`` degrees of freedom and per-axis scale ``s_o`` (the
operator's accuracy), independent over keyframes. The t tails are the robust loss: a
keyframe far from the others gets a small ``u_ik`` and hardly moves the estimate.

E-step (keyframes of one run, given every ``s_o``):

    u_ik = (nu + 2) / (nu + |x_ik - t_k|^2 / s_o^2)
    t_k  = sum_i w_ik x_ik / sum_i w_ik,   w_ik = u_ik / s_o^2          (iterated)
    P_k  = 1 / sum_i (nu / (nu + 2)) w_ik   (per-axis variance of t_k, the fused uncertainty:
                                             u is at most (nu + 2) / nu, a Gaussian's information 1)

M-step (Dawid-Skene generalised to positions: the truth is unknown, every operator is
scored against the weighted estimate of all the others, pooled over the runs they shared),
the posterior mode under a prior of ``n0_o`` pseudo-positions of scale ``s0_o``:

    s_o^2 = (n0_o s0_o^2 + 1/2 sum_{i in o} sum_k u_ik (|x_ik - t_k|^2 + 2 P_k)) / (n0_o + n_o)

``n_o`` is the number of positions of operator ``o``. The prior comes from gold runs (the
operator's measured mean error ``g``: for a 2-D Gaussian E|e| = s sqrt(pi/2), so
``s0 = g / sqrt(pi/2)``, worth ``GOLD_POSITIONS`` positions a gold run) or, for an operator
never measured, the median scale of the others worth one position. Submissions a reviewer
rejected enter the M-step at ``u = 1`` (their whole error counts against the operator). They
stay in the E-step at their own (large) scale: their errors are independent of everyone
else's, and without them two agreeing operators left alone on a run are indistinguishable
(only the sum of their variances shows). What is merged never includes them (``fuse`` over
the contributors).

Test of a submission ``i`` against the others (leave-one-out, so it cannot vouch for itself):

    T_i = sum_k |x_ik - t_k^(-i)|^2 / (s_i^2 + P_k^(-i))  ~  chi^2 with 2 n_i dof

``s_i`` is the operator's accuracy measured elsewhere (gold runs, other runs), never fitted
to this very run. That measurement is itself uncertain: estimated from ``d_i`` squared
residuals, ``s_i^2 ~ s^2 chi^2_{d_i} / d_i``, so ``(T_i / 2 n_i)`` follows an F distribution
with ``(2 n_i, d_i)`` degrees of freedom (the chi-square above when ``d_i`` is infinite). A
submission whose ratio is beyond the ``1 - alpha`` quantile is off the consensus by more
than its operator's accuracy explains; an operator measured on little evidence must be
further off before the test says so. A second test looks for a steady offset, the mean
residual ``n_i |mean_k r_ik|^2 / mean_k v_ik ~ chi^2_2`` (same F treatment): work placed
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
    posterior variance given the weights, 1 / sum w (what the M-step needs)."""

    t_m: np.ndarray
    sigma_m: np.ndarray
    w: np.ndarray
    p_m2: np.ndarray


def fuse(x_m: np.ndarray, valid: np.ndarray, sigma_m: np.ndarray, *, nu: float = NU, iters: int = 50,
         tol_m: float = 1e-4, t0_m: np.ndarray | None = None) -> Fused:
    """Robust inverse-variance fusion per keyframe (the E-step), started at ``t0_m`` or the
    weighted geometric median, so a far outlier never seeds the iteration."""
    x = np.asarray(x_m, dtype=float)
    v = np.asarray(valid, dtype=bool)
    s2 = np.maximum(np.asarray(sigma_m, dtype=float), SIGMA_FLOOR_M) ** 2
    m, k, _ = x.shape
    t = geometric_median(x, v, 1.0 / s2) if t0_m is None else np.asarray(t0_m, dtype=float)
    t = np.where(np.isnan(t), 0.0, t)
    w = np.zeros((m, k))
    for _ in range(iters):
        r2 = np.sum((x - t[None]) ** 2, axis=2)
        u = (nu + 2.0) / (nu + r2 / s2[:, None])
        w = np.where(v, u / s2[:, None], 0.0)
        wsum = w.sum(axis=0)
        t_new = np.einsum("ik,ikd->kd", w, np.where(v[..., None], x, 0.0)) / np.maximum(wsum, 1e-300)[:, None]
        t_new = np.where((wsum > 0)[:, None], t_new, t)
        step = np.max(np.linalg.norm(t_new - t, axis=1)) if k else 0.0
        t = t_new
        if step < tol_m:
            break
    wsum = w.sum(axis=0)
    p_m2 = np.where(wsum > 0, 1.0 / np.maximum(wsum, 1e-300), 0.0)
    sigma = np.where(wsum > 0, np.sqrt(p_m2 * (nu + 2.0) / nu), np.nan)
    t = np.where((wsum > 0)[:, None], t, np.nan)
    return Fused(t, sigma, w, p_m2)


@dataclass
class Estimate:
    """sigma_m (n_ops,) per-axis accuracy of each operator; n_positions (n_ops,) positions
    behind it (prior pseudo-positions included); fused: one Fused per run."""

    sigma_m: np.ndarray
    n_positions: np.ndarray
    fused: list[Fused]


def estimate(runs: list[RunObs], prior_sigma_m: np.ndarray, prior_n: np.ndarray, *, nu: float = NU,
             iters: int = 100, tol: float = 1e-4) -> Estimate:
    """EM over operator accuracies and the true positions of every run (see the module text).

    prior_sigma_m : (n_ops,) NaN where the operator was never measured;
    prior_n : (n_ops,) pseudo-positions of that prior (0 where NaN).
    """
    prior_s = np.asarray(prior_sigma_m, dtype=float)
    n0 = np.where(np.isnan(prior_s), 0.0, np.asarray(prior_n, dtype=float))
    n_ops = len(prior_s)
    s = np.where(np.isnan(prior_s), np.nan, np.maximum(prior_s, SIGMA_FLOOR_M))
    if np.all(np.isnan(s)):
        s[:] = _pairwise_scale(runs)
    s = np.where(np.isnan(s), np.nanmedian(s), s)
    fused: list[Fused] = []
    fused_prev: list[Fused] = []
    n_pos = np.zeros(n_ops)
    for _ in range(iters):
        ss = np.zeros(n_ops)
        n_pos = np.zeros(n_ops)
        fused = []
        for j, run in enumerate(runs):
            f = fuse(run.x_m, run.valid, s[run.op], nu=nu, t0_m=fused_prev[j].t_m if fused_prev else None)
            fused.append(f)
            r2 = np.sum((run.x_m - np.nan_to_num(f.t_m)[None]) ** 2, axis=2)
            s2 = s[run.op][:, None] ** 2
            u = np.where(run.truth[:, None], (nu + 2.0) / (nu + r2 / s2), 1.0)
            # the truth's own uncertainty counts only where the truth is defined
            p = f.p_m2
            term = np.where(run.valid & ~np.isnan(f.t_m[:, 0])[None], u * (r2 + 2.0 * p[None]), 0.0)
            np.add.at(ss, run.op, term.sum(axis=1))
            np.add.at(n_pos, run.op, (run.valid & ~np.isnan(f.t_m[:, 0])[None]).sum(axis=1))
        # operators never measured borrow the others' median scale, as one position
        known = (n0 > 0) | (n_pos > 0)
        pop = np.median(s[known]) if known.any() else float(np.nanmedian(s))
        s0 = np.where(n0 > 0, prior_s, pop)
        n0_eff = np.where(n0 > 0, n0, 1.0)
        s_new = np.sqrt((n0_eff * s0 ** 2 + 0.5 * ss) / (n0_eff + n_pos))
        s_new = np.maximum(np.nan_to_num(s_new, nan=pop), SIGMA_FLOOR_M)
        done = np.max(np.abs(s_new - s) / s) < tol
        s = s_new
        fused_prev = fused
        if done:
            break
    return Estimate(s, n_pos + n0, fused)


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
              *, dof_ref: np.ndarray | None = None, contributes: np.ndarray | None = None, nu: float = NU) -> ChiTest:
    """Each submission against the robust fusion of the others that ``contributes`` (weights
    ``sigma_fit_m``), scaled by its operator's accuracy measured elsewhere (``sigma_ref_m``,
    measured with ``dof_ref`` (m,) degrees of freedom, default infinite)."""
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
        f = fuse(x[others], v[others], np.asarray(sigma_fit_m, dtype=float)[others], nu=nu)
        ok = v[i] & ~np.isnan(f.t_m[:, 0])
        if not ok.any():
            continue
        r = x[i][ok] - f.t_m[ok]
        r2 = np.sum(r ** 2, axis=1)
        var = s_ref[i] ** 2 + f.sigma_m[ok] ** 2
        stat[i] = float(np.sum(r2 / var))
        dof[i] = 2.0 * ok.sum()
        p_spread = (stats.chi2.sf(stat[i], dof[i]) if np.isinf(d_ref[i])
                    else stats.f.sf(stat[i] / dof[i], dof[i], max(d_ref[i], 1.0)))
        # a steady offset (the same direction all along the run) is no accuracy at all, however
        # large the operator's measured scale: the mean residual of n honest positions has
        # per-axis variance mean(var) / n, plus how far the others' own steady offsets leave
        # their consensus unsure (two adversaries cannot make the honest one look offset)
        offset = float(np.sum(np.mean(r, axis=0) ** 2) / (np.mean(var) / ok.sum() + _others_offset_var(x[others], v[others], f, ok)))
        p_offset = (stats.chi2.sf(offset, 2.0) if np.isinf(d_ref[i])
                    else stats.f.sf(offset / 2.0, 2.0, max(d_ref[i], 1.0)))
        p[i] = float(min(1.0, 2.0 * min(p_spread, p_offset)))  # two tests: Bonferroni
        dist[i] = float(np.mean(np.sqrt(r2)))
        expect[i] = float(np.mean(np.sqrt(var))) * SQRT_HALF_PI
    return ChiTest(stat, dof, p, dist, expect)


def _others_offset_var(x_m: np.ndarray, valid: np.ndarray, f: Fused, ok: np.ndarray) -> float:
    """Per-axis variance of the consensus's own steady offset: the weighted spread of the
    contributing submissions' mean residuals about it (0 when they share one)."""
    w = np.where(valid[:, ok], f.w[:, ok], 0.0)
    share = w.sum(axis=1)
    if share.sum() <= 0:
        return 0.0
    share = share / share.sum()
    r = np.where(valid[:, ok, None], x_m[:, ok] - f.t_m[None, ok], 0.0)
    mean = r.sum(axis=1) / np.maximum(valid[:, ok].sum(axis=1), 1)[:, None]     # (m, 2)
    return float(np.sum(share * np.sum(mean ** 2, axis=1)) / 2.0)
