"""Per-run calibration: the noise model estimated from the run's own edits, and the model the
run's held-out edits choose.

Data, per horizontal axis, at the edit times t_k (sorted): the pose's error at the edit
``y_k = p~_k - c_k`` and, with raw GNSS, the fix's error there ``d_k = g~_k - c_k``
(``drift.edit_offsets``: the fix made robust by a median over neighbouring keyframes).

1. Processes from variograms.  For pairs of edits j > k at lag h = t_j - t_k the robust
   (Cressie-Hawkins) semivariance per axis is

       gamma(h) = (mean |y_j - y_k|^(1/2))^4 / (0.457 + 0.494 / N) / 2

   pooled over lag bins (both axes).  Two processes are fitted by weighted least squares
   (weights N / gamma^2), each with a nugget n (edit noise plus white error):

       random walk:    gamma(h) = n + q h / 2
       Gauss-Markov:   gamma(h) = n + sigma^2 (1 - exp(-h / tau))     (tau on a log grid)

   The same for d gives the fix's error process (white part n, bias sigma_b, tau_b; the
   robust estimator keeps outliers from inflating it).
2. Smoothers and leave-one-out residuals.  Each process is a linear-Gaussian state-space
   model observed at the edits (``drift.smooth_gauss_markov``: Kalman filter and RTS
   smoother).  The smoothed variance P_k is the diagonal of the inverse of the banded
   (tridiagonal) information matrix, so the prediction of edit k from all the others follows
   without refitting (R = n the observation variance):

       r_k,loo = (y_k - x_k) R / (R - P_k),      V_k,loo = P_k R / (R - P_k) + R

   (``loo_residuals``; equal to refitting without edit k, tested).  Of the two processes the
   one with the smaller leave-one-out RMSE describes the pose's error (``best_process``).
3. How far the fix's error and the pose's error are the same error.  At held-out edit k the
   pose predicts the truth with error r_e = y_k - y^_k,-k and the bias-corrected fix with
   error r_g = d_k - d^_k,-k.  The fused prediction (1 - w) r_e + w r_g is best at

       w* = clip(sum r_e . (r_e - r_g) / sum |r_e - r_g|^2, 0, 1)

   A pose that already fused the fix (EKF, GNSS/INS) carries the same error: r_g follows r_e
   and w* falls towards zero (reported as ``gnss_share``).
4. Model choice by the run's own held-out edits.  The candidates: ``gnss`` (the location
   term with the drift model, the GNSS level model and the edit bends: the calibrated model),
   ``plain`` (the location term at its configured sigma, no drift model, no bends: GTSAM's
   standard graph), ``relative`` (pose plus edits, no location term: naive interpolation's own
   assumption, solved with the relative terms) and ``naive`` (naive interpolation itself,
   ``engine.naive``); without raw GNSS only the last two.  Each of up to ``CV_MAX_HELD_OUT``
   edits is held out in turn and predicted without it (the engine's models by a local solve
   held at the edits either side, their drift re-estimated without the edit, so the edit
   cannot vouch for itself; naive by interpolating the others).
5. Edit spacing.  A held-out edit sits mid-way in a gap twice the edits' spacing; the run's
   keyframes sit in gaps of one spacing, on average nearer an edit.  A model that keeps the
   pose's shape between edits (gnss, relative, naive) has an error bridged between them,
   smallest at the edits: the pose process's variance V_i bridged to each keyframe
   (``drift.bias_at``, observed with the edits' own noise) against its leave-one-out variance
   at the held-out edits gives f = sqrt(mean_i V_i / mean_k V_loo,k) (a random walk:
   1/sqrt 3), kept in [0.5, 1].  The plain location term's error follows the fixes between the
   edits and is pinned at them: half bridged, s = sqrt(f) (between f and an error spread evenly,
   1).  Edits that carry their own sigma (``Edit.sigma_m``, a crowd's fused positions) are
   observed with that noise in the band, and naive interpolation, which passes each edit's
   noise straight through (full at the edits, where the smoother averages it), gets its own
   ratio from its interpolation weights (``naive_ratio``); an operator's clicks (no sigma) keep
   f for naive too.  Each candidate's run-wide RMSE is predicted as s_m times its held-out RMSE, and the
   models are compared on that scale (``choose``): the calibrated model stands unless another's
   paired gain in scaled squared error d_k = s_inc^2 |r_k,inc|^2 - s_m^2 |r_k,m|^2 has a mean
   above ``SWITCH_Z`` standard errors (this scale serves the comparison; the reported
   prediction is section 6's).  With fewer than ``MIN_EDITS`` edits nothing can be held
   out and the stated prior decides (``prior``: the calibrated model with the drift prior,
   whose bias fades from each edit over its tau of a minute, so one edit moves the run near
   it, not the whole run).
6. Predicted accuracy along the run at the real spacing.  A held-out edit is predicted across
   a gap twice the edits' spacing; the run's samples lie in gaps of one spacing, many of them
   near an edit, and an end edit is predicted from one side only.  How much smaller the
   run-wide error is than the held-out one depends on the pose error's shape below the
   spacing, which the edits cannot show: it is taken from a process fitted to their
   variogram, averaged over the shapes it allows.  The pose's error is x(t) + w(t): x a
   continuous process with semivariogram g(h) = s^2 F(h / l), w white of variance n_w per axis
   (the pose's sample-to-sample jitter: the second differences of a white error have variance
   6 n_w, estimated by their median absolute deviation, ``pose_jitter_m2``), each edit off
   the truth by white noise n_e (the edits' sigma).  Two shapes, each on a grid of l:

       Gauss-Markov (a random walk as l grows):   F(u) = 1 - exp(-u)
       integrated velocity error (Matern 3/2):    F(u) = 1 - (1 + u) exp(-u)

   (a pose's position error integrates its velocity error: smooth below its correlation
   time, F ~ u^2, where a random walk has F ~ u).  For each, s^2 is the weighted least-squares
   fit of gamma(h) - n_e - n_w (section 1's weights N / gamma^2), and its weight among them
   exp(-cost / 4) (the cost is sum N (gamma^ - gamma)^2 / gamma^2, gamma^ of variance
   2 gamma^2 / N).  Linear interpolation between the edits a, b either side of time t
   (gap G, t at u = (t - t_a) / G) leaves per axis the expected squared error

       V(t) = 2 (1 - u) g(u G) + 2 u g((1 - u) G) - 2 u (1 - u) g(G)
              + n_w (1 + (1 - u)^2 + u^2) + n_e ((1 - u)^2 + u^2)

   (a random walk, g(h) = q h / 2: V = q G u (1 - u), whose mean over a gap is q G / 6 and
   q G / 4 at its middle), beyond the first or last edit, at a distance d,
   V = 2 g(d) + 2 n_w + n_e; the held-out edit k is predicted across the gap its neighbours
   leave, against an edit with its own noise: V_k = V(t_k) + n_e.  Then

       R^2 = sum_shapes weight * mean_samples V(t) / mean_picks V_k

   and the chosen model's predicted RMSE is R (plain: sqrt(R), its error half bridged as in
   section 5) times its held-out RMSE: the process only sets the ratio, the scale is the
   model's own held-out error.  The 1-sigma along the run follows sqrt(V) at the keyframes
   (flat for plain), scaled so that its RMS over the samples is the predicted RMSE.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from posefix.core.drift import bias_at, smooth_gauss_markov

MIN_EDITS = 3  # fewer: nothing to hold out, the prior decides
CV_MAX_HELD_OUT = 12  # edits held out one at a time (spread evenly): enough to rank two models
SWITCH_Z = 0.5  # another model replaces the calibrated one when its paired gain on the held-out edits exceeds this many standard errors
RW_TAU_S = 1e7  # a random walk as a Gauss-Markov process with a correlation time far beyond any run
TAU_GRID_S = np.geomspace(10.0, 1e4, 31)


@dataclass(frozen=True)
class ProcessFit:
    """A scalar error process per axis: nugget (white, m^2) plus a random walk or Gauss-Markov part."""

    kind: str  # "random_walk" | "gauss_markov"
    nugget_m2: float
    sigma2_m2: float  # stationary variance (random walk: q tau / 2 at RW_TAU_S)
    tau_s: float
    q_m2_per_s: float  # wander rate: q = 2 sigma^2 / tau

    def to_json(self) -> dict:
        return {"kind": self.kind, "nugget_m": float(np.sqrt(self.nugget_m2)), "q_m2_per_s": float(self.q_m2_per_s),
                "sigma_m": None if self.kind == "random_walk" else float(np.sqrt(self.sigma2_m2)),
                "tau_s": None if self.kind == "random_walk" else float(self.tau_s)}


@dataclass(frozen=True)
class Calibration:
    """What the run's own edits say: the chosen model and how well it predicts held-out edits.

    model: "gnss" | "plain" | "relative" | "naive" | "prior"; cv_rmse_m: leave-one-out horizontal RMSE at the
    edits of the chosen model (NaN with fewer than MIN_EDITS); cv_rmse_by_model: each
    candidate's; predicted_rmse_m: the run-wide RMSE predicted at the real spacing (section 6); gnss_share:
    w* (section 3); sigma_m (k,): horizontal 1-sigma of the correction per keyframe.
    """

    model: str
    cv_rmse_m: float
    cv_rmse_by_model: dict = field(default_factory=dict)
    predicted_rmse_m: float = float("nan")
    gnss_share: float = float("nan")
    n_edits: int = 0
    pose: ProcessFit | None = None
    gnss: ProcessFit | None = None
    sigma_m: np.ndarray | None = None
    spacing_ratio: float = float("nan")  # R of module docstring 6: run-wide over held-out RMSE

    def to_json(self) -> dict:
        def num(v):
            return None if v is None or not np.isfinite(v) else round(float(v), 4)

        return {"model": self.model, "cv_rmse_m": num(self.cv_rmse_m), "predicted_rmse_m": num(self.predicted_rmse_m),
                "cv_rmse_by_model": {k: num(v) for k, v in self.cv_rmse_by_model.items()},
                "gnss_share": num(self.gnss_share), "n_edits": int(self.n_edits),
                "spacing_ratio": num(self.spacing_ratio),
                "pose_process": None if self.pose is None else self.pose.to_json(),
                "gnss_process": None if self.gnss is None else self.gnss.to_json()}


def variogram(t_s: np.ndarray, y: np.ndarray, max_lag: int = 8, n_bins: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust semivariance per axis of y (m,d) at sorted times: lag centres (b,), gamma (b,), pairs (b,).

    Pairs of edits up to ``max_lag`` apart in order, binned by log lag (Cressie-Hawkins,
    module docstring 1).
    """
    m = len(t_s)
    lags, roots = [], []
    for j in range(1, min(max_lag, m - 1) + 1):
        h = t_s[j:] - t_s[:-j]
        diff = np.abs(y[j:] - y[:-j])  # (m-j, d)
        lags.append(np.repeat(h, y.shape[1]))
        roots.append(np.sqrt(diff).ravel())
    if not lags:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    h, r = np.concatenate(lags), np.concatenate(roots)
    ok = h > 0
    h, r = h[ok], r[ok]
    if len(h) == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    edges = np.geomspace(h.min() * 0.999, h.max() * 1.001, n_bins + 1)
    b = np.clip(np.searchsorted(edges, h, side="right") - 1, 0, n_bins - 1)
    n = np.bincount(b, minlength=n_bins).astype(float)
    s = np.bincount(b, weights=r, minlength=n_bins)
    sh = np.bincount(b, weights=h, minlength=n_bins)
    keep = n > 0
    n, s, sh = n[keep], s[keep], sh[keep]
    gamma = (s / n) ** 4 / (0.457 + 0.494 / n) / 2.0
    return sh / n, gamma, n


