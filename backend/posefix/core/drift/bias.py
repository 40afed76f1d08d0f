"""The Gauss-Markov bias of the location measurements, as the edits reveal it.

GNSS errors are correlated in time.  Model the location measurement at keyframe i as
``g_i = truth_i + b(t_i) + w_i``: a bias ``b`` that wanders as a first-order Gauss-Markov
(Ornstein-Uhlenbeck) process, stationary sigma ``sigma_b`` and correlation time ``tau``
(per horizontal axis), plus white noise ``w`` of sigma ``sigma_w``.  An edit is
``c_k = truth + u_k`` (sigma ``sigma_u``), so every edit observes the bias:

    d_k = g~(t_k) - c_k = b(t_k) + n_k          (``base.edit_offsets``)

1. Parameters from the edits: the wander rate ``q = 2 sigma_b^2 / tau`` from consecutive
   differences, whose per-axis variance is ``q dt + var(n_k) + var(n_k+1)`` for dt << tau
   (method of moments pooled over all pairs, ``estimate_walk``), ``sigma_b^2`` from the mean
   square offset, and ``tau = 2 sigma_b^2 / q`` (clipped to [30 s, 1 h]).
2. A Kalman filter and RTS smoother over the edit times (``smooth_gauss_markov``) give the
   bias and its variance at each edit.  Between two edits the bias is the Gauss-Markov
   bridge between them (``bias_at``; linear for gaps much shorter than tau); beyond the
   first/last edit it decays towards zero with tau while its variance grows back to
   sigma_b^2.  An interval whose two edits disagree far beyond their noise (a jump of an
   urban-canyon offset, ``local_walk``) gets the variance of a Brownian bridge with the
   intensity that jump implies.
"""

from __future__ import annotations

import numpy as np

MIN_TAU_S, MAX_TAU_S = 30.0, 3600.0  # plausible correlation times of a GNSS bias


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
