"""CRF feature functions. Each is one small function; the CRF score is their weighted sum.

Linear-chain CRF over vertex sequences ``y_0 .. y_T`` (``y_0`` the position before the
first step, ``y_t`` after step t)::

    p(y | x) ∝ exp( Σ_t [ Σ_j w_j f_j(y_{t-1}, y_t, x, t) + Σ_j w_j g_j(y_t, x, t) ] )

Transition features ``f_j`` depend on (y_{t-1}, y_t) only through the grid offset k with
``y_t = y_{t-1} + o_k``, so each is a ``(T, K)`` array; state features ``g_j`` are ``(V,)``
vectors at the steps that have an observation. Transitions that are not in the graph
(walls, too far) have probability zero, which is the "nothing when not connected" of f1.

Steps shorter than a cell and the grid quantisation. A 0.7 m step on a 0.8 m grid can
only be matched by 0 or 0.8 m moves; comparing each step with each move rounds every step
to the nearest move and stretches or shrinks a whole corridor by up to 15 %. We compare
moves with the *quantised increments* of the dead-reckoning track instead (error
diffusion: ``q_t = round(P_t / c)·c - round(P_{t-1} / c)·c`` with ``P_t`` the cumulative
step sum), whose sum equals the dead-reckoning displacement to within half a cell, so
the matched distance is unbiased.

f1 (heading and length, linearised): with the residual ``r = o_k·c - q_t`` expressed along
and across the step heading θ_t::

    f1 = -½ ( r_along² / σ_l² + r_across² / σ_⊥² ),   σ_⊥ = max(l_t·σ_θ, σ_l)

which is the Gaussian on length (σ_l, metres) and on heading (σ_θ, radians; a heading
error δθ moves the end of a step of length l sideways by l·δθ).

f2: f1 for the step rotated by the mean heading error over the last w steps of the most
likely path (its own quantised increments, same σ).

f3 (WiFi): ``-½ (p_v - μ)ᵀ Σ⁻¹ (p_v - μ)`` for the position (μ, Σ) a fingerprint map predicts.

f4 (RSSI peak): ``-½ |p_v - a|² / σ_a²`` when an access point's RSSI peaks at a step, with a
that access point's surveyed peak location and σ_a its spread.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "FeatureSigmas",
    "quantised_increments",
    "f_step",
    "heading_errors_from_path",
    "rotate_steps",
    "f_gaussian_position",
    "f_robust_position",
    "TRANSITION_FEATURES",
    "STATE_FEATURES",
    "FEATURE_NAMES",
]

TRANSITION_FEATURES = ("f1", "f2")
STATE_FEATURES = ("f3", "f4")
FEATURE_NAMES = TRANSITION_FEATURES + STATE_FEATURES


@dataclass(frozen=True)
class FeatureSigmas:
    """Noise scales of the features (physics, not tuned to a floor).

    ``len_m``: step length error per step (m); ``heading_rad``: heading error per step;
    ``window_steps``: w for f2; ``min_span_m``: the dead-reckoning span over those w steps
    below which no heading error is estimated (turning on the spot says nothing).
    """

    len_m: float = 0.35
    heading_rad: float = np.deg2rad(20.0)
    window_steps: int = 5
    min_span_m: float = 2.0


def quantised_increments(steps_xy_m: np.ndarray, cell_m: float) -> np.ndarray:
    """Error-diffused grid increments (T, 2), metres, of step vectors (T, 2) (module docstring)."""
    p = np.vstack([np.zeros((1, 2)), np.cumsum(np.asarray(steps_xy_m, dtype=float), axis=0)])
    q = np.round(p / cell_m) * cell_m
    return np.diff(q, axis=0)


def f_step(offsets_m: np.ndarray, steps_xy_m: np.ndarray, incr_xy_m: np.ndarray,
           sig: FeatureSigmas) -> np.ndarray:
    """f1 (or f2 for rotated steps): scores (T, K) of moves ``offsets_m`` (K, 2) per step.

    ``steps_xy_m`` (T, 2) give the heading and length; ``incr_xy_m`` (T, 2) the quantised
    increments the moves are compared with.
    """
    steps = np.asarray(steps_xy_m, dtype=float)
    l = np.linalg.norm(steps, axis=1)
    th = np.arctan2(steps[:, 1], steps[:, 0])
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]  # along-step unit vector (T, 1) each
    inc = np.asarray(incr_xy_m, dtype=float)
    rx = offsets_m[None, :, 0] - inc[:, 0:1]  # residual (T, K) east
    ry = offsets_m[None, :, 1] - inc[:, 1:2]  # and north
    r_a = rx * c + ry * s
    r_c = -rx * s + ry * c
    s_c = np.maximum(l * sig.heading_rad, sig.len_m)[:, None]
    return -0.5 * ((r_a / sig.len_m) ** 2 + (r_c / s_c) ** 2)


def heading_errors_from_path(path_xy_m: np.ndarray, steps_xy_m: np.ndarray, sig: FeatureSigmas) -> np.ndarray:
    """Mean heading error (T,) rad before each step t: angle of the path's displacement over
    steps t-w..t-1 minus that of the dead-reckoning steps over the same window.

    ``path_xy_m`` (T+1, 2) vertex positions of the most likely path (y_0..y_T). Where the
    window's dead-reckoning span is under ``min_span_m`` the previous estimate is kept.
    Causal: step t uses only y_a..y_t, the positions before it (as the online tracker has).
    """
    steps = np.asarray(steps_xy_m, dtype=float)
    t_n = steps.shape[0]
    out = np.zeros(t_n)
    w = sig.window_steps
    cum = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    prev = 0.0
    for t in range(t_n):
        a = max(0, t - w)
        if t - a >= 2:
            dr = cum[t] - cum[a]
            pp = path_xy_m[t] - path_xy_m[a]
            if np.linalg.norm(dr) >= sig.min_span_m and np.linalg.norm(pp) > 0:
                e = np.arctan2(pp[1], pp[0]) - np.arctan2(dr[1], dr[0])
                prev = float((e + np.pi) % (2 * np.pi) - np.pi)
        out[t] = prev
    return out


def rotate_steps(steps_xy_m: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rotate each step (T, 2) counter-clockwise by ``angle_rad`` (T,) or a scalar."""
    a = np.broadcast_to(np.asarray(angle_rad, dtype=float), (steps_xy_m.shape[0],))
    c, s = np.cos(a), np.sin(a)
    x, y = steps_xy_m[:, 0], steps_xy_m[:, 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=1)


