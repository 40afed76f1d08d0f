"""Drift (issue section 6): the GNSS bias the edits reveal, and what it does to the location term.

GNSS errors are correlated in time.  Model the location measurement at keyframe i as
``g_i = truth_i + b(t_i) + w_i``: a bias ``b`` that wanders as a first-order Gauss-Markov
(Ornstein-Uhlenbeck) process, stationary sigma ``sigma_b`` and correlation time ``tau``
(per horizontal axis), plus white noise ``w`` of sigma ``sigma_w``.  An edit is
``c_k = truth + u_k`` (sigma ``sigma_u``), so every edit observes the bias:

    d_k = g~(t_k) - c_k = b(t_k) + n_k,

where ``g~(t_k)`` is the location measurement at the edit made robust against outliers
and white noise: the reported pose at the edit plus the median of (g - p~) over the
neighbouring keyframes (the reported pose keeps its local shape, so g - p~ varies slowly).

1. Parameters from the edits (with at least ``min_edits`` of them; the configured prior
   otherwise): the wander rate ``q = 2 sigma_b^2 / tau`` from consecutive differences,
   whose per-axis variance is ``q dt + var(n_k) + var(n_k+1)`` for dt << tau (method of
   moments pooled over all pairs), ``sigma_b^2`` from the mean square offset, and
   ``tau = 2 sigma_b^2 / q`` (clipped to [30 s, 1 h]).
2. A Kalman filter and RTS smoother over the edit times give the bias and its variance at
   each edit.  Between two edits the bias is the Gauss-Markov bridge between them (linear
   for gaps much shorter than tau); beyond the first/last edit it decays towards zero
   with tau while its variance grows back to sigma_b^2.  An interval whose two edits
   disagree far beyond their noise (a jump of an urban-canyon offset) gets the variance of
   a Brownian bridge with the intensity that jump implies.
3. The location term of keyframe i is re-centred on ``g_i - b_i`` and its horizontal
   sigma inflated to ``sqrt(sigma_w^2 + var_b,i)``: where edits show drift the term is
   down-weighted (between edits, where the bias is uncertain) and no longer biased, so
   hundreds of weak, correlated fixes cannot pull the run back onto a biased track.  With
   no drift detected (median offset within 3 sigma of the noise of edits and fixes, no
   wander beyond it, and all offsets together within the 99 % point of their chi-square)
   the term is left exactly as it was; far from any edit the model returns to the unbiased
   prior, so the pull of one edit fades with distance.
4. Edits the reported shape cannot join (``edit_bends``): where two consecutive edits move
   the run by more than its relative terms allow and the GNSS shows why (the fix jumped, or
   left its level in between: ``gnss_transient``), the relative variance of that interval is
   raised to what the edits show, placed where the error most likely changed
   (``shape_change_evidence``), and the fixes inside are dropped.
5. A pose that bridged urban-canyon offsets (``gnss_levels``, ``levels_bridged``): where the
   fix steps persistently against the pose (``gnss_steps``) and the pose kept its shape across
   every large step (read from the run itself: one edit is enough), a joint smoother of the
   fix's piecewise-constant level and the pose's smooth error (section "GNSS levels") gives
   the level at every keyframe; the location term then reads the level-corrected mean of
   the keyframe's fixes with the run's own white-noise sigma, so the fixes between edits
   measure the pose's wander instead of being dropped.

Vertical: only 3-D edits observe the vertical bias; without them the vertical is left alone.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

import numpy as np

MEDIAN_EFFICIENCY = 1.2533  # sigma of a sample median / (sigma / sqrt(n)) for Gaussian data
MIN_TAU_S, MAX_TAU_S = 30.0, 3600.0  # plausible correlation times of a GNSS bias
TRANSIENT_CHI2 = 13.8  # 99.9 % point of a chi-square with 2 degrees of freedom
STEP_WINDOW_S = 30.0  # window for GNSS steps: the pose's error hardly moves in it, a canyon offset switches in seconds


@dataclass(frozen=True)
class DriftEstimate:
    """What the edits say about the location measurements' bias.

    offset_enu_m : (3,) robust mean (median) of the edit offsets g - c, metres (NaN vertical
        when no 3-D edit).
    spread_m : robust horizontal spread (MAD-based sigma) of the edit offsets, metres.
    walk_m2_per_s : wander rate q = 2 sigma_b^2 / tau of the bias, m^2/s per axis.
    sigma_b_m, tau_s : stationary sigma (per axis) and correlation time of the bias model.
    detected : True when the edits show a bias the location term must not be trusted for.
    bias_enu_m : (k,3) bias at each keyframe (g - truth), metres.
    bias_sigma_m : (k,) horizontal one-sigma uncertainty of that bias, metres.
    weight : (k,) factor on the location term's information (1 = untouched, -> 0 = ignored).
    edit_offsets_enu_m : (m,3) the per-edit offsets d_k, in time order.
    edit_t_s : (m,) their times.
    """

    offset_enu_m: np.ndarray
    spread_m: float
    walk_m2_per_s: float
    detected: bool
    bias_enu_m: np.ndarray
    bias_sigma_m: np.ndarray
    weight: np.ndarray
    edit_offsets_enu_m: np.ndarray
    edit_t_s: np.ndarray
    sigma_b_m: float = 0.0
    tau_s: float = 0.0
    n_steps: int = 0
    loc_sigma_h_m: np.ndarray | None = None

    def to_json(self) -> dict:
        return {
            "offset_enu_m": [None if not np.isfinite(v) else float(v) for v in self.offset_enu_m],
            "spread_m": float(self.spread_m),
            "walk_m2_per_s": float(self.walk_m2_per_s),
            "sigma_b_m": float(self.sigma_b_m),
            "tau_s": float(self.tau_s),
            "n_steps": int(self.n_steps),
            "gnss_levels": self.loc_sigma_h_m is not None,
            "detected": bool(self.detected),
            "n_edits": int(len(self.edit_t_s)),
            "max_bias_m": float(np.max(np.hypot(*self.bias_enu_m[:, :2].T))) if len(self.bias_enu_m) else 0.0,
        }


def no_drift(n_keyframes: int) -> DriftEstimate:
    """The estimate when drift handling is off or there are no edits."""
    return DriftEstimate(
        offset_enu_m=np.full(3, np.nan),
        spread_m=0.0,
        walk_m2_per_s=0.0,
        detected=False,
        bias_enu_m=np.zeros((n_keyframes, 3)),
        bias_sigma_m=np.zeros(n_keyframes),
        weight=np.ones(n_keyframes),
        edit_offsets_enu_m=np.zeros((0, 3)),
        edit_t_s=np.zeros(0),
    )


def edit_offsets(
    kf_t_s: np.ndarray,
    p_rep_m: np.ndarray,
    g_m: np.ndarray,
    edit_kf: np.ndarray,
    edit_c_m: np.ndarray,
    window: int = 5,
) -> np.ndarray:
    """Offsets d_k = g~(t_k) - c_k (m,3) with g~ = p~ + median of (g - p~) over +-window keyframes.

    NaN rows of g (no fix) are ignored; a window without any fix gives d = p~ - c.
    Vectorised over the edits: each window is gathered into an (m, 2 window + 1, 3) block,
    missing fixes sorted to its end as +inf, and the median read at the middle of the valid part.
    """
    u = g_m - p_rep_m
    k = len(kf_t_s)
    edit_kf = np.asarray(edit_kf, dtype=np.int64)
    if len(edit_kf) == 0:
        return np.zeros((0, 3))
    rows = edit_kf[:, None] + np.arange(-window, window + 1)[None, :]
    local = u[np.clip(rows, 0, k - 1)]  # (m, w, 3)
    valid = (rows >= 0) & (rows < k) & np.all(np.isfinite(local), axis=2)
    local = np.where(valid[:, :, None], local, np.inf)
    local.sort(axis=1)
    n = valid.sum(axis=1)
    lo = np.maximum((n - 1) // 2, 0)[:, None, None]
    hi = np.maximum(n // 2, 0)[:, None, None]
    a = np.take_along_axis(local, np.broadcast_to(lo, (len(n), 1, 3)), axis=1)[:, 0]
    b = np.take_along_axis(local, np.broadcast_to(hi, (len(n), 1, 3)), axis=1)[:, 0]
    shift = np.where(n[:, None] > 0, 0.5 * (a + b), 0.0)
    return p_rep_m[edit_kf] + shift - np.asarray(edit_c_m, dtype=float)


def estimate_walk(t_s: np.ndarray, d_h: np.ndarray, noise_var: np.ndarray) -> float:
    """Random-walk intensity q (m^2/s per axis) from consecutive offsets (m,2) with per-edit noise variances.

    Method of moments pooled over all consecutive pairs:
    ``q = max(0, sum(|d_k+1 - d_k|^2 / 2 - var_k - var_k+1) / sum(dt_k))``.  Pooling (not a
    median) keeps the jumps of urban-canyon offsets, which are the very thing to detect.
    """
    dt = np.diff(t_s)
    keep = dt > 0
    if not np.any(keep):
        return 0.0
    z = 0.5 * np.sum(np.diff(d_h, axis=0) ** 2, axis=1)[keep]
    base = (noise_var[:-1] + noise_var[1:])[keep]
    return max(0.0, float(np.sum(z - base) / np.sum(dt[keep])))


def local_walk(t_s: np.ndarray, d_h: np.ndarray, noise_var: np.ndarray, q: float) -> np.ndarray:
    """Intensity per interval between edits (m-1,): the global q, raised where the two edits
    bounding the interval disagree by more than their noise (a jump of the bias).

    Under "no jump" z = |d_k+1 - d_k|^2 / 2 is exponential with mean q dt + var_k + var_k+1;
    only intervals beyond its 95th percentile (3x the mean) are raised, so noise alone
    rarely lowers the weight of good GNSS.
    """
    dt = np.maximum(np.diff(t_s), 1e-9)
    z = 0.5 * np.sum(np.diff(d_h, axis=0) ** 2, axis=1)
    expected = q * dt + noise_var[:-1] + noise_var[1:]
    raised = np.maximum(q, (z - noise_var[:-1] - noise_var[1:]) / dt)
    return np.where(z > 3.0 * expected, raised, q)


def smooth_gauss_markov(t_s: np.ndarray, y: np.ndarray, r_var: np.ndarray, sigma2: float, tau_s: float, q_extra=None):
    """Kalman filter + RTS smoother of a scalar Gauss-Markov process observed at sorted times.

    ``x_k+1 = a x_k + w``, ``a = exp(-dt/tau)``, ``var(w) = sigma2 (1 - a^2)`` plus
    ``q_extra[k] dt`` (jumps).  y (m,) or (m, d) observations (d independent series with the
    same variances r_var (m,)).  Returns the smoothed means (shaped as y) and variances (m,).
    """
    y = np.asarray(y, dtype=float)
    m = len(t_s)
    dt = np.diff(t_s)
    a = np.exp(-dt / tau_s)
    Q = sigma2 * (1.0 - a * a) + (0.0 if q_extra is None else np.asarray(q_extra) * dt)
    # the variances do not depend on y: one pass serves every column of y (m,) or (m, d).
    # The recursions run on Python floats (the same IEEE operations as on numpy scalars, several
    # times faster per step: a one-more-edit solve runs this on every call)
    a_l, Q_l, r_l = a.tolist(), np.broadcast_to(Q, (max(m - 1, 0),)).tolist(), np.asarray(r_var, dtype=float).tolist()
    Pf, Pp, K = [0.0] * m, [0.0] * m, [0.0] * m
    P = float(sigma2)
    for k in range(m):
        if k:
            P = a_l[k - 1] ** 2 * P + Q_l[k - 1]
        Pp[k] = P
        K[k] = P / (P + r_l[k])
        P = (1.0 - K[k]) * P
        Pf[k] = P
    cols = y.reshape(m, -1).T.tolist() if m else []
    xs_cols = []
    for yc in cols:
        xf, xp = [0.0] * m, [0.0] * m
        x = 0.0
        for k in range(m):
            if k:
                x = a_l[k - 1] * x
            xp[k] = x
            x = x + K[k] * (yc[k] - x)
            xf[k] = x
        xs = xf[:]
        for k in range(m - 2, -1, -1):
            G = Pf[k] * a_l[k] / Pp[k + 1]
            xs[k] = xf[k] + G * (xs[k + 1] - xp[k + 1])
        xs_cols.append(xs)
    Ps = Pf[:]
    for k in range(m - 2, -1, -1):
        G = Pf[k] * a_l[k] / Pp[k + 1]
        Ps[k] = Pf[k] + G * G * (Ps[k + 1] - Pp[k + 1])
    return np.array(xs_cols).T.reshape(y.shape), np.array(Ps)


def bias_at(kf_t_s, t_e, mean, var, sigma2: float, tau_s: float, q_jump=None):
    """Bias mean (k,) or (k, d) and variance (k,) at keyframe times from the smoothed values at edits.

    Between edits a, b: the Gauss-Markov bridge ``mu = w_a x_a + w_b x_b`` with
    ``w_a = (c_a - c_b c_ab)/(1 - c_ab^2)``, ``w_b = (c_b - c_a c_ab)/(1 - c_ab^2)``,
    ``c_a = exp(-(t - t_a)/tau)``, ``c_b = exp(-(t_b - t)/tau)``, ``c_ab = exp(-(t_b - t_a)/tau)``;
    variance ``sigma2 (1 - w_a c_a - w_b c_b) + w_a^2 P_a + w_b^2 P_b`` plus
    ``q_jump (t - t_a)(t_b - t)/(t_b - t_a)`` on intervals with a jump.  Outside the edits:
    ``mu = c x_end``, variance ``sigma2 (1 - c^2) + c^2 P_end``.
    """
    t = np.asarray(kf_t_s, dtype=float)
    mean = np.asarray(mean, dtype=float)
    cols = mean.shape[1:]  # the bias of several axes at once shares every weight

    def col(w):
        return w.reshape(w.shape + (1,) * len(cols))

    mu = np.zeros((len(t),) + cols)
    v = np.full(len(t), sigma2)
    if np.all(t[1:] >= t[:-1]):  # keyframe times (sorted): each part is a slice, no boolean masks to build
        n0, n1 = np.searchsorted(t, t_e[0], side="left"), np.searchsorted(t, t_e[-1], side="right")
        before, after, inside = slice(0, n0), slice(n1, len(t)), slice(n0, n1)
    else:
        before, after = t < t_e[0], t > t_e[-1]
        inside = ~(before | after)
    for sel, t_end, x_end, p_end in ((before, t_e[0], mean[0], var[0]), (after, t_e[-1], mean[-1], var[-1])):
        c = np.exp(-np.abs(t[sel] - t_end) / tau_s)
        mu[sel] = col(c) * x_end
        v[sel] = sigma2 * (1.0 - c * c) + c * c * p_end
    if len(t_e) == 1:
        mu[inside], v[inside] = mean[0], var[0]
        return mu, v
    ti = t[inside]
    j = np.clip(np.searchsorted(t_e, ti, side="right") - 1, 0, len(t_e) - 2)
    ta, tb = t_e[j], t_e[j + 1]
    ca, cb = np.exp(-(ti - ta) / tau_s), np.exp(-(tb - ti) / tau_s)
    cab = np.exp(-(tb - ta) / tau_s)
    den = np.maximum(1.0 - cab * cab, 1e-12)
    wa, wb = (ca - cb * cab) / den, (cb - ca * cab) / den
    mu[inside] = col(wa) * mean[j] + col(wb) * mean[j + 1]
    vi = sigma2 * np.maximum(1.0 - wa * ca - wb * cb, 0.0) + wa * wa * var[j] + wb * wb * var[j + 1]
    if q_jump is not None:
        vi = vi + np.asarray(q_jump)[j] * (ti - ta) * (tb - ti) / np.maximum(tb - ta, 1e-9)
    v[inside] = vi
    return mu, v


@dataclass(frozen=True)
class GnssSteps:
    """Persistent jumps of the GNSS relative to the locally rigid pose.

    index (j,) keyframe where each jump happens; jump_m (j,2) its size (east, north);
    level_m (k,2) the cumulative jump level of each keyframe (0 before the first jump);
    transition (k,) bool keyframes inside a jump's window; sigma_jump_m one-sigma error of a
    jump's size.
    """

    index: np.ndarray
    jump_m: np.ndarray
    level_m: np.ndarray
    transition: np.ndarray
    sigma_jump_m: float


def gnss_steps(u_h: np.ndarray, window: int = 30, n_sigma: float = 4.0, min_jump_m: float = 5.0) -> GnssSteps:
    """Find persistent steps in u = g - p~ (k,2): where the GNSS jumps and the pose does not.

    The reported pose keeps its local shape, so over a window of ``window`` keyframes
    (30 s by default) its error hardly moves, while an urban-canyon offset switches on or off
    within seconds.  A step at i is declared where the medians of u over the ``window``
    keyframes before and after i differ by more than ``n_sigma`` sigmas of that difference
    (and ``min_jump_m``), at a local maximum, and the level after it persists: the median over
    the following window agrees with the first (a pose that follows its GNSS through a low-pass
    shows a transient, not a step).  Medians make outliers and white noise harmless.
    """
    k = len(u_h)
    empty = GnssSteps(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((k, 2)), np.zeros(k, bool), 0.0)
    W = int(window)
    if k < 4 * W:
        return empty
    if np.count_nonzero(np.all(np.isfinite(u_h), axis=1)) < 3:
        return empty
    sigma = white_sigma(u_h)
    sigma_diff = MEDIAN_EFFICIENCY * sigma * np.sqrt(2.0 / W)
    threshold = max(n_sigma * sigma_diff * np.sqrt(2.0), min_jump_m)
    from numpy.lib.stride_tricks import sliding_window_view

    win = sliding_window_view(u_h, W, axis=0)  # (k-W+1, 2, W): window starting at each row
    with warnings.catch_warnings():  # a window inside a GNSS outage has no fix: its median is NaN, as meant
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(win, axis=2)  # median of u[i:i+W]
    # before(i) = median u[i-W:i] = med[i-W]; after(i) = med[i]; later(i) = med[i+W]
    i = np.arange(W, k - 2 * W + 1)
    before, after, later = med[i - W], med[i], med[i + W]
    D = np.hypot(*(after - before).T)
    persist = np.hypot(*(later - after).T) < 0.5 * D
    cand = np.flatnonzero((D > threshold) & persist & np.isfinite(D))
    picked: list[int] = []
    for c in cand[np.argsort(-D[cand])]:  # strongest first, one per window
        if all(abs(c - p) >= W for p in picked):
            picked.append(int(c))
    picked.sort()
    if not picked:
        return dataclasses.replace(empty, sigma_jump_m=float(sigma_diff))
    idx = i[picked]
    jumps = (after - before)[picked]
    level = np.zeros((k, 2))
    transition = np.zeros(k, dtype=bool)
    for j, J in zip(idx, jumps):
        level[j:] += J
        transition[max(j - W // 2, 0):min(j + W // 2, k)] = True
    return GnssSteps(idx, jumps, level, transition, float(sigma_diff * np.sqrt(2.0)))


def keyframes_in(seconds: float, kf_t_s: np.ndarray, at_least: int = 1) -> int:
    """``seconds`` in keyframes at the run's typical keyframe spacing (at least ``at_least``)."""
    dt = float(np.median(np.diff(kf_t_s))) if len(kf_t_s) > 1 else 1.0
    return max(int(round(seconds / max(dt, 1e-9))), at_least)