def _nonneg_lsq(A: np.ndarray, g: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:
    """Weighted least squares of g ~ A x with x >= 0 (two unknowns: every active set tried)."""
    best, best_cost = np.zeros(A.shape[1]), np.inf
    sw = np.sqrt(w)
    for mask in ((True, True), (True, False), (False, True)):
        cols = np.flatnonzero(mask)
        x_c, *_ = np.linalg.lstsq(A[:, cols] * sw[:, None], g * sw, rcond=None)
        if np.any(x_c < 0):
            continue
        x = np.zeros(A.shape[1])
        x[cols] = x_c
        cost = float(np.sum(w * (A @ x - g) ** 2))
        if cost < best_cost:
            best, best_cost = x, cost
    return best, best_cost


def _nonneg_lsq_grid(F: np.ndarray, g: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``_nonneg_lsq`` of g ~ x0 + x1 F[i] for every row of F (m, b) at once: the 2x2 normal
    equations per row in closed form (every active set tried, the cheapest feasible kept);
    a row whose two columns are (nearly) collinear goes through ``_nonneg_lsq``.
    Returns x (m, 2) and the cost (m,)."""
    s11 = float(np.sum(w))
    s12 = F @ w
    s22 = (F * F) @ w
    b1 = float(np.sum(w * g))
    b2 = F @ (w * g)
    det = s11 * s22 - s12 * s12
    cand = np.zeros((3,) + F.shape[:1] + (2,))
    with np.errstate(divide="ignore", invalid="ignore"):
        cand[0, :, 0] = (s22 * b1 - s12 * b2) / det
        cand[0, :, 1] = (s11 * b2 - s12 * b1) / det
        cand[1, :, 0] = b1 / s11
        cand[2, :, 1] = b2 / s22
    ok = np.all(cand >= 0, axis=2) & np.all(np.isfinite(cand), axis=2)
    cand = np.where(np.isfinite(cand), cand, 0.0)
    cost = np.einsum("b,sib->si", w, (cand[:, :, :1] + cand[:, :, 1:] * F[None] - g) ** 2)
    cost = np.where(ok, cost, np.inf)
    pick = np.argmin(cost, axis=0)  # first of equal costs: the order _nonneg_lsq tries them in
    rows = np.arange(F.shape[0])
    x, c = cand[pick, rows], cost[pick, rows]
    x[~np.isfinite(c)] = 0.0
    for i in np.flatnonzero(~(det > 1e-9 * s11 * s22)):
        x[i], c[i] = _nonneg_lsq(np.column_stack([np.ones_like(F[i]), F[i]]), g, w)
    return x, c


def fit_processes(h: np.ndarray, gamma: np.ndarray, n: np.ndarray, floor_m2: float) -> list[ProcessFit]:
    """Random-walk and Gauss-Markov fits (with nugget >= ``floor_m2``) to a variogram."""
    if len(h) == 0:
        return []
    w = n / np.maximum(gamma, floor_m2) ** 2
    fits = []
    x, _ = _nonneg_lsq(np.column_stack([np.ones_like(h), h / 2.0]), gamma, w)
    q = max(x[1], 1e-8)
    fits.append(ProcessFit("random_walk", max(x[0], floor_m2), q * RW_TAU_S / 2.0, RW_TAU_S, q))
    xs, costs = _nonneg_lsq_grid(1.0 - np.exp(-h[None, :] / TAU_GRID_S[:, None]), gamma, w)
    # the first of costs equal to round-off (a nugget alone costs the same at every tau), as a
    # loop over the grid keeping strict improvements does
    tie = 1e-9 * (costs.min() + 1e-6 * float(np.sum(w * gamma**2)))
    i = int(np.flatnonzero(costs <= costs.min() + tie)[0])
    tau, x = TAU_GRID_S[i], xs[i]
    s2 = max(x[1], 1e-8)
    fits.append(ProcessFit("gauss_markov", max(x[0], floor_m2), s2, float(tau), 2.0 * s2 / tau))
    return fits


def loo_residuals(t_s: np.ndarray, y: np.ndarray, fit: ProcessFit,
                  r_m2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Leave-one-out residuals (m,d) and predictive variances (m,) of a process observed at the
    edits (module docstring 2), with the smoothed means (m,d) and variances (m,).  ``r_m2`` (m,):
    each edit's own observation variance (default: the fit's nugget for all)."""
    R = fit.nugget_m2 if r_m2 is None else np.asarray(r_m2, dtype=float)
    xs, P = smooth_gauss_markov(t_s, y, np.broadcast_to(R, (len(t_s),)), fit.sigma2_m2, fit.tau_s)
    P = np.minimum(P, R * (1.0 - 1e-9))  # P < R always holds; guards round-off
    gain = R / (R - P)
    r = (y - xs) * gain[:, None]
    V = P * gain + R
    return r, V, xs, P


def _score(r: np.ndarray) -> float:
    """Horizontal RMSE of residuals (m,2)."""
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")


def best_process(t_s: np.ndarray, y: np.ndarray, floor_m2: float):
    """The fitted process with the smaller leave-one-out RMSE, and its residuals and variances."""
    h, gamma, n = variogram(t_s, y)
    best = None
    for fit in fit_processes(h, gamma, n, floor_m2):
        r, V, xs, P = loo_residuals(t_s, y, fit)
        score = _score(r)
        if best is None or score < best[1]:
            best = (fit, score, r, V, xs, P)
    return best


def prior_calibration(n_edits: int) -> Calibration:
    """Fewer than MIN_EDITS edits: the cautious prior, nothing held out."""
    return Calibration(model="prior", cv_rmse_m=float("nan"), n_edits=n_edits)


def candidates(model: str, has_gnss: bool) -> tuple[str, ...]:
    """The models to score: all four with raw GNSS under "auto"; without it the location term
    would pull towards the reported pose itself, so only relative and naive; a forced model alone."""
    if model != "auto":
        return (model,)
    return ("gnss", "plain", "relative", "naive") if has_gnss else ("relative", "naive")


def held_out_picks(m: int, n_max: int) -> np.ndarray:
    """Which edits to hold out, one at a time: all of them up to ``n_max``, else ``n_max`` spread evenly."""
    return np.unique(np.round(np.linspace(0, m - 1, min(n_max, m))).astype(np.int64))


def model_scale(model: str, f: float, f_naive: float | None = None) -> float:
    """Run-wide RMSE over held-out RMSE of a model (module docstring 5): f bridged, sqrt(f) plain;
    naive interpolation its own ratio when edits carry their noise (``naive_ratio``)."""
    if model == "naive" and f_naive is not None:
        return f_naive
    return float(np.sqrt(f)) if model == "plain" else f


def choose(residuals: dict[str, np.ndarray], f: float, f_naive: float | None = None) -> str:
    """The model the held-out edits choose from each candidate's held-out residuals (n,2).

    The calibrated model (``gnss``; without GNSS ``relative``) stands unless another predicts
    the same held-out edits better, on the run-wide scale (``model_scale``), by more than their
    scatter allows: the paired gain d_k = s_inc^2 |r_k,inc|^2 - s_m^2 |r_k,m|^2 must have a
    mean above ``SWITCH_Z`` standard errors.
    """
    incumbent = "gnss" if "gnss" in residuals else "relative" if "relative" in residuals else next(iter(residuals))
    err = {name: model_scale(name, f, f_naive) ** 2 * np.sum(r**2, axis=1) for name, r in residuals.items()}
    best, best_mse = incumbent, float(np.mean(err[incumbent]))
    for name, e in err.items():
        if name == incumbent:
            continue
        d = err[incumbent] - e
        se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else np.inf
        if float(np.mean(d)) > SWITCH_Z * se and float(np.mean(e)) < best_mse:
            best, best_mse = name, float(np.mean(e))
    return best


def bridge_ratio(kf_t_s: np.ndarray, edit_t_s: np.ndarray, y_m: np.ndarray, picks: np.ndarray,
                 edit_sigma_m: float | np.ndarray) -> tuple[float, ProcessFit, np.ndarray, np.ndarray]:
    """f of module docstring 5 from the pose's error at the sorted edits ``y_m`` (m,2), with the
    pose process, its leave-one-out residuals and the bridged variance along the run (k,).
    ``edit_sigma_m``: the edits' horizontal 1-sigma, one for all or (m,) each (sorted)."""
    floor_e = np.maximum(np.asarray(edit_sigma_m, dtype=float) ** 2, 1e-4)
    floor = float(floor_e) if floor_e.ndim == 0 else float(np.mean(floor_e))
    fit_e, _, r_e, _, _, _ = best_process(edit_t_s, y_m, floor)
    # the band's shape: the fitted process observed with the edits' own noise (the engine holds
    # each edit to its sigma), so V at an edit is what the edits either side leave of it
    _, V_e, xs_e, P_e = loo_residuals(edit_t_s, y_m, dataclasses.replace(fit_e, nugget_m2=floor),
                                      None if floor_e.ndim == 0 else floor_e)
    _, v_run = bias_at(kf_t_s, edit_t_s, xs_e, P_e, fit_e.sigma2_m2, fit_e.tau_s)
    f = float(np.clip(np.sqrt(np.mean(v_run) / max(float(np.mean(V_e[picks])), 1e-12)), 0.5, 1.0)) if len(picks) else 1.0
    return f, fit_e, r_e, v_run


SPACING_SHAPES = {  # module docstring 6: F(u) of the continuous part of the pose's error
    "gauss_markov": lambda u: -np.expm1(-u),
    "integrated": lambda u: 1.0 - (1.0 + u) * np.exp(-u),
}
SPACING_L_GRID_S = np.geomspace(10.0, 1e4, 25)
RATIO_MAX_SAMPLES = 5_000  # the run's samples the mean over the run is taken on (evenly strided)
JITTER_MAX_SAMPLES = 20_000  # second differences the jitter's median is taken on (evenly spread)


def pose_jitter_m2(p_m: np.ndarray) -> float:
    """Per-axis variance of the white part of the pose's error from its sample-to-sample jitter
    (module docstring 6): the median absolute second difference, as a normal sigma, squared / 6.
    The motion's own second differences (acceleration dt^2) are small and rare beside it."""
    p = np.asarray(p_m, dtype=float)
    if len(p) < 3:
        return 0.0
    i = np.arange(0, len(p) - 2, max(1, -(-(len(p) - 2) // JITTER_MAX_SAMPLES)))
    d2 = p[i + 2] - 2.0 * p[i + 1] + p[i]
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if not len(d2):
        return 0.0
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return float(np.mean((1.4826 * mad) ** 2) / 6.0)


def interpolation_variance(g, t_s: np.ndarray, edit_t_s: np.ndarray, white_m2: float, edit_m2: float) -> np.ndarray:
    """V(t) of module docstring 6 at times ``t_s`` (n,): per-axis expected squared error of the
    pose shifted by the edit offsets interpolated linearly in time (sorted ``edit_t_s``), for a
    continuous error of semivariogram ``g`` (a function of lag arrays), white error ``white_m2``
    and edit noise ``edit_m2``."""
    t = np.asarray(t_s, dtype=float)
    te = np.asarray(edit_t_s, dtype=float)
    v = np.empty(len(t))
    before, after = t < te[0], t > te[-1]
    v[before] = 2.0 * g(te[0] - t[before]) + 2.0 * white_m2 + edit_m2
    v[after] = 2.0 * g(t[after] - te[-1]) + 2.0 * white_m2 + edit_m2
    inside = ~(before | after)
    if len(te) == 1:
        v[inside] = white_m2 + edit_m2
        return v
    j = np.clip(np.searchsorted(te, t[inside], side="right") - 1, 0, len(te) - 2)
    gap = te[j + 1] - te[j]
    u = np.where(gap > 0, (t[inside] - te[j]) / np.where(gap > 0, gap, 1.0), 0.0)
    ends = (1.0 - u) ** 2 + u**2
    v[inside] = (2.0 * (1.0 - u) * g(u * gap) + 2.0 * u * g((1.0 - u) * gap) - 2.0 * u * (1.0 - u) * g(gap)
                 + white_m2 * (1.0 + ends) + edit_m2 * ends)
    return v


def held_out_variance(g, edit_t_s: np.ndarray, picks: np.ndarray, white_m2: float, edit_m2: float) -> np.ndarray:
    """V_k of module docstring 6: the expected squared error per axis of predicting each picked
    edit (indices into the sorted ``edit_t_s``) from the others by linear interpolation (the
    neighbours either side; an end edit from its one neighbour, held constant)."""
    te = np.asarray(edit_t_s, dtype=float)
    k = np.asarray(picks, dtype=np.int64)
    m = len(te)
    if m < 2:
        return np.full(len(k), np.nan)
    out = np.empty(len(k))
    first, last = k == 0, k == m - 1
    out[first] = 2.0 * g(te[1] - te[0]) + 2.0 * white_m2 + 2.0 * edit_m2
    out[last] = 2.0 * g(te[-1] - te[-2]) + 2.0 * white_m2 + 2.0 * edit_m2
    mid = k[~(first | last)]
    gap = te[mid + 1] - te[mid - 1]
    u = np.where(gap > 0, (te[mid] - te[mid - 1]) / np.where(gap > 0, gap, 1.0), 0.0)
    ends = (1.0 - u) ** 2 + u**2
    out[~(first | last)] = (2.0 * (1.0 - u) * g(u * gap) + 2.0 * u * g((1.0 - u) * gap) - 2.0 * u * (1.0 - u) * g(gap)
                            + white_m2 * (1.0 + ends) + edit_m2 * (1.0 + ends))
    return out


def spacing_ratio(run_t_s: np.ndarray, kf_t_s: np.ndarray, edit_t_s: np.ndarray, y_m: np.ndarray, picks: np.ndarray,
                  edit_sigma_m: float, white_m2: float = 0.0) -> tuple[float, np.ndarray]:
    """R of module docstring 6 from the pose's error at the sorted edits ``y_m`` (m,2) and the
    held-out edits ``picks`` (indices into them), with V at the keyframes ``kf_t_s`` (k,) over
    its mean over the run's samples ``run_t_s`` (the band's shape, RMS 1 over the run)."""
    edit_m2 = float(edit_sigma_m) ** 2
    kf_t = np.asarray(kf_t_s, dtype=float)
    run_t = np.asarray(run_t_s, dtype=float)
    run_t = run_t[:: max(1, -(-len(run_t) // RATIO_MAX_SAMPLES))]
    h, gamma, n = variogram(edit_t_s, y_m)
    if len(h) == 0 or len(edit_t_s) < 2 or len(picks) == 0:
        return 1.0, np.ones(len(kf_t))
    floor = edit_m2 + white_m2
    w = n / np.maximum(gamma, max(floor, 1e-4)) ** 2
    z = gamma - floor
    shapes, logw = [], []
    for F in SPACING_SHAPES.values():
        A = F(h[None, :] / SPACING_L_GRID_S[:, None])  # (grid, bins)
        s2 = np.maximum((A @ (w * z)) / np.maximum((A * A) @ w, 1e-300), 0.0)
        cost = ((s2[:, None] * A - z) ** 2) @ w
        for ell, s2_i, c in zip(SPACING_L_GRID_S, s2, cost):
            shapes.append((F, float(ell), float(s2_i)))
            logw.append(-float(c) / 4.0)
    logw = np.asarray(logw)
    wts = np.exp(logw - logw.max())
    wts[wts < 1e-3 * wts.max()] = 0.0  # shapes the variogram all but rules out: not evaluated
    wts /= wts.sum()
    ratio2 = 0.0
    kf_v = np.zeros(len(kf_t))
    for (F, ell, s2_i), wt in zip(shapes, wts):
        if wt == 0.0:
            continue

        def g(lag, F=F, ell=ell, s2_i=s2_i):
            return s2_i * F(np.abs(lag) / ell)

        v_run = float(np.mean(interpolation_variance(g, run_t, edit_t_s, white_m2, edit_m2)))
        v_loo = float(np.mean(held_out_variance(g, edit_t_s, picks, white_m2, edit_m2)))
        ratio2 += wt * (v_run / v_loo if v_loo > 0 else 1.0)
        kf_v += wt * interpolation_variance(g, kf_t, edit_t_s, white_m2, edit_m2) / max(v_run, 1e-300)
    return float(np.sqrt(ratio2)), kf_v


def naive_ratio(kf_t_s: np.ndarray, edit_t_s: np.ndarray, fit: ProcessFit, edit_m2: float, picks: np.ndarray) -> float:
    """Run-wide over held-out RMSE of naive interpolation (module docstring 5) when the edits
    carry their noise (``edit_m2`` per axis): V(t) over the keyframes and V_k at the held-out
    edits of module docstring 6 (``interpolation_variance``, ``held_out_variance``) for the pose
    process ``fit`` without its nugget (the edits' noise is explicit), kept in [0.5, 1] as f is.
    Naive interpolation passes each edit's noise straight through, in full at the edits, where
    the smoother averages it; with the smoother's f it would look as if its edits were exact."""
    if len(edit_t_s) < 2 or not len(picks):
        return 1.0

    def g(lag):
        return -fit.sigma2_m2 * np.expm1(-np.abs(lag) / fit.tau_s)

    v_run = float(np.mean(interpolation_variance(g, kf_t_s, edit_t_s, 0.0, edit_m2)))
    v_loo = float(np.mean(held_out_variance(g, edit_t_s, picks, 0.0, edit_m2)))
    return float(np.clip(np.sqrt(v_run / max(v_loo, 1e-12)), 0.5, 1.0))


def calibration_of(model: str, scores: dict[str, float], f: float, bridge: tuple, kf_t_s: np.ndarray,
                   edit_t_s: np.ndarray, d_m: np.ndarray | None, edit_sigma_m: float | np.ndarray,
                   spacing: tuple[float, np.ndarray] | None = None) -> Calibration:
    """The calibration of the chosen model: the pose process and bridge (``bridge_ratio``), the
    fix's process and share (``d_m``: the fix's error at the sorted edit times), and the accuracy
    the chosen model's held-out RMSE (``scores``) predicts along the run (module docstring 6:
    ``spacing`` is ``spacing_ratio``'s R and band shape)."""
    _, fit_e, r_e, v_run = bridge
    floor = float(np.mean(np.maximum(np.asarray(edit_sigma_m, dtype=float) ** 2, 1e-4)))
    gnss_fit, share = None, float("nan")
    if d_m is not None and np.all(np.isfinite(d_m)):
        gnss_fit, _, r_g, _, _, _ = best_process(edit_t_s, d_m, floor)
        diff = r_e - r_g
        den = float(np.sum(diff**2))
        share = float(np.clip(np.sum(r_e * diff) / den, 0.0, 1.0)) if den > 0 else 0.0
    ratio, kf_v = spacing if spacing is not None else (1.0, np.ones(len(kf_t_s)))
    predicted = scores[model] * (float(np.sqrt(ratio)) if model == "plain" else ratio)
    shape = np.sqrt(np.maximum(kf_v, 0.0))
    if model == "plain" or not np.any(shape > 0):
        sigma_h = np.full(len(kf_t_s), predicted)
    else:  # kf_v is V over its mean over the samples: the band's RMS over the run is the prediction
        sigma_h = shape * predicted
    return Calibration(model=model, cv_rmse_m=scores[model], cv_rmse_by_model=dict(scores),
                       predicted_rmse_m=float(predicted), gnss_share=share, n_edits=len(edit_t_s),
                       pose=fit_e, gnss=gnss_fit, sigma_m=sigma_h, spacing_ratio=float(ratio))
