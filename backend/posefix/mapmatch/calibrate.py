"""Per-walk self-calibration of the motion model: EM inside the walk.

A walker and phone differ from the model's step length and heading bias by a step-length
scale k and a heading offset δ (stride, how the phone is held, the building's magnetic
deviation). In complex notation a step z_i = x_i + i·y_i (floor frame) becomes

    z_i' = a · z_i,    a = k · e^{iδ}

E-step: the smoothed posterior means p̂_t of the walk under the current steps (the map,
and WiFi when there is any, decide where the walk went). M-step: the a that best maps the
dead-reckoning displacement of each window j of ``window_steps`` steps, D_j = Σ_{i∈j} z_i,
onto the posterior's, P_j = p̂_{end j} − p̂_{start j}, with a Gaussian prior around 1
(isotropic, σ_a: 5 % of scale and 0.05 rad of heading):

    â = (Σ_j conj(D_j)·P_j / σ_j² + 1/σ_a²) / (Σ_j |D_j|² / σ_j² + 1/σ_a²),
    σ_j² = n_j·σ_l² + 2·c²/6     (the steps' own noise, and both ends' grid quantisation)

the maximum a posteriori of P_j = a·D_j + noise. Only windows whose both ends have
converged (one mode of the posterior holding ≥ 95 %: :mod:`posefix.mapmatch.modes`) take
part: elsewhere the mean lies between places and says nothing about the walk's steps.
Repeat with the corrected steps (``iterations``). With fewer than ``min_windows`` usable
windows the prior wins (a = 1).
"""

from __future__ import annotations

import numpy as np

__all__ = ["estimate_step_correction", "apply_step_correction"]

# Prior σ of a around 1 when the walk's heading spread is not given (track_walk with an unknown
# start): heading ±0.05 rad (2.9°). With a known start track_walk passes the model's measured
# spread of the walks' own offsets (learn.learn_walk_spread: 10.1° on site1/F1, 7.4° on
# site2/F2), which it also marginalises: on the held-out walks, known start, mean / p95 went
# 1.72 / 4.15 -> 1.70 / 4.01 m (site1) and 1.30 / 3.22 -> 1.28 / 2.83 m (site2), crosswise
# 1.66 / 4.30 -> 1.60 / 3.79 and 1.25 / 3.49 -> 1.17 / 3.06 m; on site1's tuning walks
# 1.31 / 2.55 -> 1.41 / 3.01 m (a walk's own posterior, which the offset shapes, can pull it
# off). The step-length part of a, applied too, gave 1.35 / 2.62 m on those: not applied.
SIGMA_A = 0.05


def estimate_step_correction(steps_xy_m: np.ndarray, p_xy_m: np.ndarray, converged: np.ndarray, cell_m: float,
                             sigma_len_m: float, window_steps: int = 8, min_windows: int = 2,
                             sigma_a: float = SIGMA_A, min_straightness: float = 0.95) -> complex:
    """MAP a = k·e^{iδ} (module docstring) from step vectors (T, 2), the posterior means
    (T+1, 2) of the positions before/after them and each row's ``converged`` (T+1,)."""
    z = np.asarray(steps_xy_m, dtype=float) @ np.array([1.0, 1j])
    p = np.asarray(p_xy_m, dtype=float) @ np.array([1.0, 1j])
    ok = np.asarray(converged, dtype=bool)
    t_n = z.size
    num, den, used = 0j, 0.0, 0
    for a in range(0, t_n - window_steps // 2, window_steps):
        b = min(a + window_steps, t_n)
        if not (ok[a] and ok[b]):
            continue
        d = z[a:b].sum()
        if abs(d) < min_straightness * np.abs(z[a:b]).sum():
            continue  # a turn inside: the posterior mean cuts the corner, so the span would read short
        var = (b - a) * sigma_len_m**2 + 2.0 * cell_m**2 / 6.0
        num += np.conj(d) * (p[b] - p[a]) / var
        den += abs(d) ** 2 / var
        used += 1
    if used < min_windows:
        return 1.0 + 0j
    prior = 1.0 / sigma_a**2
    return complex((num + prior) / (den + prior))


def apply_step_correction(steps_xy_m: np.ndarray, a: complex) -> np.ndarray:
    """Steps (T, 2) scaled by |a| and turned by arg a."""
    z = (np.asarray(steps_xy_m, dtype=float) @ np.array([1.0, 1j])) * a
    return np.column_stack([z.real, z.imag])
