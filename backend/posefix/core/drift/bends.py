"""Edits the reported shape cannot join: where the pose was dragged by its GNSS.

Between consecutive edits a < b the reported shape predicts ``p~_b - p~_a`` and the edits
say ``c_b - c_a``; their difference D has per axis the variance V = sum s_RT,i^2 the
relative terms allow plus ``2 sigma_u^2``.  Where ``|D|^2 > chi2 (V + 2 sigma_u^2)`` and the
GNSS shows why (``gnss_transient``: the whitened departure of the fix from its level,
``dev = med_short(u) - med_long(u)``, ``dev^2 / var(dev)`` about chi-square(2) where the fix
keeps its level), the interval's relative variance is raised to ``|D|^2 / 2`` per axis,
shared among its steps in proportion to ``shape_change_evidence``, and its fixes drop out.
"""

from __future__ import annotations

import numpy as np

from posefix.core.drift.base import MEDIAN_EFFICIENCY, edit_offsets, fill_gaps
from posefix.core.filters import running_median, running_min

TRANSIENT_CHI2 = 13.8  # 99.9 % point of a chi-square with 2 degrees of freedom


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
    k = len(u_h)
    if k < 2:
        return np.zeros(k)
    u = fill_gaps(np.asarray(u_h, dtype=float))
    short, long = max(int(short), 1), max(int(long), 1)
    dev = running_median(u, short) - running_median(u, long)
    du = np.diff(u, axis=0)
    var_w = (1.4826 * np.median(np.abs(du - np.median(du, axis=0)), axis=0)) ** 2 / 2.0  # per axis
    var_dev = MEDIAN_EFFICIENCY**2 * var_w * (1.0 / short + 1.0 / long)
    if not np.all(var_dev > 0):
        return np.zeros(k)
    # a transient lasts: a burst of outliers long enough to carry one median (3 in 5) does not
    # (kept only where ``short`` keyframes in a row stand out)
    return running_min(np.sum(dev**2 / var_dev, axis=1), short)


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
    sigma_u_m: float | np.ndarray,
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
    ``sigma_u,a^2 + sigma_u,b^2`` (``sigma_u_m``: one for all, or (m,) per edit).  Where ``|D|^2 > chi2 (V + 2 sigma_u^2)`` (9.21: the 99 % point of a
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
    if np.ndim(sigma_u_m):
        s2 = np.asarray(sigma_u_m, dtype=float)[order] ** 2
        u2 = s2[:-1][ok] + s2[1:][ok]  # the two ends' variances, per interval
    else:
        u2 = 2.0 * sigma_u_m**2
    cum_var = np.concatenate([[0.0], np.cumsum(rel_var_m2)])
    V = cum_var[b] - cum_var[a]
    D = (cb[:, :2] - ca[:, :2]) - (p_rep_m[b, :2] - p_rep_m[a, :2])
    d2 = np.einsum("ij,ij->i", D, D)
    bent = d2 > chi2 * (V + u2)
    if not np.any(bent):
        return extra_rel, dragged
    if np.ndim(u2):
        u2 = u2[bent]
    a, b, ca, cb, d2, V = a[bent], b[bent], ca[bent], cb[bent], d2[bent], V[bent]
    g_m = p_rep_m if g_m is None else g_m
    off = edit_offsets(np.zeros(k), p_rep_m, g_m, np.concatenate([a, b]), np.concatenate([ca, cb]), window)[:, :2]
    n_win = min(2 * window + 1, k)
    noise2 = u2 + 2.0 * (MEDIAN_EFFICIENCY * sigma_w_m) ** 2 / n_win  # of the two ends' offsets together
    jump = off[len(a):] - off[:len(a)]
    by_gnss = np.einsum("ij,ij->i", jump, jump) > chi2 * noise2
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
