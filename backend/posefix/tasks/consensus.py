"""Consensus of several operators' corrected tracks, and conflict detection (numpy only).

Geometric median (Weiszfeld 1937, with the Vardi & Zhang 2000 fix for an estimate that
lands on a data point). For each keyframe ``j`` and operators ``i = 1..m`` with positions
``x_ij`` (local East-North metres) and weights ``w_i``, the median minimises

    f_j(y) = sum_i w_i |x_ij - y|

and Weiszfeld's fixed point iteration is

    T(y) = (sum_i w_i x_ij / d_i) / (sum_i w_i / d_i),   d_i = |x_ij - y|.

When ``y`` coincides with a point ``x_kj`` (weight ``eta``), Vardi-Zhang use

    y+ = max(0, 1 - eta / r) T~(y) + min(1, eta / r) y,
    R~(y) = sum_{i != k} w_i (x_ij - y) / d_i,   r = |R~(y)|,

where ``T~`` is ``T`` without the coincident point. This keeps the iteration convergent and
makes the answer the data point itself when it is the median (a majority of operators on
one spot wins). All keyframes are iterated at once (vectorised over ``k``).

The median is robust: one operator who drags a keyframe 50 m away moves the median of
three by at most a fraction of the spread of the other two (breakdown point 1/2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "geometric_median", "pairwise_separation_m", "disagreement_m", "track_conflicts", "edit_conflicts",
    "TrackConflict", "EditConflict",
]


def geometric_median(
    x_m: np.ndarray, valid: np.ndarray | None = None, weights: np.ndarray | None = None,
    *, tol_m: float = 1e-4, max_iter: int = 500,
) -> np.ndarray:
    """Per-keyframe geometric median of operators' positions.

    Parameters
    ----------
    x_m : ndarray, shape (m, k, d)
        Position of keyframe ``j`` by operator ``i`` in a local metric frame (metres).
    valid : ndarray, shape (m, k), bool, optional
        Which positions take part (e.g. False where an operator deleted the keyframe).
    weights : ndarray, shape (m,), optional
        Operator weights (default 1).
    tol_m : float
        Stop when no estimate moved more than this (metres).

    Returns
    -------
    y_m : ndarray, shape (k, d)
        The median per keyframe; NaN where no position is valid.
    """
    x = np.asarray(x_m, dtype=float)
    if x.ndim != 3:
        raise ValueError(f"x_m must have shape (m, k, d), got {x.shape}")
    m, k, _ = x.shape
    v = np.ones((m, k), dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    w_i = np.ones(m) if weights is None else np.asarray(weights, dtype=float)
    w = np.where(v, w_i[:, None], 0.0)  # (m, k)
    wsum = w.sum(axis=0)
    empty = wsum <= 0
    safe = np.where(empty, 1.0, wsum)
    y = np.einsum("ik,ikd->kd", w, np.where(v[..., None], x, 0.0)) / safe[:, None]  # weighted mean start
    eps = 1e-12
    vertex, is_vertex = _vertex_medians(x, w)
    for _ in range(max_iter):
        diff = x - y[None]                                  # (m, k, d)
        d = np.linalg.norm(diff, axis=2)                    # (m, k)
        coincident = (d < 1e-9) & (w > 0)
        inv = np.where(coincident | (w <= 0), 0.0, w / np.maximum(d, eps))
        denom = inv.sum(axis=0)                             # (k,)
        t_tilde = np.einsum("ik,ikd->kd", inv, x) / np.maximum(denom, eps)[:, None]
        eta = np.where(coincident, w, 0.0).sum(axis=0)      # (k,)
        r_vec = np.einsum("ik,ikd->kd", inv, diff)          # R~(y)
        r = np.linalg.norm(r_vec, axis=1)
        ratio = np.where(r > eps, eta / np.maximum(r, eps), np.inf)
        y_new = np.where(
            (eta > 0)[:, None],
            np.maximum(0.0, 1.0 - ratio)[:, None] * t_tilde + np.minimum(1.0, ratio)[:, None] * y,
            t_tilde,
        )
        # a keyframe whose every valid point coincides with y has denom 0: it is done
        y_new = np.where((denom <= 0)[:, None], y, y_new)
        step = np.linalg.norm(y_new - y, axis=1)
        y = y_new
        if not np.any(step > tol_m):
            break
    y = np.where(is_vertex[:, None], vertex, y)
    y[empty] = np.nan
    return y


def _vertex_medians(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keyframes whose median is one of the data points, found exactly.

    A data point ``x_p`` (with ``eta_p`` the weight of the points on it) is the median iff
    ``|R~(x_p)| <= eta_p`` (the subgradient condition Vardi-Zhang's step converges to). We use
    ``<``: at equality (e.g. two points) a whole segment are medians, and the iteration from
    the mean returns its midpoint. Testing directly avoids Weiszfeld's slow linear approach
    to a vertex. Loops over the m
    candidates, vectorised over keyframes.
    """
    m, k, d = x.shape
    vertex = np.zeros((k, d))
    found = np.zeros(k, dtype=bool)
    for p in range(m):
        diff = x - x[p][None]                           # (m, k, d)
        dist = np.linalg.norm(diff, axis=2)             # (m, k)
        on = dist <= 1e-9
        eta = np.where(on, w, 0.0).sum(axis=0)
        inv = np.where(on, 0.0, w / np.maximum(dist, 1e-300))
        r = np.linalg.norm(np.einsum("ik,ikd->kd", inv, diff), axis=1)
        # strict, with room for rounding: an even split (two points, r = eta) keeps the midpoint
        ok = (w[p] > 0) & (r < eta * (1.0 - 1e-9)) & ~found
        vertex[ok] = x[p][ok]
        found |= ok
    return vertex, found


