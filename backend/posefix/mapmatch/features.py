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

f3 and f4 are weighted by the share of new evidence an observation carries given the
previous one of its kind (:func:`evidence_share`): WiFi errors are correlated in time,
so scans seconds apart are nearly one observation, not several.
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
    "evidence_share",
    "evidence_shares",
    "capped_information",
    "WIFI_CORR_S",
    "TRANSITION_FEATURES",
    "STATE_FEATURES",
    "FEATURE_NAMES",
]

TRANSITION_FEATURES = ("f1", "f2")
STATE_FEATURES = ("f3", "f4")
FEATURE_NAMES = TRANSITION_FEATURES + STATE_FEATURES

# Correlation time (s) of WiFi position errors (f3 and f4), the τ of evidence_share. A WiFi
# fix errs by what the place's radio environment looks like: which access points are heard,
# how walls, shelves and people shadow them, which surveyed fingerprints they resemble; and
# by the device and body (phone model, hand or pocket, facing), which last the whole walk.
# The place part changes when the set of strongest access points changes, about one
# access-point spacing (15-25 m in office and mall deployments, designed for -67 dBm
# cells of ~10 m radius), which a pedestrian at 1.0-1.4 m/s covers in 10-25 s. τ = 20 s:
# a walk then carries one independent fix per 2τ = 40 s, however often the phone scans.
# (Measured afterwards on site1/F1, not fitted: two held-out scans' k-NN error vectors
# correlate 0.78 under 5 s apart, 0.58 at 10-20 s and 0.48 at 20-40 s, RSSI-peak (f4)
# errors about 0.5 throughout; the device part keeps them from falling to 0, so with
# 20 s a long walk's scans still count as more independent than they are.)
WIFI_CORR_S = 20.0


@dataclass(frozen=True)
class FeatureSigmas:
    """Noise scales of the features (physics, not tuned to a floor).

    ``len_m``: step length error per step (m); ``heading_rad``: heading error per step;
    ``window_steps``: w for f2; ``min_span_m``: the dead-reckoning span over those w steps
    below which no heading error is estimated (turning on the spot says nothing);
    ``wifi_corr_s``: correlation time τ (s) of WiFi errors (f3, f4; :data:`WIFI_CORR_S`
    says why 20 s), 0 = every scan independent (the behaviour before the discount).
    """

    len_m: float = 0.35
    heading_rad: float = np.deg2rad(20.0)
    window_steps: int = 5
    min_span_m: float = 2.0
    wifi_corr_s: float = WIFI_CORR_S


def evidence_share(dt_s: float | None, tau_s: float) -> float:
    """Share (0..1] of an observation's evidence that is new, ``(1 - ρ) / (1 + ρ)`` with
    ``ρ = exp(-|Δt| / τ)``, given the previous observation of the same kind ``dt_s`` seconds
    earlier (None: there was none, share 1); ``tau_s`` = 0: independent observations, share 1.

    Model: the observation errors are an Ornstein-Uhlenbeck (continuous AR(1)) process of
    variance σ² and correlation ρ(Δt) = e^{-Δt/τ}. It is Markov, so given the previous
    observation x_{i-1} the innovation ``x_i - ρ_i x_{i-1}`` is all that is new: it has
    mean (1 - ρ_i)·μ and variance (1 - ρ_i²)·σ², and so carries (1 - ρ_i)/(1 + ρ_i) of one
    independent observation's Fisher information 1/σ² about the position μ. Summed over a
    sequence this is exactly the generalised-least-squares information 1ᵀC⁻¹1 of the
    correlated observations (unit test), e.g. 1 + (n - 1)(1 - ρ)/(1 + ρ) for n at equal
    spacing, and tends to 1 + T/(2τ) over a span T scanned densely. Each f3/f4 score is
    multiplied by its share: the marginal Gaussian of a scan tempered to the information
    it adds (its total information is exact for a walker standing still; when moving it is a
    composite likelihood that keeps the chain linear — the exact conditional density would
    couple y_t with the previous scan's y_{t-k}).
    """
    if dt_s is None or tau_s <= 0.0:
        return 1.0
    rho = float(np.exp(-abs(float(dt_s)) / tau_s))
    return (1.0 - rho) / (1.0 + rho)


def capped_information(n_eff: float, rho_walk: float) -> float:
    """Information (in independent observations) of ``n_eff`` observations whose errors also
    share a part that lasts the whole walk, with correlation ``rho_walk`` between any two:
    ``n / (1 + (n - 1)·ρ)`` (the generalised-least-squares information 1ᵀC⁻¹1 of n equally
    correlated observations) for n ≥ 1, n below 1. It never exceeds 1/ρ: however long a walk
    is scanned, an error the whole walk shares (the phone, the body, a route the survey
    did not cover) is not averaged away. ρ = 0: n."""
    n = float(n_eff)
    if rho_walk <= 0.0 or n <= 1.0:
        return n
    return n / (1.0 + (n - 1.0) * float(rho_walk))


def evidence_shares(t_s: np.ndarray, tau_s: float) -> np.ndarray:
    """:func:`evidence_share` (n,) of each of a time-ordered sequence of observations at ``t_s`` (n,) s."""
    t = np.asarray(t_s, dtype=float)
    return np.array([evidence_share(None if i == 0 else t[i] - t[i - 1], tau_s) for i in range(t.size)])


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
