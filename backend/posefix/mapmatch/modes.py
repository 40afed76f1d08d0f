"""Modes of a position posterior, and whether it has converged on one.

A marginal p(y_t = v) over the graph's vertices is summarised by its mean and covariance
(:func:`posefix.mapmatch.viterbi.gaussian_summary`), which is honest only when the
distribution is one blob. With an unknown start it is often several: the same walk shape
fits several corridors. The modes are found on a coarse grid of ``bin_m`` cells:

    m_b = Σ_{v in bin b} p(v)                           (mass per bin)
    S   = the fewest bins holding ``support`` of the mass (largest first)
    modes = connected components of S dilated by one bin (8-neighbours), so blobs less
            than about two bins apart are one mode
    mode j: mass M_j = Σ_{v in j} p(v), mean μ_j = Σ p(v) p_v / M_j, covariance likewise

The posterior has **converged** when its largest mode holds at least ``converged_mass``
of the probability and is compact (its 1σ major semi-axis at most ``converged_sigma_m``;
a posterior spread over one connected floor is one component, not a place): the Gaussian summary then describes where the walker is, and its
ellipse can be read as a confidence region. Otherwise the answer is "one of these places",
and a single ellipse (or the mean, which may fall between them) must not be reported as
a position fix. ``spread_m`` is the largest distance from the main mode's mean to another
counted mode's (modes under ``min_mass`` are not counted).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Modes", "posterior_modes", "CONVERGED_MASS"]

# A 2-D Gaussian's 2σ ellipse holds 86 % of it; when the main mode holds 95 % the rest can
# cost at most 5 points of the ellipse's coverage, and a 5 % chance of being elsewhere is
# what a user reading "converged" would accept.
CONVERGED_MASS = 0.95
# A place, not a wing: a 2σ ellipse of at most 20 m across (corridor junctions and shop
# fronts are 5-10 m apart; beyond this the answer is "somewhere along here").
CONVERGED_SIGMA_M = 5.0


@dataclass(frozen=True)
class Modes:
    """``n``: modes holding ≥ ``min_mass`` each; ``mass`` (n,) descending; ``mean_xy_m`` (n, 2);
    ``spread_m``: farthest counted mode from the main one (0 with one); ``converged``:
    the main mode holds ≥ the converged mass."""

    n: int
    mass: np.ndarray
    mean_xy_m: np.ndarray
    spread_m: float
    converged: bool


def _bins(p_xy_m: np.ndarray, bin_m: float) -> tuple[np.ndarray, tuple[int, int]]:
    lo = p_xy_m.min(axis=0)
    ij = np.floor((p_xy_m - lo) / bin_m).astype(np.int64)
    shape = (int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1)
    return ij[:, 1] * shape[1] + ij[:, 0], shape


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
    bin_id, shape = _bins(p, bin_m)
    m = np.bincount(bin_id, weights=wl, minlength=shape[0] * shape[1])
    order = np.argsort(m)[::-1]
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
    sel = sel[np.argsort(mass[sel])[::-1]]
    means = np.column_stack([sx[sel] / mass[sel], sy[sel] / mass[sel]])
    spread = float(np.max(np.linalg.norm(means - means[0], axis=1))) if sel.size > 1 else 0.0
    main = lab_v == sel[0] + 1
    wm = wl[main] / mass[sel[0]]
    d = p[main] - means[0]
    cov = (d * wm[:, None]).T @ d
    sigma_major = float(np.sqrt(max(np.linalg.eigvalsh(cov)[-1], 0.0)))
    return Modes(n=int(sel.size), mass=mass[sel], mean_xy_m=means, spread_m=spread,
                 converged=bool(mass[sel[0]] >= converged_mass and sigma_major <= converged_sigma_m))