def pairwise_separation_m(x_m: np.ndarray) -> np.ndarray:
    """Horizontal distance between every pair of operators at every keyframe.

    x_m : (m, k, d) metres -> (m, m, k) metres (symmetric, zero diagonal).
    """
    x = np.asarray(x_m, dtype=float)[..., :2]
    return np.linalg.norm(x[:, None] - x[None, :], axis=3)


def disagreement_m(x_m: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Per keyframe, the largest distance between two operators' positions (k,), metres."""
    sep = pairwise_separation_m(x_m)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        sep = np.where(v[:, None] & v[None, :], sep, 0.0)
    return sep.max(axis=(0, 1)) if sep.size else np.zeros(np.asarray(x_m).shape[1])


@dataclass(frozen=True)
class TrackConflict:
    """Operators ``a`` and ``b`` are more than the threshold apart on keyframes first..last."""

    a: int
    b: int
    first: int
    last: int
    max_separation_m: float

    def to_json(self) -> dict:
        return {"kind": "tracks_apart", "a": self.a, "b": self.b, "first": self.first, "last": self.last,
                "keyframes": self.last - self.first + 1, "max_separation_m": round(self.max_separation_m, 3)}


@dataclass(frozen=True)
class EditConflict:
    """Operators ``a`` and ``b`` both moved keyframe ``index`` to places ``distance_m`` apart."""

    a: int
    b: int
    index: int
    distance_m: float

    def to_json(self) -> dict:
        return {"kind": "edits_apart", "a": self.a, "b": self.b, "index": self.index,
                "distance_m": round(self.distance_m, 3)}


def _runs_of_true(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) of each run of consecutive True values in a 1-D mask."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(s), int(e) - 1) for s, e in zip(edges[::2], edges[1::2])]


def track_conflicts(
    x_m: np.ndarray, distance_m: float, min_keyframes: int, valid: np.ndarray | None = None,
) -> list[TrackConflict]:
    """Pairs of tracks more than ``distance_m`` apart over at least ``min_keyframes`` consecutive keyframes.

    x_m : (m, k, d) metres; valid (m, k) masks out deleted keyframes (never part of a conflict).
    """
    if distance_m <= 0 or min_keyframes < 1:
        raise ValueError("distance_m must be > 0 and min_keyframes >= 1")
    sep = pairwise_separation_m(x_m)
    m = sep.shape[0]
    v = np.ones(sep.shape[::2], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    out: list[TrackConflict] = []
    for a in range(m):
        for b in range(a + 1, m):
            apart = (sep[a, b] > distance_m) & v[a] & v[b]
            for first, last in _runs_of_true(apart):
                if last - first + 1 >= min_keyframes:
                    out.append(TrackConflict(a, b, first, last, float(sep[a, b, first:last + 1].max())))
    return out


def edit_conflicts(moves_m: list[dict[int, np.ndarray]], distance_m: float) -> list[EditConflict]:
    """Keyframes moved by two operators to places more than ``distance_m`` apart.

    moves_m : per operator, ``{keyframe index: (2,) or (3,) target in metres}``.
    """
    if distance_m <= 0:
        raise ValueError("distance_m must be > 0")
    out: list[EditConflict] = []
    for a in range(len(moves_m)):
        for b in range(a + 1, len(moves_m)):
            for j in sorted(set(moves_m[a]) & set(moves_m[b])):
                d = float(np.linalg.norm(np.asarray(moves_m[a][j])[:2] - np.asarray(moves_m[b][j])[:2]))
                if d > distance_m:
                    out.append(EditConflict(a, b, j, d))
    return out