def step_window(kf_t_s: np.ndarray) -> int:
    """Keyframes in ``STEP_WINDOW_S`` at the run's typical keyframe spacing (at least 5)."""
    return keyframes_in(STEP_WINDOW_S, kf_t_s, 5)


def steps_confirmed_by_edits(steps: GnssSteps, edit_kf: np.ndarray, d_h: np.ndarray, noise_var: float, k: int) -> GnssSteps:
    """Keep only the steps the edits confirm.

    Between two consecutive edits the GNSS bias changes by ``d_b - d_a``; the steps found
    in that interval must add up to that change within 3 sigmas (edit noise and the steps'
    own errors), and the interval must show a change at all.  Steps outside the edits, or
    in an interval they do not explain (a step missed, a wander of the pose taken for one),
    are dropped, and the Gauss-Markov model covers those intervals as before.
    """
    if len(steps.index) == 0 or len(edit_kf) < 2:
        return dataclasses.replace(steps, index=steps.index[:0], jump_m=steps.jump_m[:0],
                                   level_m=np.zeros((k, 2)), transition=np.zeros(k, dtype=bool))
    keep = np.zeros(len(steps.index), dtype=bool)
    jumps = steps.jump_m.copy()
    # stretches: before the first edit, between consecutive edits, after the last one
    if np.all(edit_kf[1:] > edit_kf[:-1]):
        # only the stretches holding a step (a handful among dozens) need a look: same result,
        # without numpy work on every stretch (a one-more-edit solve runs this on every call)
        ends = np.append(edit_kf, k)
        held = np.unique(np.searchsorted(ends, steps.index, side="left")).tolist()
        bounds = [(-1 if s == 0 else edit_kf[s - 1], ends[s], None if s in (0, len(edit_kf)) else d_h[s] - d_h[s - 1])
                  for s in held]
    else:
        bounds = [(-1, edit_kf[0], None)] + [(a, b, db - da) for a, b, da, db in
                                             zip(edit_kf[:-1], edit_kf[1:], d_h[:-1], d_h[1:])] + [(edit_kf[-1], k, None)]
    for a, b, change in bounds:
        inside = (steps.index > a) & (steps.index <= b)
        n = int(inside.sum())
        if n == 0:
            continue
        total = steps.jump_m[inside].sum(axis=0)
        tol = 3.0 * np.sqrt(2.0 * (2.0 * noise_var + n * steps.sigma_jump_m**2))
        if change is not None and np.hypot(*(total - change)) < tol and np.hypot(*change) > tol:
            keep |= inside  # the edits saw the change the steps add up to
        elif n >= 2 and np.hypot(*total) < 3.0 * np.sqrt(n) * steps.sigma_jump_m \
                and (change is None or np.hypot(*change) < tol):
            # an offset that switched on and off again (an urban canyon entered and left)
            # within the stretch: the steps cancel, as the edits around them (if any) say;
            # every step is far beyond the noise, so two false ones cancelling is unlikely
            keep |= inside
    level = np.zeros((k, 2))
    transition = np.zeros(k, dtype=bool)
    W = int(np.ceil(np.count_nonzero(steps.transition) / max(len(steps.index), 1)))
    for j, J in zip(steps.index[keep], jumps[keep]):
        level[j:] += J
        transition[max(j - W // 2, 0):min(j + W // 2, k)] = True
    # levels are relative: anchor them so the first edit sees level 0 (the GM part carries the rest)
    return GnssSteps(steps.index[keep], jumps[keep], level, transition, steps.sigma_jump_m)


def suspect_intervals(found: GnssSteps, kept: GnssSteps, edit_kf: np.ndarray, k: int) -> np.ndarray:
    """(k,) extra variance, m^2: the squared size of any unconfirmed step over the stretch
    between the edits around it (from the run's start or to its end beyond the edits)."""
    extra = np.zeros(k)
    kept_set = set(int(i) for i in kept.index)
    bounds = np.concatenate([[0], np.sort(np.asarray(edit_kf, dtype=np.int64)), [k]])
    for j, J in zip(found.index, found.jump_m):
        if int(j) in kept_set:
            continue
        b = np.searchsorted(bounds, j, side="right")
        lo, hi = bounds[b - 1], bounds[min(b, len(bounds) - 1)]
        extra[lo:hi] = np.maximum(extra[lo:hi], 9.0 * float(J @ J))
    return extra


def estimate_drift(
    kf_t_s: np.ndarray,
    p_rep_m: np.ndarray,
    g_m: np.ndarray,
    edit_kf: np.ndarray,
    edit_c_m: np.ndarray,
    edit_has_alt: np.ndarray,
    sigma_w_h_m: float,
    sigma_w_v_m: float,
    sigma_u_h_m: float,
    sigma_u_v_m: float,
    prior_sigma_m: float,
    prior_tau_s: float,
    min_edits_for_estimate: int = 3,
    window: int = 5,
    frozen: tuple | None = None,
    steps: GnssSteps | None = None,
    levels=None,
) -> DriftEstimate:
    """Fit the bias model to the edits; see the module docstring.

    kf_t_s (k,), p_rep_m (k,3) reported keyframe positions, g_m (k,3) location measurements
    (NaN where none), edit_kf (m,) keyframe of each edit, edit_c_m (m,3) edit targets
    (vertical ignored where ``edit_has_alt`` is False).  ``frozen`` = (sigma_b^2, tau_s,
    detected) holds the model's parameters (a live drag re-uses those of the last solve so
    one more edit changes the bias only around it); a fourth element, the DriftEstimate
    of that solve, keeps its GNSS levels (a live drag).  ``steps`` passes the
    result of ``gnss_steps`` when the caller keeps it between solves (it depends on the run
    only).  ``levels`` (``gnss_levels``, also the run's only, or a function returning it when
    needed) enables the level model where
    the fix shows persistent jumps the pose does not (see the "GNSS levels" section).
    """
    k = len(kf_t_s)
    if len(edit_kf) == 0:
        return no_drift(k)
    order = np.argsort(kf_t_s[edit_kf], kind="stable")
    edit_kf = np.asarray(edit_kf)[order]
    edit_c_m = np.asarray(edit_c_m, dtype=float)[order]
    edit_has_alt = np.asarray(edit_has_alt, dtype=bool)[order]
    t_e = kf_t_s[edit_kf]
    d = edit_offsets(kf_t_s, p_rep_m, g_m, edit_kf, edit_c_m, window)
    d[~edit_has_alt, 2] = np.nan
    n_win = min(2 * window + 1, k)
    noise_h = np.full(len(t_e), sigma_u_h_m**2 + (MEDIAN_EFFICIENCY * sigma_w_h_m) ** 2 / n_win)
    noise_v = np.full(len(t_e), sigma_u_v_m**2 + (MEDIAN_EFFICIENCY * sigma_w_v_m) ** 2 / n_win)
    # persistent GNSS steps (urban-canyon offsets switching on and off) are taken out of the
    # offsets first; the Gauss-Markov model then describes what is left
    if steps is None:
        steps = gnss_steps((g_m - p_rep_m)[:, :2], window=step_window(kf_t_s))
    all_steps = steps
    steps = steps_confirmed_by_edits(steps, edit_kf, d[:, :2], noise_h[0], k)
    d[:, :2] -= steps.level_m[edit_kf]
    suspect = suspect_intervals(all_steps, steps, edit_kf, k)
    if frozen is not None:
        sigma2, tau = float(frozen[0]), float(frozen[1])
        q = 2.0 * sigma2 / tau
    elif len(t_e) >= max(min_edits_for_estimate, 2):
        q = max(estimate_walk(t_e, d[:, :2], noise_h), 1e-6)
        sigma2 = max(float(np.mean(0.5 * np.sum(d[:, :2] ** 2, axis=1) - noise_h)), 1e-4)
        tau = float(np.clip(2.0 * sigma2 / q, MIN_TAU_S, MAX_TAU_S))
    else:
        sigma2, tau = prior_sigma_m**2, prior_tau_s
        q = 2.0 * sigma2 / tau
    q_jump = local_walk(t_e, d[:, :2], noise_h, q) - q
    bias = np.zeros((k, 3))
    var_h = np.zeros(k)
    xs, Ps = smooth_gauss_markov(t_e, d[:, :2], noise_h, sigma2, tau, q_jump)  # both axes at once
    bias[:, :2], var_h = bias_at(kf_t_s, t_e, xs, Ps, sigma2, tau, q_jump)
    has_v = np.isfinite(d[:, 2])
    if np.any(has_v):
        xs, Ps = smooth_gauss_markov(t_e[has_v], d[has_v, 2], noise_v[has_v], sigma2, tau)
        bias[:, 2], _ = bias_at(kf_t_s, t_e[has_v], xs, Ps, sigma2, tau)
    offset = np.array([np.median(d[:, 0]), np.median(d[:, 1]), np.median(d[has_v, 2]) if np.any(has_v) else np.nan])
    dev = np.hypot(d[:, 0] - offset[0], d[:, 1] - offset[1])
    spread = float(1.4826 * np.median(dev) / np.sqrt(np.log(4.0))) if len(dev) > 1 else 0.0
    # A bias is "detected" when the offsets stand out of the noise they would have without
    # one: a median offset beyond 3 of its sigmas, or a wander over the typical spacing of
    # edits of more than twice the offsets' noise (the pooled estimate of q is rough), or all
    # the offsets together beyond the 99 % point of the chi-square they would follow (a few
    # edits that agree on one offset: their median is a poor estimate, their sum is not).
    from scipy.special import chdtri  # ~35 ms of import, once (scipy.ndimage loads it too); scipy.stats: ~0.4 s

    typical_dt = float(np.median(np.diff(t_e))) if len(t_e) > 1 else float(kf_t_s[-1] - kf_t_s[0])
    median_sigma = MEDIAN_EFFICIENCY * np.sqrt(2.0 * noise_h[0] / len(t_e))
    together = float(np.sum(np.sum(d[:, :2] ** 2, axis=1) / noise_h))
    detected = bool(np.hypot(offset[0], offset[1]) > 3.0 * median_sigma or q * typical_dt > 2.0 * noise_h[0]
                    or together > chdtri(2 * len(t_e), 0.01))
    if frozen is not None:
        detected = bool(frozen[2])
    if not detected:
        # the offsets are what edit and GNSS noise alone would give: the location term is
        # unbiased as far as the edits can tell, and is left exactly as configured
        bias = np.zeros((k, 3))
        var_h = np.zeros(k)
    if len(steps.index):
        # add the steps back: the bias is the step level plus the smooth part; each step
        # between a keyframe and its nearest edit adds its size's uncertainty, and keyframes
        # inside a step's window (the ramp) keep almost no location weight
        detected = True
        bias[:, :2] += steps.level_m
        seg = np.searchsorted(steps.index, np.arange(k), side="right")
        seg_e = seg[edit_kf]
        # segments (between steps) from each keyframe's to its nearest edit's (seg_e is sorted)
        j = np.searchsorted(seg_e, seg)
        n_between = np.minimum(np.abs(seg - seg_e[np.maximum(j - 1, 0)]), np.abs(seg_e[np.minimum(j, len(seg_e) - 1)] - seg))
        var_h += n_between * steps.sigma_jump_m**2
        big = np.max(np.hypot(*steps.jump_m.T)) ** 2
        var_h = np.where(steps.transition, var_h + big, var_h)
        d[:, :2] += steps.level_m[edit_kf]
    # a step the edits could not confirm still says the GNSS jumped there: between the two
    # edits around it (or beyond the last one) the fixes are not trusted to more than the jump
    var_h = var_h + suspect
    if np.any(suspect > 0):
        detected = True
    loc_sigma = None
    if callable(levels) and len(all_steps.index):
        levels = levels()  # found from every sample once per run: only when the fix shows persistent steps
    if isinstance(levels, GnssLevels) and len(all_steps.index) and levels.bridged:
        # the fix steps persistently against the pose, and the pose bridged every large step
        bias[:, :2], var_h, loc_sigma = _level_bias(kf_t_s, p_rep_m, g_m, edit_kf, edit_c_m, levels, sigma_u_h_m,
                                                    prior_sigma_m, frozen, d)
        detected = True
        weight = sigma_w_h_m**2 / loc_sigma**2
    else:
        weight = sigma_w_h_m**2 / (sigma_w_h_m**2 + var_h)
    return DriftEstimate(
        offset_enu_m=offset,
        spread_m=spread,
        walk_m2_per_s=float(q),
        sigma_b_m=float(np.sqrt(sigma2)),
        tau_s=float(tau),
        detected=detected,
        bias_enu_m=bias,
        bias_sigma_m=np.sqrt(var_h),
        weight=weight,
        edit_offsets_enu_m=d,
        edit_t_s=t_e,
        n_steps=int(len(steps.index)),
        loc_sigma_h_m=loc_sigma,
    )


def levels_bridged(levels: GnssLevels, kf_t_s: np.ndarray, big_m: float = 5.0, share: float = 0.75) -> bool:
    """True when the pose bridged the fix's level jumps: at least ``share`` of the jumps over
    ``big_m`` (two at least) persist, the level of u 20-40 s after the jump still departing
    from the level before it by more than half the jump.

    A pose that follows its fix through a low-pass (an INS that trusted the canyon) catches up
    within seconds, so u = g - p~ shows a transient that decays, and there the level model's
    smooth pose error does not hold; a bridged pose leaves the jump in u for as long as the
    fix keeps its level.  Jumps with another one too close after them to tell are skipped.
    """
    k = len(kf_t_s)
    W, gap = keyframes_in(LEVEL_WINDOW_S, kf_t_s, 5), keyframes_in(LEVEL_GAP_S, kf_t_s)
    u = np.where(levels.use[:, None], levels.u_m, np.nan)
    nxt = np.append(levels.jumps[1:], k)
    prv = np.insert(levels.jumps[:-1], 0, 0)
    votes = []
    for j, J, a, b in zip(levels.jumps, levels.jump_m, prv, nxt):
        if np.hypot(*J) <= big_m or b - j < gap + 2 * W or j - a < gap + W // 2:
            continue
        with warnings.catch_warnings():  # a stretch inside a GNSS outage: NaN, skipped below
            warnings.simplefilter("ignore", RuntimeWarning)
            before = np.nanmedian(u[j - gap - W // 2:j - gap], axis=0)
            soon = np.nanmedian(u[j + gap:j + gap + W // 2], axis=0)
            late = np.nanmedian(u[j + gap + W:j + gap + 2 * W], axis=0)
        if not (np.all(np.isfinite(before)) and np.all(np.isfinite(soon)) and np.all(np.isfinite(late))):
            continue
        votes.append(np.hypot(*(late - soon)) < 0.5 * np.hypot(*(soon - before)))
    return len(votes) >= 2 and float(np.mean(votes)) >= share


def open_sky_information(kf_t_s: np.ndarray, c_m: np.ndarray, var_c: np.ndarray, breaks: np.ndarray,
                         half: np.ndarray) -> np.ndarray:
    """(k,) information (1/m^2) on a zero level, one keyframe per level (between jumps).

    Between canyons the receiver sees open sky and its fix is unbiased to about a metre (the
    location term trusts exactly that where no edit says otherwise).  Each level is open sky
    or a canyon offset: a mixture prior ``OPEN_SKY_SHARE N(0, OPEN_SKY_SIGMA_M^2) +
    (1 - OPEN_SKY_SHARE) N(0, CANYON_LEVEL_SIGMA_M^2)`` per axis.  From the level the fixes and
    edits alone give (mean ``c_s``, variance ``v_s`` over its inner keyframes), the chance it
    is open sky is ``r_s``; the level then gets ``r_s / OPEN_SKY_SIGMA_M^2`` of information on
    zero (one step of expectation-maximisation).
    """
    k = len(kf_t_s)
    info = np.zeros(k)
    bounds = np.concatenate([[0], np.asarray(breaks, dtype=np.int64), [k]])
    widths = np.concatenate([[0], np.asarray(half, dtype=np.int64), [0]])
    for lo, hi, h_lo, h_hi in zip(bounds[:-1], bounds[1:], widths[:-1], widths[1:]):
        a, b = lo + h_lo, hi - h_hi
        if b - a < 2:
            continue
        c_s = np.mean(c_m[a:b], axis=0)
        v_s = float(np.mean(var_c[a:b]))

        def log_n(sig2):  # log of a 2-D N(c_s; 0, (sig2 + v_s) I), constants dropped
            s2 = sig2 + v_s
            return -0.5 * float(c_s @ c_s) / s2 - np.log(s2)

        lo_o = np.log(OPEN_SKY_SHARE) + log_n(OPEN_SKY_SIGMA_M**2)
        lo_c = np.log(1.0 - OPEN_SKY_SHARE) + log_n(CANYON_LEVEL_SIGMA_M**2)
        r = 1.0 / (1.0 + np.exp(min(lo_c - lo_o, 700.0)))
        info[(a + b) // 2] = r / OPEN_SKY_SIGMA_M**2
    return info


def _level_bias(kf_t_s, p_rep_m, g_m, edit_kf, edit_c_m, levels: GnssLevels, sigma_u: float, prior_sigma: float,
                frozen, d_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horizontal bias (k,2) such that g - bias = p~ + u - c (the level-corrected mean fix), the
    variance of the level (k,), and the location term's horizontal sigma (k,) (inf: no fix).
    ``d_m`` (m,3) the edit offsets (``edit_offsets``), which tell a live drag's moved edits."""
    y = p_rep_m[edit_kf, :2] - edit_c_m[:, :2]  # the pose's error at each edit
    if len(y) >= 3:
        sigma_e = max(float(np.sqrt(np.mean(0.5 * np.sum(y**2, axis=1)))), 1.0)
    else:
        sigma_e = prior_sigma
    u_single = (g_m - p_rep_m)[:, :2]
    prev = frozen[3] if frozen is not None and len(frozen) > 3 else None
    if prev is not None and prev.loc_sigma_h_m is not None and len(prev.loc_sigma_h_m) == len(kf_t_s):
        return _levels_near_new_edits(kf_t_s, levels, edit_kf, y, sigma_u, sigma_e, u_single, prev, d_m)
    c, _, var_c = solve_levels(kf_t_s, levels, edit_kf, y, sigma_u, sigma_e)
    info = open_sky_information(kf_t_s, c, var_c, *level_breaks(levels, ramp_keyframes(kf_t_s)))
    if np.any(info > 0):
        c, _, var_c = solve_levels(kf_t_s, levels, edit_kf, y, sigma_u, sigma_e, level_info=info)
    loc_sigma = np.where(levels.use, np.sqrt(levels.sigma_w_m**2 + var_c), np.inf)
    bias = np.where(levels.use[:, None], u_single - levels.u_m + c, 0.0)
    return bias, np.where(np.isfinite(loc_sigma), var_c, 0.0), loc_sigma


def _levels_near_new_edits(kf_t_s, levels: GnssLevels, edit_kf, y, sigma_u, sigma_e, u_single, prev: DriftEstimate,
                           d_m):
    """A live drag (one more edit on a solved run, or one moved): the levels re-solved with the
    edits that are new or moved (their offset ``d_m`` differs from the last solve's) within ``LEVEL_TAPER_KEYFRAMES[0]`` keyframes of them, tapering linearly to the last full
    solve's beyond the second, and that solve's variances.  Re-solving them in full moves
    every location target of the level an edit sits in (and its neighbours) by millimetres
    to centimetres, which would turn each frame of a drag into a full solve; near the drag
    they are what the commit will see, so the dragged keyframe lands where the commit puts it."""
    prev_bias, prev_var, prev_sigma = prev.bias_enu_m[:, :2], prev.bias_sigma_m**2, prev.loc_sigma_h_m
    before = {round(float(t), 6): dd for t, dd in zip(prev.edit_t_s, prev.edit_offsets_enu_m[:, :2])}
    new = np.array([i for i, (t, dd) in enumerate(zip(kf_t_s[edit_kf], d_m[:, :2]))
                    if (b := before.get(round(float(t), 6))) is None or np.max(np.abs(dd - b)) > 1e-3], dtype=np.int64)
    if len(new) == 0 and len(edit_kf) == len(prev.edit_t_s):
        return prev_bias, prev_var, prev_sigma
    c, _, _ = solve_levels(kf_t_s, levels, edit_kf, y, sigma_u, sigma_e, want_variance=False)
    bias = np.where(levels.use[:, None], u_single - levels.u_m + c, 0.0)
    near, far = LEVEL_TAPER_KEYFRAMES
    changed = edit_kf[new] if len(new) else edit_kf
    dist = np.min(np.abs(np.arange(len(kf_t_s))[:, None] - changed[None, :]), axis=1)
    w = np.clip((far - dist) / (far - near), 0.0, 1.0)[:, None]
    return w * bias + (1.0 - w) * prev_bias, prev_var, prev_sigma


# ----------------------------------------------------------------------------- edits the shape cannot join


def _fill_gaps(u: np.ndarray) -> np.ndarray:
    """Rows of u (k,d) without a fix (NaN) filled by linear interpolation along the rows; zeros when none has one."""
    ok = np.all(np.isfinite(u), axis=1)
    if np.all(ok):
        return u
    if not np.any(ok):
        return np.zeros_like(u)
    idx = np.arange(len(u))
    return np.column_stack([np.interp(idx, idx[ok], u[ok, j]) for j in range(u.shape[1])])


def gnss_transient(u_h: np.ndarray, short: int, long: int) -> np.ndarray:
    """(k,) whitened squared departure of the fix from its usual level relative to the pose.

    ``dev = med_short(u) - med_long(u)`` with u = g - p~ (k,2) (medians over ``short`` and
    ``long`` keyframes make outliers and white noise harmless), divided by the variance it has
    from the fixes' white noise alone (estimated from the run: MAD of the differences of u):
    about chi-square with 2 degrees of freedom where the fix keeps its level, large where it
    jumped (an urban-canyon offset switching on or off) or where a pose that follows it is
    still catching up, for at least ``short`` keyframes in a row.  Zero for a run without
    separate GNSS (u = 0).
    """
    from scipy.ndimage import median_filter, minimum_filter1d

    k = len(u_h)
    if k < 2:
        return np.zeros(k)
    u = _fill_gaps(np.asarray(u_h, dtype=float))
    short, long = max(int(short), 1), max(int(long), 1)
    dev = median_filter(u, size=(short, 1), mode="nearest") - median_filter(u, size=(long, 1), mode="nearest")
    du = np.diff(u, axis=0)
    var_w = (1.4826 * np.median(np.abs(du - np.median(du, axis=0)), axis=0)) ** 2 / 2.0  # per axis
    var_dev = MEDIAN_EFFICIENCY**2 * var_w * (1.0 / short + 1.0 / long)
    if not np.all(var_dev > 0):
        return np.zeros(k)
    # a transient lasts: a burst of outliers long enough to carry one median (3 in 5) does not
    # (kept only where ``short`` keyframes in a row stand out)
    return minimum_filter1d(np.sum(dev**2 / var_dev, axis=1), short, mode="nearest")


def shape_change_evidence(transient: np.ndarray, sideways_m: np.ndarray) -> np.ndarray:
    """(k-1,) relative evidence, per step between keyframes, that the reported pose's error changed there.

    Two physical signs, each scaled by its mean over the run so they weigh alike:

    * the GNSS innovation transient (``gnss_transient``, per keyframe, averaged over each
      step's two ends): a pose that follows its GNSS (an INS fed a biased fix) moves its error
      towards the fix, so its error changes where the fix departs from its usual level;
    * sideways/vertical motion of the reported step a road vehicle cannot make,
      ``|s_lateral|^2`` (see ``terms.sideways_steps``).

    A run without GNSS (u = 0) or without sideways motion simply lacks that sign.
    """
    k = len(transient)
    ev = np.zeros(max(k - 1, 0))
    if k < 2:
        return ev
    innov = 0.5 * (transient[:-1] + transient[1:])
    side = np.asarray(sideways_m, dtype=float) ** 2
    for sign in (innov, side):
        m = float(np.mean(sign))
        if m > 0:
            ev += sign / m
    return ev + 1e-6  # never exactly zero: an interval without any sign shares its change evenly


def edit_bends(
    p_rep_m: np.ndarray,
    rel_var_m2: np.ndarray,
    evidence: np.ndarray,
    edit_kf: np.ndarray,
    edit_c_m: np.ndarray,
    sigma_u_m: float,
    chi2: float = 9.21,
    g_m: np.ndarray | None = None,
    sigma_w_m: float = 3.0,
    window: int = 5,
    transient: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Extra relative-translation variance (k-1,) m^2 between consecutive edits that show the
    pose was dragged by its GNSS, and the keyframes strictly inside those intervals (k,) bool.

    Between consecutive edits a < b the reported shape predicts the horizontal displacement
    ``p~_b - p~_a``, the edits say ``c_b - c_a``; their difference D has per axis the variance
    ``V = sum s_RT,i^2`` that the relative terms allow over the interval plus the edits'
    ``2 sigma_u^2``.  Where ``|D|^2 > chi2 (V + 2 sigma_u^2)`` (9.21: the 99 % point of a
    chi-square with 2 degrees of freedom) the pose's error changed there more than its model
    admits.  When the location measurements ``g_m`` (k,3, NaN without a fix; None: the
    reported pose itself) show why - the edits' GNSS offsets (``edit_offsets``) at the two
    ends differ beyond the same chi-square of their noise (the fix jumped and the pose
    followed), or the fix departed from its level somewhere inside and came back
    (``transient`` beyond the 99.9 % point of its chi-square, see ``gnss_transient``: a canyon
    entered and left between two edits) - the pose was dragged by its GNSS (an INS following
    a biased fix), and the edits are far stronger evidence than the shape:

    * the interval's relative variance is raised to what the edits show, ``|D|^2 / 2`` per
      axis, the extra ``|D|^2/2 - V`` shared among its steps in proportion to ``evidence``
      (``shape_change_evidence``: where the error most likely changed), so the correction
      bends the run where the pose was dragged, not evenly over the interval;
    * the fixes strictly between those edits carry an error change of that size at a time
      nobody knows: they are returned as ``dragged`` and the caller drops them (weight 0);
      the edits at both ends pin the interval.  (Merely down-weighting them leaves robust,
      non-convex location terms holding keyframes whose relative terms were just loosened:
      worse answers, and three times the solver iterations.)

    A pose that wandered more than its model under a fix that did neither is left to the
    location terms, which are good there.  Elsewhere nothing changes.  ``chi2`` 0: off.
    """
    k = len(p_rep_m)
    extra_rel = np.zeros(max(k - 1, 0))
    dragged = np.zeros(k, dtype=bool)
    edit_kf = np.asarray(edit_kf, dtype=np.int64)
    if chi2 <= 0 or len(edit_kf) < 2:
        return extra_rel, dragged
    order = np.argsort(edit_kf, kind="stable")
    e = edit_kf[order]
    c = np.asarray(edit_c_m, dtype=float)[order]
    a, b = e[:-1], e[1:]
    ok = b > a
    a, b, ca, cb = a[ok], b[ok], c[:-1][ok], c[1:][ok]
    cum_var = np.concatenate([[0.0], np.cumsum(rel_var_m2)])
    V = cum_var[b] - cum_var[a]
    D = (cb[:, :2] - ca[:, :2]) - (p_rep_m[b, :2] - p_rep_m[a, :2])
    d2 = np.einsum("ij,ij->i", D, D)
    bent = d2 > chi2 * (V + 2.0 * sigma_u_m**2)
    if not np.any(bent):
        return extra_rel, dragged
    a, b, ca, cb, d2, V = a[bent], b[bent], ca[bent], cb[bent], d2[bent], V[bent]
    g_m = p_rep_m if g_m is None else g_m
    off = edit_offsets(np.zeros(k), p_rep_m, g_m, np.concatenate([a, b]), np.concatenate([ca, cb]), window)[:, :2]
    n_win = min(2 * window + 1, k)
    noise = sigma_u_m**2 + (MEDIAN_EFFICIENCY * sigma_w_m) ** 2 / n_win
    jump = off[len(a):] - off[:len(a)]
    by_gnss = np.einsum("ij,ij->i", jump, jump) > chi2 * 2.0 * noise
    if transient is not None:
        big = np.asarray(transient, dtype=float) > TRANSIENT_CHI2
        cum_big = np.concatenate([[0], np.cumsum(big)])
        by_gnss |= (cum_big[b] - cum_big[a + 1]) > 0  # strictly between the edits
    if not np.any(by_gnss):
        return extra_rel, dragged
    a, b, d2, V = a[by_gnss], b[by_gnss], d2[by_gnss], V[by_gnss]
    E = np.maximum(0.5 * d2 - V, 0.0)
    cum_ev = np.concatenate([[0.0], np.cumsum(evidence)])
    S = cum_ev[b] - cum_ev[a]
    # steps of each interval (they do not overlap: consecutive edits)
    n = b - a
    j = np.repeat(np.arange(len(a)), n)
    step = a[j] + (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n))
    extra_rel[step] = E[j] * evidence[step] / S[j]
    dragged[step[step > a[j]]] = True
    return extra_rel, dragged


# ----------------------------------------------------------------------------- GNSS levels
#
# A GNSS/INS pose that bridged an urban canyon keeps its shape while the raw fix jumps onto
# an offset and back (the ``canyon_ins`` case).  Per horizontal axis, at keyframe i:
#
#     u_i = mean over the keyframe's samples of (g - p~) = c_i - e_i + w_i
#
# with ``e`` the reported pose's error (smooth: its velocity error ``v`` wanders as a
# Gauss-Markov process, e_i+1 = a e_i + dt v_i), ``c`` the fix's level (constant between
# jumps, free at a jump) and ``w`` white noise.  An edit observes e directly (p~ - c_edit).
# Because e is smooth and c is piecewise constant, u separates them: e's shape inside a
# level, and each jump's size from e's continuity (position and velocity) across it; the
# edits anchor the levels.  The location term then reads the level-corrected mean fix,
# g~_i = p~_i + u_i - c_i, with the white sigma the run shows plus the level's uncertainty.

LEVEL_WINDOW_S = 20.0  # line fits on each side of a candidate jump
LEVEL_GAP_S = 3.0  # left out on each side: a fix moves onto its new level within seconds
LEVEL_RAMP_S = 4.0  # a level may change within this many seconds of a found jump
LEVEL_N_SIGMA = 5.0  # a jump stands this many sigmas out of the line fits' noise
LEVEL_MIN_JUMP_M = 2.0  # and is at least this large
POSE_VEL_SIGMA_MPS = 0.05  # velocity error of a GNSS/INS pose, 1 sigma per axis (a few cm/s)
POSE_VEL_TAU_S = 30.0  # its correlation time
POSE_ERR_TAU_S = 600.0  # the pose error returns to zero over this (aided by GNSS)
LEVEL_WANDER_M2_PER_S = 1e-5  # a level's slow wander between jumps (0.13 m over 30 min)
LEVEL_PRIOR_SIGMA_M = 10.0  # the first level, before any edit says otherwise
LEVEL_JUMP_SIGMA_M = 15.0  # prior spread of a jump (canyon offsets are 5-20 m)
OPEN_SKY_SIGMA_M = 1.0  # bias of an open-sky fix, 1 sigma per axis
CANYON_LEVEL_SIGMA_M = 12.0  # spread of a canyon offset's level, per axis
OPEN_SKY_SHARE = 0.5  # prior share of open-sky levels
LEVEL_TAPER_KEYFRAMES = (30, 90)  # a live drag re-solves the levels within the first, none beyond the second


@dataclass(frozen=True)
class GnssLevels:
    """What the fixes say about their own level, from the run alone (cached per keyframe set).

    u_m (k,2): mean of g - p~ over the samples nearest each keyframe (east, north; NaN where none);
    use (k,) bool: keyframes whose mean counts (a fix, not an outlier); sigma_w_m: white sigma of
    u_m per keyframe and axis (from the MAD of its differences); jumps (j,) keyframes where the
    level changes; jump_m (j,2) their sizes as found; bridged: the pose bridged the jumps
    (``levels_bridged``).
    """

    u_m: np.ndarray
    use: np.ndarray
    sigma_w_m: float
    jumps: np.ndarray
    jump_m: np.ndarray
    bridged: bool = False


def keyframe_means(t_s: np.ndarray, u: np.ndarray, kf_t_s: np.ndarray) -> np.ndarray:
    """Mean of u (n,d) over the samples nearer each keyframe time than its neighbours' (k,d); NaN where none."""
    edges = 0.5 * (kf_t_s[1:] + kf_t_s[:-1])
    b = np.searchsorted(edges, t_s, side="right")
    ok = np.all(np.isfinite(u), axis=1)
    k, d = len(kf_t_s), u.shape[1]
    s = np.zeros((k, d))
    n = np.bincount(b[ok], minlength=k).astype(float)
    for j in range(d):
        s[:, j] = np.bincount(b[ok], weights=u[ok, j], minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n[:, None] > 0, s / n[:, None], np.nan)


def white_sigma(u: np.ndarray) -> float:
    """Per-axis sigma of the white part of u (k,d): MAD of consecutive differences / sqrt 2."""
    ok = np.all(np.isfinite(u), axis=1)
    du = np.diff(u[ok], axis=0)
    if len(du) < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(du - np.median(du, axis=0))) / np.sqrt(2.0))


def line_breaks(u: np.ndarray, sigma_w: float, window: int, gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Discontinuity of u (k,2) at each keyframe, (k,2), and its z-score (k,).

    Lines fitted (least squares, cumulative sums: O(k)) to u on [i-gap-window, i-gap) and on
    (i+gap, i+gap+window], both extrapolated to i: a smooth wander of the pose's error meets
    itself, a jump of the fix does not.  z divides the gap by the sigma of the two
    extrapolations (white noise ``sigma_w``).
    """
    k = len(u)
    ok = np.all(np.isfinite(u), axis=1).astype(float)
    uf = np.where(ok[:, None] > 0, u, 0.0)
    x = np.arange(k, dtype=float)

    def cum(a):
        return np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)])

    S0, S1, S2 = cum(ok), cum(ok * x), cum(ok * x * x)
    Sy, Sxy = cum(uf * ok[:, None]), cum(uf * (ok * x)[:, None])

    def extrapolate(lo, hi):
        lo, hi = np.clip(lo, 0, k), np.clip(hi, 0, k)
        n, sx, sxx = S0[hi] - S0[lo], S1[hi] - S1[lo], S2[hi] - S2[lo]
        sy, sxy = Sy[hi] - Sy[lo], Sxy[hi] - Sxy[lo]
        nn = np.maximum(n, 1.0)
        xbar = sx / nn
        sxx_c = sxx - n * xbar * xbar
        good = (n >= max(window // 2, 3)) & (sxx_c > 1e-9)
        slope = (sxy - sx[:, None] * sy / nn[:, None]) / np.where(good, sxx_c, 1.0)[:, None]
        at = slope * (x - xbar)[:, None] + sy / nn[:, None]
        var = sigma_w**2 * (1.0 / nn + (x - xbar) ** 2 / np.where(good, sxx_c, 1.0))
        return np.where(good[:, None], at, np.nan), np.where(good, var, np.inf)

    i = np.arange(k)
    left, v_l = extrapolate(i - gap - window, i - gap)
    right, v_r = extrapolate(i + gap + 1, i + gap + 1 + window)
    D = right - left
    with np.errstate(invalid="ignore"):
        z = np.hypot(D[:, 0], D[:, 1]) / np.sqrt(np.maximum(v_l + v_r, 1e-12))
    return D, np.where(np.isfinite(z), z, 0.0)


def find_level_jumps(u: np.ndarray, sigma_w: float, window: int, gap: int,
                     n_sigma: float = LEVEL_N_SIGMA, min_jump_m: float = LEVEL_MIN_JUMP_M,
                     max_jumps: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    """Jumps of the fix's level in u (k,2), greedily: the strongest break, taken out of u, then the next.

    Taking each jump out before looking again keeps a jump from showing up a second time
    where one line fit straddles it, and lets two jumps a short open-sky stretch apart both
    be found.  Returns keyframes (j,) and sizes (j,2), in keyframe order.
    """
    v = np.array(u, dtype=float)
    k = len(v)
    picked, sizes = [], []
    blocked = np.zeros(k, dtype=bool)
    D, z = line_breaks(v, sigma_w, window, gap)
    reach = window + 2 * gap + 1  # breaks whose fits read u around a jump taken out (and its blanked ramp)
    for _ in range(max_jumps):
        mag = np.hypot(D[:, 0], D[:, 1])
        ok = (z > n_sigma) & (mag > min_jump_m) & np.isfinite(mag) & ~blocked
        if not ok.any():
            break
        j0 = int(np.flatnonzero(ok)[np.argmax(mag[ok])])
        j = _sharpest_split(v, j0, window, gap)  # a line fit straddling the jump extrapolates further than the jump
        if blocked[j] or not np.all(np.isfinite(D[j])):
            blocked[max(j0 - gap, 0):j0 + gap + 1] = True  # the break leads nowhere new: never again
            continue
        picked.append(j)
        sizes.append(D[j].copy())
        # the step leaves u (after the gap) and so does the ramp (the fix moving onto its new level);
        # a step taken out at a slightly wrong place would otherwise leave a spike that looks like two more
        v[j + gap + 1:] -= D[j]
        v[max(j - gap, 0):j + gap + 1] = np.nan
        blocked[max(j - gap, 0):j + gap + 1] = True
        # only breaks whose fits reach across j changed: recompute those (O(window) per jump, not O(k))
        lo, hi = max(j - reach, 0), min(j + reach + 1, k)
        a, b = max(lo - reach, 0), min(hi + reach, k)
        D_s, z_s = line_breaks(v[a:b], sigma_w, window, gap)
        D[lo:hi], z[lo:hi] = D_s[lo - a:hi - a], z_s[lo - a:hi - a]
    order = np.argsort(picked, kind="stable")
    return np.asarray(picked, dtype=np.int64)[order], np.asarray(sizes, dtype=float).reshape(-1, 2)[order]


def _sharpest_split(u: np.ndarray, j: int, window: int, gap: int) -> int:
    """The split near j (within ``window``) where the means of u over ``window // 2`` keyframes
    on each side (``gap`` left out) differ most: where a step sits, flat on both sides."""
    k = len(u)
    h = max(window // 2, 2)
    ok = np.all(np.isfinite(u), axis=1).astype(float)
    cs = np.concatenate([np.zeros((1, 2)), np.cumsum(np.where(ok[:, None] > 0, u, 0.0), axis=0)])
    cn = np.concatenate([[0.0], np.cumsum(ok)])
    i = np.arange(max(j - window, 0), min(j + window, k - 1) + 1)
    lo_a, lo_b = np.clip(i - gap - h, 0, k), np.clip(i - gap, 0, k)
    hi_a, hi_b = np.clip(i + gap + 1, 0, k), np.clip(i + gap + 1 + h, 0, k)
    n_l, n_r = cn[lo_b] - cn[lo_a], cn[hi_b] - cn[hi_a]
    good = (n_l >= 2) & (n_r >= 2)
    if not good.any():
        return j
    m_l = (cs[lo_b] - cs[lo_a]) / np.maximum(n_l, 1)[:, None]
    m_r = (cs[hi_b] - cs[hi_a]) / np.maximum(n_r, 1)[:, None]
    score = np.where(good, np.hypot(*(m_r - m_l).T), -1.0)
    # a step scores the same at every split whose left-out gap holds it: take the middle of that plateau
    top = np.flatnonzero(score >= 0.97 * score.max())
    return int(i[top[len(top) // 2]])


def gnss_levels(t_s: np.ndarray, u: np.ndarray, kf_t_s: np.ndarray) -> GnssLevels:
    """The level model's data for keyframes at kf_t_s (k,), from all samples' u = g - p~ (n,2)."""
    u_m = keyframe_means(t_s, u[:, :2], kf_t_s)
    sigma_w = max(white_sigma(u_m), 0.05)
    window, gap = keyframes_in(LEVEL_WINDOW_S, kf_t_s, 5), keyframes_in(LEVEL_GAP_S, kf_t_s)
    ok = np.all(np.isfinite(u_m), axis=1)
    use = ok.copy()
    if ok.sum() > 9:
        # outliers: far from the median of their neighbours (a 50 m fix among good ones)
        from scipy.ndimage import median_filter

        filled = _fill_gaps(u_m)
        med = np.column_stack([median_filter(filled[:, j], 9, mode="nearest") for j in range(2)])
        use &= np.hypot(*(filled - med).T) <= 5.0 * sigma_w + 1.0
    jumps, jump_m = find_level_jumps(np.where(use[:, None], u_m, np.nan), sigma_w, window, gap) \
        if len(kf_t_s) >= 2 * (window + gap) + 1 else (np.zeros(0, np.int64), np.zeros((0, 2)))
    levels = GnssLevels(u_m, use, sigma_w, jumps, jump_m)
    return dataclasses.replace(levels, bridged=levels_bridged(levels, kf_t_s))


def ramp_keyframes(kf_t_s: np.ndarray) -> int:
    """``LEVEL_RAMP_S`` in keyframes at the run's typical spacing (at least 1)."""
    return keyframes_in(LEVEL_RAMP_S, kf_t_s)


def level_breaks(levels: GnssLevels, ramp: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the level may change: centres (b,) and half-widths (b,) in keyframes, sorted.

    Each jump found, over its ramp; and each stretch without a usable fix that lasts at least
    a ramp (a tunnel, a receiver outage), over its length plus a ramp: nothing says the fix
    kept its level while it was gone.
    """
    k = len(levels.use)
    missing = np.flatnonzero(np.diff(np.concatenate([[0], (~levels.use).astype(np.int8), [0]])))
    starts, ends = missing[0::2], missing[1::2]  # runs [start, end) of keyframes without a usable fix
    long_ = (ends - starts) >= ramp
    starts, ends = starts[long_], ends[long_]
    keep = (starts > 0) & (ends < k)  # a run at either end of the run separates nothing
    starts, ends = starts[keep], ends[keep]
    centres = np.concatenate([np.asarray(levels.jumps, dtype=np.int64), (starts + ends) // 2])
    half = np.concatenate([np.full(len(levels.jumps), ramp, dtype=np.int64), (ends - starts + 1) // 2 + ramp])
    order = np.argsort(centres, kind="stable")
    return centres[order], half[order]


def _level_blocks(t_s, levels: GnssLevels, edit_kf, sigma_u, sigma_e, ramp: int):
    """Information matrix of the level model as 3x3 blocks: diagonal (k,3,3) and below it (k-1,3,3), states [e, v, c]."""
    k = len(t_s)
    dt = np.maximum(np.diff(t_s), 1e-6)
    a = np.exp(-dt / POSE_ERR_TAU_S)
    b = np.exp(-dt / POSE_VEL_TAU_S)
    ie = 1.0 / (1e-6 * dt + 1e-9)  # e moves through v; a trace of its own noise keeps H definite
    iv = 1.0 / (POSE_VEL_SIGMA_MPS**2 * (1.0 - b * b))
    q_c = LEVEL_WANDER_M2_PER_S * dt
    for j, h in zip(*level_breaks(levels, ramp)):
        lo, hi = max(int(j - h), 0), min(int(j + h), k - 1)
        q_c[lo:hi] += LEVEL_JUMP_SIGMA_M**2 / max(hi - lo, 1)
    ic = 1.0 / q_c
    Dg = np.zeros((k, 3, 3))
    L = np.zeros((k - 1, 3, 3))  # L[i] = H[i+1, i]
    # e_i+1 - a e_i - dt v_i: alpha = (-a, -dt, 0) on i, beta = (1, 0, 0) on i+1
    Dg[:-1, 0, 0] += a * a * ie
    Dg[:-1, 0, 1] += a * dt * ie
    Dg[:-1, 1, 0] += a * dt * ie
    Dg[:-1, 1, 1] += dt * dt * ie
    Dg[1:, 0, 0] += ie
    L[:, 0, 0] += -a * ie
    L[:, 0, 1] += -dt * ie
    # v_i+1 - b v_i
    Dg[:-1, 1, 1] += b * b * iv
    Dg[1:, 1, 1] += iv
    L[:, 1, 1] += -b * iv
    # c_i+1 - c_i
    Dg[:-1, 2, 2] += ic
    Dg[1:, 2, 2] += ic
    L[:, 2, 2] += -ic
    Dg[0] += np.diag([1.0 / sigma_e**2, 1.0 / POSE_VEL_SIGMA_MPS**2, 1.0 / LEVEL_PRIOR_SIGMA_M**2])
    # u_i = c_i - e_i
    w = np.where(levels.use, 1.0 / levels.sigma_w_m**2, 0.0)
    Dg[:, 0, 0] += w
    Dg[:, 2, 2] += w
    Dg[:, 0, 2] -= w
    Dg[:, 2, 0] -= w
    np.add.at(Dg[:, 0, 0], np.asarray(edit_kf, dtype=np.int64), 1.0 / sigma_u**2)
    return Dg, L, w


def solve_levels(t_s, levels: GnssLevels, edit_kf, y_m, sigma_u: float, sigma_e: float,
                 want_variance: bool = True, level_info: np.ndarray | None = None):
    """Smoothed level c (k,2) and pose error e (k,2) of the level model, and the variance of c (k,) (or None).

    ``y_m`` (m,2) the pose's error at each edit (p~ - c_edit); ``level_info`` (k,) extra
    information (1/m^2) on the level being zero at each keyframe (``open_sky_information``).  The means come from one
    banded Cholesky solve (both axes at once: they share the information matrix); the
    variances from columns of the inverse (``level_variance_at_levels``).
    """
    from scipy.linalg import cho_solve_banded, cholesky_banded

    k = len(t_s)
    ramp = ramp_keyframes(t_s)
    Dg, L, w = _level_blocks(t_s, levels, edit_kf, sigma_u, sigma_e, ramp)
    if level_info is not None:
        Dg[:, 2, 2] += level_info
    g = np.zeros((k, 3, 2))
    u = np.where(levels.use[:, None], levels.u_m, 0.0)
    g[:, 0] -= w[:, None] * u
    g[:, 2] += w[:, None] * u
    np.add.at(g[:, 0], np.asarray(edit_kf, dtype=np.int64), np.asarray(y_m, dtype=float) / sigma_u**2)
    # upper banded storage, bandwidth 5: ab[5 + row - col, col]
    n = 3 * k
    ab = np.zeros((6, n))
    for r in range(3):
        for s in range(r, 3):
            ab[5 + r - s, np.arange(k) * 3 + s] = Dg[:, r, s]
    for r in range(3):  # H[3i + r, 3(i+1) + s] = L[i][s, r]
        for s in range(3):
            ab[5 + r - (3 + s), np.arange(1, k) * 3 + s] = L[:, s, r]
    cb = cholesky_banded(ab, check_finite=False)
    x = cho_solve_banded((cb, False), g.reshape(n, 2), check_finite=False).reshape(k, 3, 2)
    var_c = level_variance_at_levels(cb, *level_breaks(levels, ramp)) if want_variance else None
    return x[:, 2], x[:, 0], var_c


def level_variance_at_levels(cb: np.ndarray, breaks: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Marginal variance of the level (k,) from the banded Cholesky factor ``cb`` of the information matrix.

    Between jumps the level is one constant (its wander is centimetres over a run), so its
    variance is the same at every keyframe of a level: it is solved exactly (a column of the
    inverse, ``H^-1 e_i``) at the middle of each level and held over it, and at each break
    (``level_breaks``: centres, half-widths), whose value (the peak: the level is free there)
    the keyframes around it take.  O(k (levels +
    jumps)) instead of a per-keyframe recursion.
    """
    from scipy.linalg import cho_solve_banded

    k = cb.shape[1] // 3
    jumps = np.asarray(breaks, dtype=np.int64)
    bounds = np.concatenate([[0], jumps, [k]])
    mids = (bounds[:-1] + bounds[1:]) // 2
    at = np.unique(np.clip(np.concatenate([mids, jumps]), 0, k - 1))
    E = np.zeros((3 * k, len(at)))
    E[3 * at + 2, np.arange(len(at))] = 1.0
    X = cho_solve_banded((cb, False), E, check_finite=False)
    exact = X[3 * at + 2, np.arange(len(at))]
    seg = np.searchsorted(jumps, np.arange(k), side="right")  # level of each keyframe
    var = np.empty(k)
    var[:] = exact[np.searchsorted(at, mids)][seg]
    for j, h in zip(jumps, half):  # where the level moves: its peak, at the break
        var[max(j - h, 0):j + h + 1] = exact[np.searchsorted(at, min(j, k - 1))]
    return np.maximum(var, 0.0)
