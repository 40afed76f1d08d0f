"""Persistent steps of the GNSS against the locally rigid pose (urban-canyon offsets).

The reported pose keeps its local shape, so over a window of W keyframes (``STEP_WINDOW_S``)
its error hardly moves, while an urban-canyon offset switches on or off within seconds.
With u = g - p~ (k,2), a step at i is where ``median(u[i:i+W]) - median(u[i-W:i])`` exceeds
``n_sigma`` of its sigma ``1.2533 sigma_w sqrt(2 / W) sqrt 2`` and persists (the next
window's median agrees).  The edits then confirm a step only where the change of their
offsets between two edits, ``d_b - d_a``, matches the steps found in between within 3 sigma
(``steps_confirmed_by_edits``); an unconfirmed step still widens the bias variance of its
stretch by 9 |J|^2 (``suspect_intervals``).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

import numpy as np

from posefix.core.drift.base import MEDIAN_EFFICIENCY, keyframes_in, white_sigma

STEP_WINDOW_S = 30.0  # window for GNSS steps: the pose's error hardly moves in it, a canyon offset switches in seconds


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