def f_gaussian_position(p_xy_m: np.ndarray, mean_xy_m: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """f3/f4: ``-½ (p - μ)ᵀ Σ⁻¹ (p - μ)`` for vertex positions (V, 2); μ (2,), Σ (2, 2) m²."""
    p = np.asarray(p_xy_m, dtype=float)
    mu = np.asarray(mean_xy_m, dtype=float)
    inv = np.linalg.inv(np.asarray(cov_m2, dtype=float))
    dx, dy = p[:, 0] - mu[0], p[:, 1] - mu[1]
    # The 2×2 quadratic form written out: a generic einsum is ~5x slower on (V, 2).
    return -0.5 * (inv[0, 0] * dx * dx + (inv[0, 1] + inv[1, 0]) * dx * dy + inv[1, 1] * dy * dy)


def f_robust_position(p_xy_m: np.ndarray, mean_xy_m: np.ndarray, cov_m2: np.ndarray, outlier_frac: float,
                      cell_m: float) -> np.ndarray:
    """f3 with outliers: ``log((1 - ε)·c²·N(p; μ, Σ) + ε / V)`` for vertex positions (V, 2).

    The prediction is right (Gaussian, the vertex's probability mass c²·N) with probability
    1 - ε, or points anywhere (uniform over the V vertices) with probability ε — a WiFi scan
    that matches the wrong wing. ε = 0 gives f_gaussian_position up to a constant.
    """
    p = np.asarray(p_xy_m, dtype=float)
    cov = np.asarray(cov_m2, dtype=float)
    g = f_gaussian_position(p, mean_xy_m, cov) + np.log(cell_m**2 / (2.0 * np.pi * np.sqrt(np.linalg.det(cov))))
    if outlier_frac <= 0.0:
        return g
    return np.logaddexp(np.log1p(-outlier_frac) + g, np.log(outlier_frac / p.shape[0]))
