"""Drift (issue section 6): the GNSS bias the edits reveal, and what it does to the location term.

GNSS errors are correlated in time.  Model the location measurement at keyframe i as
``g_i = truth_i + b(t_i) + w_i``: a bias ``b`` that wanders as a random walk of intensity
``q`` (m^2/s per horizontal axis) plus white noise ``w`` of sigma ``sigma_w``.  An edit is
``c_k = truth + u_k`` with sigma ``sigma_u``, so every edit observes the bias:

    d_k = g~(t_k) - c_k = b(t_k) + n_k,

where ``g~(t_k)`` is the location measurement at the edit made robust against outliers
and white noise: the reported pose at the edit plus the median of (g - p~) over the
neighbouring keyframes (the reported pose keeps its local shape, so g - p~ varies slowly).

1. ``q`` is estimated from consecutive edits, whose differences have per-axis variance
   ``q dt + 2 var(n)`` (method of moments, pooled over all pairs).  With fewer edits than ``min_edits`` the configured prior is used.
2. A Kalman filter and RTS smoother over the edit times give the bias and its variance at
   each edit; between edits the mean is interpolated linearly (the Brownian-bridge mean)
   and the variance is ``(1-a) P_a + a P_b + q (t - t_a)(t_b - t)/(t_b - t_a)``; beyond
   the first/last edit the bias is held and its variance grows by ``q |dt|``.
3. The location term of keyframe i is re-centred on ``g_i - b_i`` and its horizontal
   sigma inflated to ``sqrt(sigma_w^2 + var_b,i)``: where edits show drift the term is
   down-weighted (between edits, where the bias is uncertain) and no longer biased, so
   hundreds of weak, correlated fixes cannot pull the run back onto a biased track.  With
   no drift (q ~ 0, offsets ~ 0) the term is left as it was.

Vertical: only 3-D edits observe the vertical bias; without them the vertical is left alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MEDIAN_EFFICIENCY = 1.2533  # sigma of a sample median / (sigma / sqrt(n)) for Gaussian data


@dataclass(frozen=True)
class DriftEstimate:
    """What the edits say about the location measurements' bias.

    offset_enu_m : (3,) robust mean (median) of the edit offsets g - c, metres (NaN vertical
        when no 3-D edit).
    spread_m : robust horizontal spread (MAD-based sigma) of the edit offsets, metres.
    walk_m2_per_s : estimated random-walk intensity q of the bias, m^2/s per axis.
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

    def to_json(self) -> dict:
        return {
            "offset_enu_m": [None if not np.isfinite(v) else float(v) for v in self.offset_enu_m],
            "spread_m": float(self.spread_m),
            "walk_m2_per_s": float(self.walk_m2_per_s),
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
    """
    g_minus_p = g_m - p_rep_m
    k = len(kf_t_s)
    out = np.empty((len(edit_kf), 3))
    for n, i in enumerate(np.asarray(edit_kf, dtype=np.int64)):
        lo, hi = max(i - window, 0), min(i + window + 1, k)
        local = g_minus_p[lo:hi]
        local = local[np.all(np.isfinite(local), axis=1)]
        shift = np.median(local, axis=0) if len(local) else np.zeros(3)
        out[n] = p_rep_m[i] + shift - edit_c_m[n]
    return out


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


def smooth_random_walk(t_s: np.ndarray, y: np.ndarray, r_var: np.ndarray, q, prior_var: float = 1e6):
    """Kalman filter + RTS smoother of a scalar random walk observed at sorted times.

    y (m,) observations, r_var (m,) their variances, q the intensity (scalar, or (m-1,) one
    per interval).  Returns smoothed means (m,) and variances (m,).
    """
    q = np.broadcast_to(np.asarray(q, dtype=float), (max(len(t_s) - 1, 0),))
    m = len(t_s)
    xf, Pf = np.empty(m), np.empty(m)
    xp, Pp = np.empty(m), np.empty(m)
    x, P = 0.0, prior_var
    for k in range(m):
        if k:
            P = P + q[k - 1] * (t_s[k] - t_s[k - 1])
        xp[k], Pp[k] = x, P
        K = P / (P + r_var[k])
        x = x + K * (y[k] - x)
        P = (1.0 - K) * P
        xf[k], Pf[k] = x, P
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(m - 2, -1, -1):
        G = Pf[k] / Pp[k + 1]
        xs[k] = xf[k] + G * (xs[k + 1] - xp[k + 1])
        Ps[k] = Pf[k] + G * G * (Ps[k + 1] - Pp[k + 1])
    return xs, Ps


def bias_at(kf_t_s: np.ndarray, t_e: np.ndarray, mean: np.ndarray, var: np.ndarray, q: float, q_seg=None):
    """Bias mean (k,) and variance (k,) at keyframe times from the smoothed values at edit times.

    ``q`` applies outside the edits, ``q_seg`` (m-1,) inside each interval (default q).
    """
    if len(t_e) == 1:
        return np.full(len(kf_t_s), mean[0]), var[0] + q * np.abs(kf_t_s - t_e[0])
    q_seg = np.full(len(t_e) - 1, q) if q_seg is None else np.asarray(q_seg, dtype=float)
    j = np.clip(np.searchsorted(t_e, kf_t_s, side="right") - 1, 0, len(t_e) - 2)
    ta, tb = t_e[j], t_e[j + 1]
    a = np.clip((kf_t_s - ta) / (tb - ta), 0.0, 1.0)
    mu = (1 - a) * mean[j] + a * mean[j + 1]
    bridge = q_seg[j] * np.clip(kf_t_s - ta, 0, None) * np.clip(tb - kf_t_s, 0, None) / (tb - ta)
    v = (1 - a) * var[j] + a * var[j + 1] + bridge
    before, after = kf_t_s < t_e[0], kf_t_s > t_e[-1]
    v = np.where(before, var[0] + q * (t_e[0] - kf_t_s), v)
    v = np.where(after, var[-1] + q * (kf_t_s - t_e[-1]), v)
    return mu, v


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
    prior_walk_m2_per_s: float,
    min_edits_for_estimate: int = 3,
    window: int = 5,
) -> DriftEstimate:
    """Fit the bias model to the edits; see the module docstring.

    kf_t_s (k,), p_rep_m (k,3) reported keyframe positions, g_m (k,3) location measurements
    (NaN where none), edit_kf (m,) keyframe of each edit, edit_c_m (m,3) edit targets
    (vertical ignored where ``edit_has_alt`` is False).
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
    if len(t_e) >= max(min_edits_for_estimate, 2):
        q = estimate_walk(t_e, d[:, :2], noise_h)
    else:
        q = prior_walk_m2_per_s
    q = max(q, 1e-6)
    q_seg = local_walk(t_e, d[:, :2], noise_h, q)
    bias = np.zeros((k, 3))
    var_h = np.zeros(k)
    for axis in (0, 1):
        xs, Ps = smooth_random_walk(t_e, d[:, axis], noise_h, q_seg)
        bias[:, axis], v = bias_at(kf_t_s, t_e, xs, Ps, q, q_seg)
        var_h += 0.5 * v
    has_v = np.isfinite(d[:, 2])
    if np.any(has_v):
        xs, Ps = smooth_random_walk(t_e[has_v], d[has_v, 2], noise_v[has_v], q)
        bias[:, 2], _ = bias_at(kf_t_s, t_e[has_v], xs, Ps, q)
    offset = np.array([np.median(d[:, 0]), np.median(d[:, 1]), np.median(d[has_v, 2]) if np.any(has_v) else np.nan])
    dev = np.hypot(d[:, 0] - offset[0], d[:, 1] - offset[1])
    spread = float(1.4826 * np.median(dev) / np.sqrt(np.log(4.0))) if len(dev) > 1 else 0.0
    # A bias is "detected" when the offsets stand out of the noise they would have without one.
    typical_dt = float(np.median(np.diff(t_e))) if len(t_e) > 1 else float(kf_t_s[-1] - kf_t_s[0])
    detected = bool(
        np.hypot(offset[0], offset[1]) > 2.0 * np.sqrt(noise_h[0] + sigma_w_h_m**2 / len(t_e))
        or q * typical_dt > noise_h[0]
    )
    weight = sigma_w_h_m**2 / (sigma_w_h_m**2 + var_h)
    return DriftEstimate(
        offset_enu_m=offset,
        spread_m=spread,
        walk_m2_per_s=float(q),
        detected=detected,
        bias_enu_m=bias,
        bias_sigma_m=np.sqrt(var_h),
        weight=weight,
        edit_offsets_enu_m=d,
        edit_t_s=t_e,
    )
