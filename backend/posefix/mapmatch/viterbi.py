"""Log-space Viterbi and forward-backward over the sparse step transitions of a GridGraph.

Scores: ``trans`` (T, K) = Σ_j w_j f_j[t, k] for moving by offset k at step t, and
``state[t]`` (V,) or None = Σ_j w_j g_j at y_{t+1}. With ``pred[v, k]`` the vertex u such
that v = u + o_k (-1 when not allowed):

    Viterbi:  δ_{t+1}(v) = max_k  δ_t(pred[v, k]) + trans[t, k]  + state[t](v)
    Forward:  α_{t+1}(v) = logsumexp_k α_t(pred[v, k]) + trans[t, k] + state[t](v)
    Backward: β_t(u)     = logsumexp_k β_{t+1}(succ[u, k]) + trans[t, k] + state[t](succ[u, k])

Each step is one (V', K) gather plus a reduction: vectorised numpy, O(V'·K).

Beam (documented pruning): states more than ``beam`` nats below the best are dropped
(set to -inf), and only vertices with an active predecessor are evaluated. With the
default 25 nats the dropped mass is below e⁻²⁵ ≈ 1e-11 per state, which changes neither
the Viterbi path in practice nor the marginals visibly; ``beam=None`` disables it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from posefix.mapmatch.graph import GridGraph

__all__ = [
    "DEFAULT_BEAM",
    "GaussianSummary",
    "gaussian_summary",
    "viterbi",
    "ViterbiFilter",
    "ForwardFilter",
    "forward_backward",
    "ForwardBackward",
]

DEFAULT_BEAM = 25.0
DEAD_END_NATS = 25.0  # evidence charged for a step no path survives when there is no beam
NEG_INF = -np.inf


@dataclass(frozen=True)
class GaussianSummary:
    """2-D Gaussian of a distribution over vertices, with its error ellipse.

    ``mean_xy_m`` (2,), ``cov_m2`` (2, 2); ``sigma_major_m``/``sigma_minor_m`` the 1σ
    semi-axes (multiply by 2 or 3 for the 2σ/3σ ellipse); ``angle_deg`` of the major axis,
    counter-clockwise from the floor x axis (east).
    """

    mean_xy_m: np.ndarray
    cov_m2: np.ndarray
    sigma_major_m: float
    sigma_minor_m: float
    angle_deg: float


def gaussian_summary(p_xy_m: np.ndarray, logp: np.ndarray, min_sigma_m: float = 0.0,
                     cut_nats: float = 20.0, cov_scale: float = 1.0) -> GaussianSummary:
    """Moment-match normalised log-weights ``logp`` (V,) over positions (V, 2).

    ``min_sigma_m`` adds an isotropic floor (e.g. the cell's own spread c/√12). Entries
    more than ``cut_nats`` below the maximum (weight < 2e-9 each) are left out for speed.
    ``cov_scale`` multiplies the covariance (a model file's ``ellipse_scale``); the mean is unchanged.
    """
    top = float(np.max(logp))
    sel = logp > top - cut_nats
    n_sel = int(np.count_nonzero(sel))
    if n_sel < logp.shape[0] // 4:
        p, lp = p_xy_m[sel], logp[sel]
    else:  # most vertices live (unknown start): weigh them all rather than copy a subset
        p, lp = p_xy_m, logp
    # Entries below the cut weigh 0, as in the subset branch (and no subnormal floats).
    w = np.exp(np.where(lp > top - cut_nats, lp - top, NEG_INF))
    w /= w.sum()
    mean = w @ p
    # Σ = Σ_i w_i (p_i - μ)(p_i - μ)ᵀ as one (2, n) x (n, 2) product. (Not as dot products of
    # the strided columns: OpenBLAS threads a ddot of over 10 000 elements, and on a busy
    # machine waking the threads cost 10-20 ms a call.)
    d = p - mean
    cov = ((d * w[:, None]).T @ d + np.eye(2) * min_sigma_m**2) * cov_scale
    evals, evecs = np.linalg.eigh(cov)
    major = evecs[:, 1]
    return GaussianSummary(mean_xy_m=mean, cov_m2=cov,
                           sigma_major_m=float(np.sqrt(max(evals[1], 0.0))),
                           sigma_minor_m=float(np.sqrt(max(evals[0], 0.0))),
                           angle_deg=float(np.degrees(np.arctan2(major[1], major[0])) % 180.0))


def _ext(a: np.ndarray) -> np.ndarray:
    """Append a -inf sentinel so index -1 (no transition) gathers -inf."""
    return np.concatenate([a, [NEG_INF]])


def _candidates(graph: GridGraph, active: np.ndarray) -> np.ndarray:
    """Vertices reachable in one step from the active set (sorted, unique)."""
    s = graph.succ[active].ravel()
    s = s[s >= 0]
    mark = np.zeros(graph.n_vertices, dtype=bool)
    mark[s] = True
    return np.nonzero(mark)[0]


def _beam_predecessors(graph: GridGraph, scores: np.ndarray, beam: float | None) -> tuple[np.ndarray | None, np.ndarray]:
    """(vertices to compute or None for all, their predecessor table (K, V') to gather from):
    with a beam and under a third of the vertices live, only those reachable from the live ones."""
    active = np.nonzero(np.isfinite(scores))[0]
    if beam is not None and active.size < graph.n_vertices // 3:
        cand = _candidates(graph, active)
        return cand, graph.pred_t[:, cand]
    return None, graph.pred_t


def _log_normalised(a: np.ndarray) -> np.ndarray:
    """``a - log Σ exp(a)`` (V,), -inf entries kept."""
    top = float(np.max(a))
    return a - (top + np.log(np.sum(np.exp(a - top))))


def _prune(a: np.ndarray, beam: float | None) -> np.ndarray:
    if beam is None:
        return a
    m = np.max(a)
    return np.where(a >= m - beam, a, NEG_INF)


class ViterbiFilter:
    """Online Viterbi: feed one step at a time; keeps δ and the back-pointers.

    ``step(trans_k, state_v)`` with ``trans_k`` (K,) and ``state_v`` (V,) or None.
    ``column()`` is the current normalised column log p (V,), ``best_path()`` the
    back-tracked most likely vertex sequence y_0..y_t so far.
    """

    def __init__(self, graph: GridGraph, log_prior: np.ndarray, beam: float | None = DEFAULT_BEAM):
        if log_prior.shape != (graph.n_vertices,):
            raise ValueError(f"log_prior must have shape ({graph.n_vertices},), got {log_prior.shape}")
        if not np.any(np.isfinite(log_prior)):
            raise ValueError("log_prior has no finite entry: no possible start vertex")
        self.graph = graph
        self.beam = beam
        self.delta = _prune(np.asarray(log_prior, dtype=float), beam)
        self.back: list[np.ndarray] = []  # per step: (V,) int8 offset index, -1 = unreachable

    def step(self, trans_k: np.ndarray, state_v: np.ndarray | None = None) -> None:
        g = self.graph
        cand, pred_t = _beam_predecessors(g, self.delta, self.beam)
        # One contiguous (V',) gather per offset; faster than a (V', K) gather + argmax.
        # np.take into reused buffers: no temporaries (-30 % on a dense 12 000-vertex step).
        d_ext = _ext(self.delta)
        best = np.take(d_ext, pred_t[0]) + trans_k[0]
        k_best = np.zeros(best.shape[0], dtype=np.int8)
        c = np.empty_like(best)
        better = np.empty(best.shape[0], dtype=bool)
        for k in range(1, pred_t.shape[0]):
            np.take(d_ext, pred_t[k], out=c)
            c += trans_k[k]
            np.greater(c, best, out=better)
            np.copyto(best, c, where=better)
            np.copyto(k_best, k, where=better)
        new = np.full(g.n_vertices, NEG_INF)
        back = np.full(g.n_vertices, -1, dtype=np.int8)
        idx = cand if cand is not None else slice(None)
        new[idx] = best
        back[idx] = np.where(np.isfinite(best), k_best, -1)
        if state_v is not None:
            new = new + state_v
        if not np.any(np.isfinite(new)):
            # Every path hit a wall (e.g. a step much longer than the reach). Keep the
            # previous belief rather than dying: the walker is assumed to have stood still.
            new = self.delta.copy()
            back = np.where(np.isfinite(new), 0, -1).astype(np.int8)
        self.delta = _prune(new, self.beam)
        self.back.append(back)

    def column(self) -> np.ndarray:
        """Normalised log column (V,): log p(y_t = v) under max-product, -inf off the beam."""
        return _log_normalised(self.delta)

    def best_path(self, last_n: int | None = None) -> np.ndarray:
        """Most likely vertex sequence, back-tracked from the current best vertex.

        Returns all of y_0..y_t, or only the last ``last_n + 1`` vertices.
        """
        v = int(np.argmax(self.delta))
        t_n = len(self.back)
        n = t_n if last_n is None else min(last_n, t_n)
        out = np.empty(n + 1, dtype=np.int64)
        out[n] = v
        for i in range(n):
            k = int(self.back[t_n - 1 - i][v])
            if k < 0:
                raise RuntimeError("back-pointer chain broken (pruned state on the best path)")
            u = int(self.graph.pred[v, k])
            v = u
            out[n - 1 - i] = v
        return out


class ForwardFilter:
    """Online forward (sum-product) filter: log α_t (V,), the filtered marginal
    p(y_t | x_1..t) up to a constant, with the same transitions, states and beam as
    :class:`ViterbiFilter`. The live position is its mean (the minimum mean-squared-error
    estimate given only the past, the online counterpart of the smoothed mean), not the
    max-product column, whose mass sits on the best path's neighbours only.
    """

    def __init__(self, graph: GridGraph, log_prior: np.ndarray, beam: float | None = DEFAULT_BEAM):
        if log_prior.shape != (graph.n_vertices,):
            raise ValueError(f"log_prior must have shape ({graph.n_vertices},), got {log_prior.shape}")
        self.graph = graph
        self.beam = beam
        self.alpha = _prune(np.asarray(log_prior, dtype=float), beam)
        # log of what has been divided out of α so far: log Z = log_scale + log Σ exp(α).
        self.log_scale = 0.0

    def step(self, trans_k: np.ndarray, state_v: np.ndarray | None = None) -> None:
        g = self.graph
        cand, pred_t = _beam_predecessors(g, self.alpha, self.beam)
        # Sum-product in the linear domain, scaled by the maxima: V exponentials and one
        # contiguous gather per offset instead of a (V', K) logsumexp (5-10x faster when
        # the start is unknown and every vertex is live). Terms more than ~700 nats below
        # the best underflow to 0: far outside any beam.
        top, t_top = float(np.max(self.alpha)), float(np.max(trans_k))
        a = np.concatenate([np.exp(self.alpha - top), [0.0]])
        tk = np.asarray(trans_k, dtype=float) - t_top
        e = np.exp(np.where(tk > -300.0, tk, NEG_INF))  # no subnormal products (see gaussian_summary)
        acc = np.take(a, pred_t[0]) * e[0]
        buf = np.empty_like(acc)
        for k in range(1, pred_t.shape[0]):
            if e[k] == 0.0:
                continue
            np.take(a, pred_t[k], out=buf)
            buf *= e[k]
            acc += buf
        with np.errstate(divide="ignore"):
            la = np.log(acc) + (top + t_top)
        row = np.full(g.n_vertices, NEG_INF)
        idx = cand if cand is not None else slice(None)
        row[idx] = la
        if state_v is not None:
            row = row + state_v
        if not np.any(np.isfinite(row)):
            # Every path hit a wall: keep the belief (as ViterbiFilter does), and charge the
            # evidence what falling off the beam would cost (the step was impossible).
            self.log_scale -= DEAD_END_NATS if self.beam is None else self.beam
            return
        top = float(np.max(row))
        self.alpha = _prune(row - top, self.beam)  # renormalised so it never under/overflows
        self.log_scale += top

    def column(self) -> np.ndarray:
        """Normalised log filtered marginal (V,), -inf off the beam."""
        return _log_normalised(self.alpha)

    def log_evidence(self) -> float:
        """log Z_t = log Σ_paths exp(prior + Σ scores) over the steps so far (within the beam)."""
        top = float(np.max(self.alpha))
        return self.log_scale + top + float(np.log(np.sum(np.exp(self.alpha - top))))


def viterbi(graph: GridGraph, log_prior: np.ndarray, trans: np.ndarray,
            state: list[np.ndarray | None] | None = None, beam: float | None = DEFAULT_BEAM) -> tuple[np.ndarray, float]:
    """Offline Viterbi: most likely y_0..y_T (T+1,) and its log score."""
    f = ViterbiFilter(graph, log_prior, beam=beam)
    for t in range(trans.shape[0]):
        f.step(trans[t], None if state is None else state[t])
    return f.best_path(), float(np.max(f.delta))


@dataclass(frozen=True)
class ForwardBackward:
    """Result of :func:`forward_backward`.

    ``log_z``: log partition; ``gamma`` (T+1, V): marginals p(y_t = v); ``xi_k`` (T, K):
    p(step t moves by offset k), summed over vertices — all a linear CRF's expected
    transition features need when those depend on k only.
    """

    log_z: float
    gamma: np.ndarray
    xi_k: np.ndarray


def forward_backward(graph: GridGraph, log_prior: np.ndarray, trans: np.ndarray,
                     state: list[np.ndarray | None] | None = None,
                     beam: float | None = DEFAULT_BEAM) -> ForwardBackward:
    """Forward-backward in log space (module docstring).

    Only the beam's support is computed: α_t on the vertices reachable from the previous
    support, β_t on the support of α_t (elsewhere γ_t = 0 anyway), so a walk with a known
    start costs O(active·K) per step rather than O(V·K).
    """
    t_n, k_n = trans.shape
    v_n = graph.n_vertices
    pred, succ = graph.pred, graph.succ
    alpha = np.full((t_n + 1, v_n), NEG_INF)
    alpha[0] = _prune(np.asarray(log_prior, dtype=float), beam)
    for t in range(t_n):
        active = np.nonzero(np.isfinite(alpha[t]))[0]
        cand = _candidates(graph, active)
        m = _ext(alpha[t])[pred[cand]] + trans[t][None, :]
        with np.errstate(invalid="ignore"):
            a = logsumexp(m, axis=1)
        if state is not None and state[t] is not None:
            a = a + state[t][cand]
        row = np.full(v_n, NEG_INF)
        row[cand] = a
        if not np.any(np.isfinite(row)):
            raise ValueError(f"no path is consistent with the observations at step {t}")
        alpha[t + 1] = _prune(row, beam)
    log_z = float(logsumexp(alpha[t_n][np.isfinite(alpha[t_n])]))
    beta = np.full((t_n + 1, v_n), NEG_INF)
    beta[t_n] = np.where(np.isfinite(alpha[t_n]), 0.0, NEG_INF)
    xi_k = np.zeros((t_n, k_n))
    for t in range(t_n - 1, -1, -1):
        sup = np.nonzero(np.isfinite(alpha[t]))[0]
        nb = beta[t + 1] if (state is None or state[t] is None) else beta[t + 1] + state[t]
        nxt = _ext(nb)[succ[sup]] + trans[t][None, :]  # (S, K)
        with np.errstate(invalid="ignore"):
            beta[t, sup] = logsumexp(nxt, axis=1)
            joint = alpha[t, sup][:, None] + nxt - log_z
            xi_k[t] = np.exp(logsumexp(joint, axis=0))
    with np.errstate(invalid="ignore"):
        g = alpha + beta - log_z
    gamma = np.exp(np.where(np.isfinite(g), g, NEG_INF))
    return ForwardBackward(log_z=log_z, gamma=gamma, xi_k=np.nan_to_num(xi_k))
