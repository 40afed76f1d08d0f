"""The drift estimate: the bias model, the GNSS steps and the GNSS levels put together.

The location term of keyframe i is re-centred on ``g_i - b_i`` and its horizontal sigma
inflated to ``sqrt(sigma_w^2 + var_b,i)``: where edits show drift the term is down-weighted
(between edits, where the bias is uncertain) and no longer biased, so hundreds of weak,
correlated fixes cannot pull the run back onto a biased track.  With no drift detected
(median offset within 3 sigma of the noise of edits and fixes, no wander beyond it, and all
offsets together within the 99 % point of their chi-square) the term is left exactly as it
was; far from any edit the model returns to the unbiased prior, so the pull of one edit
fades with distance.  The weight on the location term's information is
``sigma_w^2 / (sigma_w^2 + var_b,i)`` (or ``sigma_w^2 / sigma_loc,i^2`` under the level model).

Persistent GNSS steps the edits confirm (``steps``) are taken out of the offsets first and
added back after; a pose that bridged the steps hands the bias to the level model (``levels``).
Vertical: only 3-D edits observe the vertical bias; without them the vertical is left alone.
"""

from __future__ import annotations

import numpy as np

from posefix.core.drift.base import MEDIAN_EFFICIENCY, DriftEstimate, DriftParams, edit_offsets, no_drift
from posefix.core.drift.bias import MAX_TAU_S, MIN_TAU_S, bias_at, estimate_walk, local_walk, smooth_gauss_markov
from posefix.core.drift.levels import GnssLevels, level_bias
from posefix.core.drift.steps import GnssSteps, gnss_steps, step_window, steps_confirmed_by_edits, suspect_intervals
from posefix.core.filters import chi2_upper_quantile


def estimate_drift(
    kf_t_s: np.ndarray,
    p_rep_m: np.ndarray,
    g_m: np.ndarray,
    edit_kf: np.ndarray,
    edit_c_m: np.ndarray,
    edit_has_alt: np.ndarray,
    sigma_w_h_m: float,
    sigma_w_v_m: float,
    sigma_u_h_m: float | np.ndarray,
    sigma_u_v_m: float,
    prior_sigma_m: float,
    prior_tau_s: float,
    min_edits_for_estimate: int = 3,
    window: int = 5,
    held: DriftParams | None = None,
    steps: GnssSteps | None = None,
    levels=None,
) -> DriftEstimate:
    """Fit the bias model to the edits; see the module docstring.

    kf_t_s (k,), p_rep_m (k,3) reported keyframe positions, g_m (k,3) location measurements
    (NaN where none), edit_kf (m,) keyframe of each edit, edit_c_m (m,3) edit targets
    (vertical ignored where ``edit_has_alt`` is False), ``sigma_u_h_m`` their horizontal
    1-sigma (one for all, or (m,) per edit).  ``held`` (``DriftParams``) holds the
    model's parameters (a live drag re-uses those of the last solve so one more edit changes
    the bias only around it; its ``previous`` estimate keeps its GNSS levels).  ``steps``
    passes the result of ``gnss_steps`` when the caller keeps it between solves (it depends on
    the run only).  ``levels`` (``gnss_levels``, also the run's only, or a function returning
    it when needed) enables the level model where
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
    if np.ndim(sigma_u_h_m):  # each edit its own sigma: the tests that take one noise take the typical one
        noise_h = np.asarray(sigma_u_h_m, dtype=float)[order] ** 2 + (MEDIAN_EFFICIENCY * sigma_w_h_m) ** 2 / n_win
        noise0 = float(np.mean(noise_h))
        sigma_u_h_m = float(np.sqrt(np.mean(np.asarray(sigma_u_h_m, dtype=float) ** 2)))
    else:
        noise_h = np.full(len(t_e), sigma_u_h_m**2 + (MEDIAN_EFFICIENCY * sigma_w_h_m) ** 2 / n_win)
        noise0 = noise_h[0]
    noise_v = np.full(len(t_e), sigma_u_v_m**2 + (MEDIAN_EFFICIENCY * sigma_w_v_m) ** 2 / n_win)
    # persistent GNSS steps (urban-canyon offsets switching on and off) are taken out of the
    # offsets first; the Gauss-Markov model then describes what is left
    if steps is None:
        steps = gnss_steps((g_m - p_rep_m)[:, :2], window=step_window(kf_t_s))
    all_steps = steps
    steps = steps_confirmed_by_edits(steps, edit_kf, d[:, :2], noise0, k)
    d[:, :2] -= steps.level_m[edit_kf]
    suspect = suspect_intervals(all_steps, steps, edit_kf, k)
    if held is not None:
        sigma2, tau = held.sigma2_m2, held.tau_s
        q = 2.0 * sigma2 / tau
    elif len(t_e) >= max(min_edits_for_estimate, 2):
        q = max(estimate_walk(t_e, d[:, :2], noise_h), 1e-6)
        sigma2 = max(float(np.mean(0.5 * np.sum(d[:, :2] ** 2, axis=1) - noise_h)), 1e-4)
        tau = float(np.clip(2.0 * sigma2 / q, MIN_TAU_S, MAX_TAU_S))
    else:
        sigma2, tau = prior_sigma_m**2, prior_tau_s
        q = 2.0 * sigma2 / tau
    prior = held is None and len(t_e) < max(min_edits_for_estimate, 2)
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
    typical_dt = float(np.median(np.diff(t_e))) if len(t_e) > 1 else float(kf_t_s[-1] - kf_t_s[0])
    median_sigma = MEDIAN_EFFICIENCY * np.sqrt(2.0 * noise0 / len(t_e))
    together = float(np.sum(np.sum(d[:, :2] ** 2, axis=1) / noise_h))
    detected = bool(np.hypot(offset[0], offset[1]) > 3.0 * median_sigma or q * typical_dt > 2.0 * noise0
                    or together > chi2_upper_quantile(2 * len(t_e), 0.01))
    if held is not None:
        detected = held.detected
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
    if prior:
        # the stated prior (too few edits to estimate the model or confirm a step): away from the
        # edits the run is left as without them, so the doubt about the fixes fades with the
        # correlation to the nearest edit (otherwise sigma_b, or a step no edit can confirm, would
        # soften every fix of the run, and one edit move all of it)
        near = np.min(np.abs(kf_t_s[:, None] - t_e[None, :]), axis=1)
        var_h = var_h * np.exp(-near / tau)
    loc_sigma = None
    if callable(levels) and len(all_steps.index):
        levels = levels()  # found from every sample once per run: only when the fix shows persistent steps
    if isinstance(levels, GnssLevels) and len(all_steps.index) and levels.bridged:
        # the fix steps persistently against the pose, and the pose bridged every large step
        bias[:, :2], var_h, loc_sigma = level_bias(kf_t_s, p_rep_m, g_m, edit_kf, edit_c_m, levels, sigma_u_h_m,
                                                    prior_sigma_m, held, d)
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
