"""Learning the CRF weights, the step constants and the heading bias from surveyed walks.

Weights — conditional log-likelihood with partially observed states. A training walk has
its position known only at its waypoints. Let ``C`` be the set of vertex sequences that,
at the step nearest each waypoint's time, lie within ``clamp_m`` of it. With linear
scores ``s_w(y) = Σ_j w_j F_j(y)``::

    L(w) = log Σ_{y ∈ C} exp s_w(y)  -  log Σ_y exp s_w(y)  -  ½ |w - w0|² / σ_w²
    ∂L/∂w_j = E_{p(y | x, C)}[F_j] - E_{p(y | x)}[F_j] - (w_j - w0_j) / σ_w²

Both expectations come from :func:`posefix.mapmatch.viterbi.forward_backward` (the clamped
one with -inf state scores outside C); scipy's L-BFGS-B maximises L with w ≥ 0. When every
step is clamped to one vertex this is the ordinary fully observed CRF likelihood.

Step constants — hard EM with the heading-only feature (the patent's recipe): E-step,
the most likely path under f1 with its along-step (length) term switched off, so where the
walker went is decided by headings and walls alone; M-step, least squares of the model's
summed step lengths against the path's straight-line spans over windows of straight
walking between turns, the last one left out (``l = h (α f + β) + γ`` is linear in α, β, γ).
Repeat. The basin of attraction is about ±0.2 m of γ around the truth (tested on a
simulated serpentine): start from the physical default, not from an arbitrary value.

Heading bias — circular mean, weighted by length, of the angle between each waypoint-to-
waypoint displacement and the dead-reckoning displacement over the same time span.

Step-length scale — over the same waypoint-to-waypoint segments, the ratio of sums
``s = Σ |Δp_waypoints| / Σ |Δp_dead_reckoning|``, applied as ``h ← s·h``, ``γ ← s·γ`` (so
every step length is multiplied by s). The straight line between two waypoints is never
longer than the path walked, so s is, if anything, an underestimate of the true scale.
On site1/F1 the default step model is short by 6–8 % (s = 1.079 and 1.064 on the two
halves of the walks); unlike the hard-EM γ this needs no walls, only waypoints.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize

from posefix.mapmatch.features import (FEATURE_NAMES, FeatureSigmas, f_gaussian_position, f_step,
                                       heading_errors_from_path, quantised_increments, rotate_steps)
from posefix.mapmatch.sensors import StepModel, Steps, Walk, steps_from_walk
from posefix.mapmatch.tracker import start_log_prior
from posefix.mapmatch.viterbi import forward_backward, viterbi

__all__ = [
    "learn_step_scale",
    "learn_walk_spread",
    "WalkFeatures",
    "walk_features",
    "clamp_states",
    "learn_weights",
    "learn_step_constants",
    "learn_heading_bias",
    "WeightFit",
]


@dataclass
class WalkFeatures:
    """Raw (unweighted) features of one walk on one graph.

    ``F`` maps f1, f2 -> (T, K) arrays and f3, f4 -> lists of T entries, each (V,) or None.
    ``log_prior`` (V,); ``t_ms`` (T+1,) with the walk start first.
    """

    F: dict
    log_prior: np.ndarray
    t_ms: np.ndarray

    @property
    def n_steps(self) -> int:
        return int(self.F["f1"].shape[0])

    def scores(self, w: dict[str, float]) -> tuple[np.ndarray, list]:
        trans = w["f1"] * self.F["f1"] + w["f2"] * self.F["f2"]
        state = []
        for t in range(self.n_steps):
            s = None
            for name in ("f3", "f4"):
                f = self.F[name][t]
                if f is not None and w[name] != 0.0:
                    s = w[name] * f if s is None else s + w[name] * f
            state.append(s)
        return trans, state


def walk_features(model, steps_xy_m: np.ndarray, t_ms: np.ndarray, start_xy_m=None,
                  wifi: dict | None = None, peaks: dict | None = None) -> WalkFeatures:
    """Features of a walk given its step vectors (T, 2) m (bias applied) and times (T+1,).

    f2 uses the heading errors of the most likely path under the model's current weights
    without f2 (one Viterbi pass), then is held fixed, as the tracker would have seen it.
    ``wifi``/``peaks``: {step index: (mean, cov)} / {step index: (xy, sigma_m)}.
    """
    g = model.graph
    sig: FeatureSigmas = model.sigmas
    off = g.offsets_m
    steps = np.asarray(steps_xy_m, dtype=float)
    f1 = f_step(off, steps, quantised_increments(steps, g.cell_m), sig)
    p = g.p_xy_m
    f3 = [None] * len(steps)
    f4 = [None] * len(steps)
    for i, (mu, cov) in (wifi or {}).items():
        f3[i] = f_gaussian_position(p, mu, cov)
    for i, (xy, s) in (peaks or {}).items():
        f4[i] = f_gaussian_position(p, xy, np.eye(2) * s**2)
    prior = start_log_prior(p, start_xy_m)
    wf = WalkFeatures(F={"f1": f1, "f2": np.zeros_like(f1), "f3": f3, "f4": f4}, log_prior=prior,
                      t_ms=np.asarray(t_ms))
    if len(steps) >= 2:
        w0 = dict(model.weights, f2=0.0, f1=max(model.weights["f1"], 1e-3))
        trans, state = wf.scores(w0)
        path, _ = viterbi(g, prior, trans, state, beam=model.beam)
        err = heading_errors_from_path(p[path], steps, sig)
        s2 = rotate_steps(steps, err)
        wf.F["f2"] = f_step(off, s2, quantised_increments(s2, g.cell_m), sig)
    return wf


def clamp_states(graph, t_ms: np.ndarray, waypoints: np.ndarray, clamp_m: float = 2.0) -> list:
    """Clamp scores (T entries, (V,) of 0 / -inf or None) keeping y_t within ``clamp_m`` of
    each waypoint at the step nearest its time (index into y_1..y_T)."""
    t_n = len(t_ms) - 1
    out: list = [None] * t_n
    p = graph.p_xy_m
    for t_w, x, y in np.asarray(waypoints, dtype=float):
        i = int(np.argmin(np.abs(np.asarray(t_ms[1:], dtype=float) - t_w)))
        d = np.hypot(p[:, 0] - x, p[:, 1] - y)
        r = max(clamp_m, float(d.min()) + 1e-6)
        c = np.where(d <= r, 0.0, -np.inf)
        # Two waypoints at the same step: either may hold (union of the two discs).
        out[i] = c if out[i] is None else np.maximum(out[i], c)
    return out


@dataclass(frozen=True)
class WeightFit:
    weights: dict[str, float]
    log_likelihood: float
    iterations: int
    message: str


def _expectations(graph, wf: WalkFeatures, w: dict, extra_state: list | None, beam):
    trans, state = wf.scores(w)
    if extra_state is not None:
        state = [a if b is None else (b if a is None else a + b) for a, b in zip(state, extra_state)]
    fb = forward_backward(graph, wf.log_prior, trans, state, beam=beam)
    e = {"f1": float(np.sum(fb.xi_k * wf.F["f1"])), "f2": float(np.sum(fb.xi_k * wf.F["f2"]))}
    for name in ("f3", "f4"):
        e[name] = float(sum(np.sum(fb.gamma[t + 1] * np.nan_to_num(f, neginf=0.0))
                            for t, f in enumerate(wf.F[name]) if f is not None))
    return fb.log_z, e


def learn_weights(model, data: list[tuple[WalkFeatures, list]], learn: tuple[str, ...] = FEATURE_NAMES,
                  sigma_w: float = 3.0, max_iter: int = 30, beam: float | None = 40.0) -> WeightFit:
    """Maximise the clamped conditional log-likelihood over ``data`` = [(features, clamp)].

    ``learn``: which weights are free (others stay at the model's values); ``sigma_w``:
    the Gaussian prior width around the starting weights (keeps unused features put).
    """
    g = model.graph
    w0 = dict(model.weights)
    names = [n for n in FEATURE_NAMES if n in learn]
    x0 = np.array([w0[n] for n in names])

    def negll(x: np.ndarray):
        w = dict(w0, **dict(zip(names, x)))
        ll, grad = 0.0, np.zeros(len(names))
        for wf, clamp in data:
            try:
                lz_c, e_c = _expectations(g, wf, w, clamp, beam)
            except ValueError:
                continue  # the clamp is unreachable under this graph (bad survey point)
            lz, e = _expectations(g, wf, w, None, beam)
            ll += lz_c - lz
            grad += np.array([e_c[n] - e[n] for n in names])
        ll -= 0.5 * np.sum((x - x0) ** 2) / sigma_w**2
        grad -= (x - x0) / sigma_w**2
        return -ll, -grad

    res = minimize(negll, x0, jac=True, method="L-BFGS-B", bounds=[(0.0, None)] * len(names),
                   options={"maxiter": max_iter})
    return WeightFit(weights=dict(w0, **dict(zip(names, res.x.tolist()))), log_likelihood=-float(res.fun),
                     iterations=int(res.nit), message=str(res.message))


def _stretches(heading_rad: np.ndarray, turn_rad: float = np.deg2rad(30.0), min_steps: int = 4) -> list[tuple[int, int]]:
    """Maximal runs [a, b) of steps whose heading stays within ``turn_rad`` of the run's first."""
    out, a = [], 0
    for i in range(1, len(heading_rad) + 1):
        if i == len(heading_rad) or abs((heading_rad[i] - heading_rad[a] + np.pi) % (2 * np.pi) - np.pi) > turn_rad:
            if i - a >= min_steps:
                out.append((a, i))
            a = i
    return out


def _span_rows(path_xy_m: np.ndarray, steps_xy_m: np.ndarray, freq_hz: np.ndarray, height_m: float):
    """Rows (A, b) of the M-step: over each straight stretch between turns, the path's span
    ≈ Σ h(α f + β) + n γ, i.e. [h Σf, h n, n] · [α, β, γ] = span. Walls put the path's
    stretch ends where the turns really are, so the spans carry the true lengths."""
    rows, rhs = [], []
    th = np.arctan2(steps_xy_m[:, 1], steps_xy_m[:, 0])
    # The last stretch ends where the walk ends, not at a turn: nothing fixes its length.
    for a, b in _stretches(th)[:-1]:
        n = b - a
        span = np.linalg.norm(path_xy_m[b] - path_xy_m[a])
        f = freq_hz[a:b]
        rows.append([height_m * f.sum(), height_m * n, n])
        rhs.append(span)
    return rows, rhs


def learn_step_constants(model, walks: list[tuple[Steps, tuple | None]], iters: int = 5,
                         fit: tuple[str, ...] = ("gamma",)) -> StepModel:
    """Hard EM for the step-length constants (module docstring). ``walks`` = [(steps, start)].

    ``fit``: which of ``alpha``, ``beta``, ``gamma`` are free (least squares on the others'
    current values). Returns the updated :class:`StepModel`.
    """
    g = model.graph
    sm: StepModel = model.step_model
    # Heading only (see _f_heading_only): where to go along the step is left to the walls.
    sig = model.sigmas
    for _ in range(iters):
        rows, rhs = [], []
        for steps, start in walks:
            if len(steps) < 8:
                continue
            vec = steps.vectors_m(sm)
            inc = quantised_increments(vec, g.cell_m)
            f1 = _f_heading_only(g.offsets_m, vec, inc, sig)
            path, _ = viterbi(g, start_log_prior(g.p_xy_m, start), f1, None, beam=model.beam)
            r, b = _span_rows(g.p_xy_m[path], vec, steps.freq_hz, sm.height_m)
            rows += r
            rhs += b
        if len(rows) < 3:
            raise ValueError("too few straight stretches in the walks to fit the step length")
        a_mat, b_vec = np.asarray(rows), np.asarray(rhs)
        cur = np.array([sm.alpha_s, sm.beta, sm.gamma_m])
        free = [i for i, n in enumerate(("alpha", "beta", "gamma")) if n in fit]
        fixed = [i for i in range(3) if i not in free]
        sol, *_ = np.linalg.lstsq(a_mat[:, free], b_vec - a_mat[:, fixed] @ cur[fixed], rcond=None)
        new = cur.copy()
        new[free] = sol
        done = np.allclose(new, cur, atol=1e-3)
        sm = replace(sm, alpha_s=float(new[0]), beta=float(new[1]), gamma_m=float(new[2]))
        if done:
            break
    return sm


LENGTH_LOOSEN = 4.0


def _f_heading_only(offsets_m, steps, inc, sig: FeatureSigmas) -> np.ndarray:
    """f1 with its length term weakened (σ_l × LENGTH_LOOSEN) so headings and walls decide the path.

    Dropping the length term entirely would make standing still free (a zero move has no
    across-step residual), and every E-step would shrink the steps; a weak length term
    keeps moving and leaves the walls to decide how far.
    """
    return f_step(offsets_m, steps, inc, replace(sig, len_m=LENGTH_LOOSEN * sig.len_m))


def waypoint_segments(walks: list[Walk], step_model: StepModel,
                      heading: str = "rotation_vector") -> tuple[np.ndarray, np.ndarray]:
    """Dead-reckoning and surveyed displacements (n, 2) each, metres, between consecutive
    waypoints of every walk (dead reckoning interpolated at the waypoint times), keeping
    only segments where both are longer than 1 m."""
    dds, dws = [np.zeros((0, 2))], [np.zeros((0, 2))]
    for walk in walks:
        if walk.waypoints.shape[0] < 2:
            continue
        steps = steps_from_walk(walk, heading=heading)
        if len(steps) < 2:
            continue
        v = steps.vectors_m(step_model)
        p = np.vstack([np.zeros((1, 2)), np.cumsum(v, axis=0)])
        t = np.concatenate([[walk.acc[0, 0]], steps.t_ms])
        wp = walk.waypoints
        at = np.column_stack([np.interp(wp[:, 0], t, p[:, 0]), np.interp(wp[:, 0], t, p[:, 1])])
        dd, dw = np.diff(at, axis=0), np.diff(wp[:, 1:3], axis=0)
        ok = (np.linalg.norm(dd, axis=1) > 1.0) & (np.linalg.norm(dw, axis=1) > 1.0)
        dds.append(dd[ok])
        dws.append(dw[ok])
    return np.concatenate(dds), np.concatenate(dws)


def learn_heading_bias(walks: list[Walk], step_model: StepModel, heading: str = "rotation_vector") -> float:
    """Heading bias (rad) to add to sensor headings, from surveyed walks (module docstring)."""
    dd, dw = waypoint_segments(walks, replace(step_model, heading_bias_rad=0.0), heading)
    a = np.arctan2(dw[:, 1], dw[:, 0]) - np.arctan2(dd[:, 1], dd[:, 0])
    length = np.linalg.norm(dw, axis=1)
    s_sum = float(np.sum(length * np.sin(a)))
    c_sum = float(np.sum(length * np.cos(a)))
    if s_sum == 0.0 and c_sum == 0.0:
        raise ValueError("no walk with two or more waypoints a metre apart: cannot learn the heading bias")
    return float(np.arctan2(s_sum, c_sum))


def learn_step_scale(walks: list[Walk], step_model: StepModel, heading: str = "rotation_vector",
                     bounds: tuple[float, float] = (0.7, 1.4)) -> StepModel:
    """Step model with every step length multiplied by ``s = Σ|Δwaypoints| / Σ|Δdead reckoning|``
    (module docstring): ``height_m`` and ``gamma_m`` scaled by s. ``bounds``: s outside them
    means broken data (wrong units, missed steps), not a walker: a clear error."""
    dd, dw = waypoint_segments(walks, step_model, heading)
    if dd.shape[0] == 0:
        raise ValueError("no walk with two or more waypoints a metre apart: cannot learn the step-length scale")
    s = float(np.sum(np.linalg.norm(dw, axis=1)) / np.sum(np.linalg.norm(dd, axis=1)))
    if not bounds[0] <= s <= bounds[1]:
        raise ValueError(f"step-length scale {s:.3f} (surveyed / dead-reckoned distance) is outside "
                         f"{bounds}: check the waypoints' units and the step detection")
    return replace(step_model, height_m=step_model.height_m * s, gamma_m=step_model.gamma_m * s)


def learn_walk_spread(walks: list[Walk], step_model: StepModel, heading: str = "rotation_vector",
                      min_walks: int = 3) -> tuple[float | None, float | None, int]:
    """How far the walks' own heading offsets (rad) and step-length scales (log) spread about the
    floor's, and the number of walks measured; (None, None, n) with fewer than ``min_walks``
    walks of two waypoint segments or more.

    Each walk's offset and scale are :func:`learn_heading_bias` and :func:`learn_step_scale`'s
    ratio over its own waypoint segments, with the floor's bias and scale (``step_model``)
    applied: what is left is how this walk's phone and walker differ (how the phone is held,
    the magnetic field along its route, the stride). The spreads are their RMS. The CRF counts
    heading and length errors as independent per step, so an error that lasts the whole walk
    is what its posterior cannot see; :func:`posefix.mapmatch.tracker.track_walk` marginalises
    over it with these σ.
    """
    offs, scales = [], []
    for w in walks:
        dd, dw = waypoint_segments([w], step_model, heading)
        if dd.shape[0] < 2:
            continue
        a = np.arctan2(dw[:, 1], dw[:, 0]) - np.arctan2(dd[:, 1], dd[:, 0])
        length = np.linalg.norm(dw, axis=1)
        offs.append(np.arctan2(np.sum(length * np.sin(a)), np.sum(length * np.cos(a))))
        scales.append(np.log(length.sum() / np.linalg.norm(dd, axis=1).sum()))
    if len(offs) < min_walks:
        return None, None, len(offs)
    return float(np.sqrt(np.mean(np.square(offs)))), float(np.sqrt(np.mean(np.square(scales)))), len(offs)
