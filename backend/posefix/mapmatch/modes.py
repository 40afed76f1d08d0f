"""Modes of a position posterior, and whether it has converged on one.

A marginal p(y_t = v) over the graph's vertices is summarised by its mean and covariance
(:func:`posefix.mapmatch.viterbi.gaussian_summary`), which is honest only when the
distribution is one blob. With an unknown start it is often several: the same walk shape
fits several corridors. The modes are found on a coarse grid of ``bin_m`` cells, anchored
at the lowest x and y of all the vertices (so a vertex keeps its bin from step to step):

    m_b = Σ_{v in bin b} p(v)                           (mass per bin, in vertex order)
    S   = the fewest bins holding ``support`` of the mass (by mass, descending; ties: lower
          bin index first, bins numbered row by row)
    modes = connected components of S dilated by one bin (8-neighbours): bins of S at most
            three bins apart along each axis (gaps of up to two empty bins) are one mode
    mode j: mass M_j = Σ_{v in a bin of S in j} p(v), mean μ_j = Σ p(v) p_v / M_j
    counted modes: M_j ≥ ``min_mass`` (at least the largest), by mass descending (ties: the
          mode whose first bin comes first)

The posterior has **converged** when

    (1) its largest mode holds at least ``converged_mass`` of the probability, and
    (2) the whole posterior's 1σ major semi-axis σ = √λ_max(Σ_v p(v)(p_v − μ)(p_v − μ)ᵀ) is
        at most ``converged_sigma_m``.

(1) says the posterior is one place; (2) that this place is small, and it bounds what the
rest of the mass can do to the reported estimate, which is the Gaussian summary of the
*whole* posterior (its mean and 2σ ellipse): mass ε outside the main mode, at distance d
from it, adds ε(1 − ε)d² to the variance along that direction, so (2) caps d at
σ/√(ε(1 − ε)) and the pull on the mean, εd, at σ√(ε/(1 − ε)) ≤ 0.23σ for ε ≤ 5 %. A
converged estimate is therefore within a quarter of its stated 1σ of the main mode's mean,
and its ellipse is at most 4σ = 20 m across. (A posterior spread over one connected floor is
one component, but (2) fails: nowhere in particular.) Otherwise the answer is "one of these
places", and a single ellipse (or the mean, which may fall between them) must not be
reported as a position fix. ``spread_m`` is the largest distance from the main mode's mean
to another counted mode's.

The browser tracker (frontend/src/tracker/modes.ts) implements this definition exactly; the
parity test compares both on the same walks (tests/vectors/tracker_parity.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Modes", "posterior_modes", "CONVERGED_MASS", "CONVERGED_SIGMA_M"]

# A 2-D Gaussian's 2σ ellipse holds 86 % of it; when the main mode holds 95 % the rest can
# cost at most 5 points of the ellipse's coverage, and a 5 % chance of being elsewhere is
# what a user reading "converged" would accept.
CONVERGED_MASS = 0.95
# A place, not a wing: a 2σ ellipse of at most 20 m across (corridor junctions and shop
# fronts are 5-10 m apart; beyond this the answer is "somewhere along here").
CONVERGED_SIGMA_M = 5.0


@dataclass(frozen=True)
class Modes:
    """``n``: counted modes; ``mass`` (n,) descending; ``mean_xy_m`` (n, 2); ``spread_m``:
    farthest counted mode from the main one (0 with one); ``sigma_major_m``: the whole
    posterior's 1σ major semi-axis (m); ``converged``: (1) and (2) of the module docstring."""

    n: int
    mass: np.ndarray
    mean_xy_m: np.ndarray
    spread_m: float
    sigma_major_m: float
    converged: bool


def _bins(p_xy_m: np.ndarray, bin_m: float) -> tuple[np.ndarray, tuple[int, int]]:
    lo = p_xy_m.min(axis=0)
    ij = np.floor((p_xy_m - lo) / bin_m).astype(np.int64)
    shape = (int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1)
    return ij[:, 1] * shape[1] + ij[:, 0], shape


def _sigma_major(p: np.ndarray, w: np.ndarray) -> float:
    """1σ major semi-axis (m) of the weights ``w`` (sum 1) over positions ``p``."""
    mean = w @ p
    d = p - mean
    cov = (d * w[:, None]).T @ d
    tr, det = cov[0, 0] + cov[1, 1], cov[0, 0] * cov[1, 1] - cov[0, 1] * cov[1, 0]
    return float(np.sqrt(max(tr / 2 + np.sqrt(max(tr * tr / 4 - det, 0.0)), 0.0)))


def posterior_modes(p_xy_m: np.ndarray, prob: np.ndarray, bin_m: float = 2.0, support: float = 0.995,
                    min_mass: float = 0.01, converged_mass: float = CONVERGED_MASS,
                    converged_sigma_m: float = CONVERGED_SIGMA_M) -> Modes:
    """Modes (module docstring) of a distribution ``prob`` (V,) (need not be normalised) over
    vertex positions ``p_xy_m`` (V, 2)."""
    from scipy import ndimage

    w = np.nan_to_num(np.asarray(prob, dtype=float), nan=0.0, posinf=0.0, neginf=0.0)
    w = np.maximum(w, 0.0)
    total = float(w.sum())
    if total <= 0.0:
        raise ValueError("posterior_modes: the distribution has no mass")
    w = w / total
    live = np.nonzero(w > 0.0)[0]
    p, wl = p_xy_m[live], w[live]
    bin_all, shape = _bins(p_xy_m, bin_m)
    bin_id = bin_all[live]
    m = np.bincount(bin_id, weights=wl, minlength=shape[0] * shape[1])
    order = np.lexsort((np.arange(m.size), -m))
    k = int(np.searchsorted(np.cumsum(m[order]), support)) + 1
    keep = np.zeros(m.size, bool)
    keep[order[:k]] = True
    grid = keep.reshape(shape)
    labels, n_lab = ndimage.label(ndimage.binary_dilation(grid, structure=np.ones((3, 3), bool)),
                                  structure=np.ones((3, 3), bool))
    lab_v = labels.ravel()[bin_id] * keep[bin_id]  # 0 = outside the support
    mass = np.bincount(lab_v, weights=wl, minlength=n_lab + 1)[1:]
    sx = np.bincount(lab_v, weights=wl * p[:, 0], minlength=n_lab + 1)[1:]
    sy = np.bincount(lab_v, weights=wl * p[:, 1], minlength=n_lab + 1)[1:]
    sel = np.nonzero(mass >= min_mass)[0]
    if sel.size == 0:  # mass spread thinner than min_mass everywhere: count the largest
        sel = np.array([int(np.argmax(mass))])
    sel = sel[np.argsort(-mass[sel], kind="stable")]
    means = np.column_stack([sx[sel] / mass[sel], sy[sel] / mass[sel]])
    spread = float(np.max(np.linalg.norm(means - means[0], axis=1))) if sel.size > 1 else 0.0
    sigma = _sigma_major(p, wl)
    return Modes(n=int(sel.size), mass=mass[sel], mean_xy_m=means, spread_m=spread, sigma_major_m=sigma,
                 converged=bool(mass[sel[0]] >= converged_mass and sigma <= converged_sigma_m))
