"""GNSS levels: a pose that bridged urban-canyon offsets, and the fix's piecewise-constant level.

A GNSS/INS pose that bridged an urban canyon keeps its shape while the raw fix jumps onto
an offset and back (the ``canyon_ins`` case).  Per horizontal axis, at keyframe i:

    u_i = mean over the keyframe's samples of (g - p~) = c_i - e_i + w_i

with ``e`` the reported pose's error (smooth: its velocity error ``v`` wanders as a
Gauss-Markov process, e_i+1 = a e_i + dt v_i), ``c`` the fix's level (constant between
jumps, free at a jump) and ``w`` white noise.  An edit observes e directly (p~ - c_edit).
Because e is smooth and c is piecewise constant, u separates them: e's shape inside a
level, and each jump's size from e's continuity (position and velocity) across it; the
edits anchor the levels.  The location term then reads the level-corrected mean fix,
g~_i = p~_i + u_i - c_i, with the white sigma the run shows plus the level's uncertainty.

The model engages where the fix steps persistently against the pose (``steps.gnss_steps``)
and the pose kept its shape across every large step (``levels_bridged``, read from the run
itself: one edit is enough).  Each level is open sky or a canyon offset: a mixture prior
``OPEN_SKY_SHARE N(0, OPEN_SKY_SIGMA_M^2) + (1 - OPEN_SKY_SHARE) N(0, CANYON_LEVEL_SIGMA_M^2)``
(``open_sky_information``).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

import numpy as np

from posefix.core import banded
from posefix.core.drift.base import DriftEstimate, DriftParams, fill_gaps, keyframe_means, keyframes_in, white_sigma
from posefix.core.filters import running_median

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
        filled = fill_gaps(u_m)
        med = running_median(filled, 9)
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
    # H[3i + r, 3(i+1) + s] = L[i][s, r]: the upper blocks are L transposed
    factor = banded.factor(Dg, L.transpose(0, 2, 1))
    x = banded.solve(factor, g.reshape(3 * k, 2)).reshape(k, 3, 2)
    var_c = level_variance_at_levels(factor, *level_breaks(levels, ramp)) if want_variance else None
    return x[:, 2], x[:, 0], var_c


def level_variance_at_levels(factor: banded.Factor, breaks: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Marginal variance of the level (k,) from the factor (``banded.factor``) of the information matrix.

    Between jumps the level is one constant (its wander is centimetres over a run), so its
    variance is the same at every keyframe of a level: it is solved exactly (a column of the
    inverse, ``H^-1 e_i``) at the middle of each level and held over it, and at each break
    (``level_breaks``: centres, half-widths), whose value (the peak: the level is free there)
    the keyframes around it take.  O(k (levels +
    jumps)) instead of a per-keyframe recursion.
    """
    k = factor.n
    jumps = np.asarray(breaks, dtype=np.int64)
    bounds = np.concatenate([[0], jumps, [k]])
    mids = (bounds[:-1] + bounds[1:]) // 2
    at = np.unique(np.clip(np.concatenate([mids, jumps]), 0, k - 1))
    E = np.zeros((3 * k, len(at)))
    E[3 * at + 2, np.arange(len(at))] = 1.0
    X = banded.solve(factor, E)
    exact = X[3 * at + 2, np.arange(len(at))]
    seg = np.searchsorted(jumps, np.arange(k), side="right")  # level of each keyframe
    var = np.empty(k)
    var[:] = exact[np.searchsorted(at, mids)][seg]
    for j, h in zip(jumps, half):  # where the level moves: its peak, at the break
        var[max(j - h, 0):j + h + 1] = exact[np.searchsorted(at, min(j, k - 1))]
    return np.maximum(var, 0.0)


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


def level_bias(kf_t_s, p_rep_m, g_m, edit_kf, edit_c_m, levels: GnssLevels, sigma_u: float, prior_sigma: float,
               held: DriftParams | None, d_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horizontal bias (k,2) such that g - bias = p~ + u - c (the level-corrected mean fix), the
    variance of the level (k,), and the location term's horizontal sigma (k,) (inf: no fix).
    ``d_m`` (m,3) the edit offsets (``edit_offsets``), which tell a live drag's moved edits."""
    y = p_rep_m[edit_kf, :2] - edit_c_m[:, :2]  # the pose's error at each edit
    if len(y) >= 3:
        sigma_e = max(float(np.sqrt(np.mean(0.5 * np.sum(y**2, axis=1)))), 1.0)
    else:
        sigma_e = prior_sigma
    u_single = (g_m - p_rep_m)[:, :2]
    prev = held.previous if held is not None else None
    if prev is not None and prev.loc_sigma_h_m is not None and len(prev.loc_sigma_h_m) == len(kf_t_s):
        return levels_near_new_edits(kf_t_s, levels, edit_kf, y, sigma_u, sigma_e, u_single, prev, d_m)
    c, _, var_c = solve_levels(kf_t_s, levels, edit_kf, y, sigma_u, sigma_e)
    info = open_sky_information(kf_t_s, c, var_c, *level_breaks(levels, ramp_keyframes(kf_t_s)))
    if np.any(info > 0):
        c, _, var_c = solve_levels(kf_t_s, levels, edit_kf, y, sigma_u, sigma_e, level_info=info)
    loc_sigma = np.where(levels.use, np.sqrt(levels.sigma_w_m**2 + var_c), np.inf)
    bias = np.where(levels.use[:, None], u_single - levels.u_m + c, 0.0)
    return bias, np.where(np.isfinite(loc_sigma), var_c, 0.0), loc_sigma


def levels_near_new_edits(kf_t_s, levels: GnssLevels, edit_kf, y, sigma_u, sigma_e, u_single, prev: DriftEstimate,
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
