"""Propagation of the keyframe correction to every full-rate sample.

For a sample s between keyframes a and b (rows a <= s <= b) with fraction alpha in [0, 1]
(distance travelled since a over distance a..b along the reported track: "distance", the
default; or elapsed time over a..b: "time"):

1. rotation first: the world-frame correction of each keyframe, ``C_k = R_k R~_k^T``, is
   interpolated by slerp, ``C_s = C_a Exp(alpha Log(C_a^T C_b))``, and applied,
   ``R_s = C_s R~_s``;
2. then translation: the sample keeps its offset from the reported chord between a and b,
   rotated by the correction, around the corrected chord:
   ``p_s = (1 - alpha) p_a + alpha p_b + C_a (p~_s - (1 - alpha) p~_a - alpha p~_b)``
   (C_a, not C_s: the offset is centimetres and C_s differs from C_a by milliradians at
   most, so the difference is below 0.1 mm and the map stays affine per segment).

At a keyframe alpha is 0 or 1, so the sample lands exactly on the corrected keyframe:
the corrected run is continuous.  Between keyframes the local shape (the sample's deviation
from the chord) is kept up to the small rotation C_s; a stopped vehicle (no distance
travelled) receives no spurious motion under "distance".  Everything is vectorised.
"""

from __future__ import annotations

import numpy as np

from posefix.core import rotations as rot


def interpolation_fraction(
    t_s: np.ndarray, along_m: np.ndarray | None, kf_index: np.ndarray, mode: str = "distance"
) -> tuple[np.ndarray, np.ndarray]:
    """Segment (keyframe a, so b = a + 1) and fraction alpha of every row, shapes (n,), (n,).

    ``along_m`` is the cumulative distance travelled (n,), needed for "distance"; segments
    without travel fall back to time.  Rows before the first keyframe take alpha 0 of the
    first segment, rows after the last alpha 1 of the last one.
    """
    n = len(t_s)
    k = len(kf_index)
    if k < 2:
        return np.zeros(n, dtype=np.int64), np.zeros(n)
    if mode not in ("distance", "time"):
        raise ValueError(f"propagation mode must be 'distance' or 'time', got {mode!r}")
    if mode == "distance" and along_m is None:
        raise ValueError("distance-weighted propagation needs the distance travelled")
    # rows of segment j are kf_index[j] .. kf_index[j+1]-1; the last keyframe row closes the last segment
    counts = np.diff(kf_index).astype(np.int64)
    seg = np.empty(n, dtype=np.int64)
    first, last = int(kf_index[0]), int(kf_index[-1])
    seg[:first] = 0
    seg[first:last] = np.repeat(np.arange(k - 1), counts)
    seg[last:] = k - 2
    coord = t_s if mode == "time" else along_m
    span = np.diff(coord[kf_index])
    use_time = span <= 1e-6 if mode == "distance" else np.zeros(k - 1, dtype=bool)
    if np.any(use_time):
        coord_t = np.diff(t_s[kf_index])
        start = np.where(use_time, t_s[kf_index[:-1]], coord[kf_index[:-1]])
        span = np.where(use_time, coord_t, span)
        moving_row = ~use_time[seg]
        alpha = (np.where(moving_row, coord, t_s) - start[seg]) / span[seg]
    else:
        alpha = (coord - coord[kf_index[:-1]][seg]) / span[seg]
    return seg, np.clip(alpha, 0.0, 1.0)


MIN_BLOCK_SEGMENTS = 8  # runs of fewer equal-length segments go through the row-wise gather


def segment_blocks(kf_index: np.ndarray, n: int) -> tuple[list[tuple[int, int, int]], np.ndarray]:
    """Runs of consecutive segments with the same number of rows, and the rows outside them.

    Returns ``blocks`` [(first segment s, segments m, rows per segment c)], whose rows
    ``kf_index[s] .. kf_index[s] + m c - 1`` reshape to (m, c) without any gather (keyframes
    every S seconds at a constant rate make the whole run one block), and ``rest`` (r,) the
    other rows (before the first keyframe, the last keyframe and after it, short runs).
    """
    kf_index = np.asarray(kf_index, dtype=np.int64)
    counts = np.diff(kf_index)
    if len(counts) == 0:
        return [], np.arange(n)
    change = np.flatnonzero(np.diff(counts) != 0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(counts)]])
    blocks = [(int(a), int(b - a), int(counts[a])) for a, b in zip(starts, ends) if b - a >= MIN_BLOCK_SEGMENTS]
    covered = np.zeros(n, dtype=bool)
    for a, m, c in blocks:
        covered[kf_index[a]:kf_index[a] + m * c] = True
    return blocks, np.flatnonzero(~covered)


def _left_product_matrices(q: np.ndarray) -> np.ndarray:
    """(m,4,4) matrices L(q) with L(q) b = q * b (Hamilton product) for b as a column (w,x,y,z)."""
    w, x, y, z = q.T
    return np.stack([
        np.stack([w, -x, -y, -z], -1),
        np.stack([x, w, -z, y], -1),
        np.stack([y, z, w, -x], -1),
        np.stack([z, -y, x, w], -1),
    ], 1)


def interpolate_rotations(
    q_kf_wxyz: np.ndarray,
    seg: np.ndarray,
    alpha: np.ndarray,
    then_multiply_wxyz: np.ndarray | None = None,
    kf_index: np.ndarray | None = None,
) -> np.ndarray:
    """Slerp of keyframe quaternions (k,4) to rows (n,4): ``q_a Exp(alpha Log(q_a^-1 q_b))``.

    Computed as normalised linear interpolation where consecutive keyframes differ by less
    than 0.05 rad (equal to slerp within 1e-8 rad there, and several times cheaper), with
    true slerp on the rows of the other segments.  With ``then_multiply_wxyz`` (n,4) the
    result is the product ``slerp * then_multiply`` (done column-wise, without temporaries
    of shape (n,4,4)).  With ``kf_index`` (the keyframe rows that gave ``seg``) runs of
    equal segments are done block-wise: the normalised interpolation is
    ``(q_a + alpha dq) / |q_a + alpha dq|`` and its product with b is
    ``(L(q_a) b + alpha L(dq) b) / |q_a + alpha dq|`` (L the left-product matrix, linear in
    q), two small matrix products per segment instead of a gather of 8 values per row.
    """
    q = np.asarray(q_kf_wxyz, dtype=float)
    n = len(seg)
    if len(q) < 2:
        out = np.broadcast_to(q[0], (n, 4)).copy()
        return out if then_multiply_wxyz is None else rot.quat_multiply(out, then_multiply_wxyz)
    q = q.copy()
    # same hemisphere as the previous keyframe so interpolation takes the short way
    flip = np.cumsum(np.einsum("ki,ki->k", q[:-1], q[1:]) < 0) % 2 == 1
    q[1:][flip] *= -1.0
    qa, qb = q[:-1], q[1:]
    angle = 2.0 * np.arccos(np.clip(np.abs(np.einsum("ki,ki->k", qa, qb)), 0.0, 1.0))
    b_q = None if then_multiply_wxyz is None else np.asarray(then_multiply_wxyz, dtype=float)
    blocks, rest = segment_blocks(kf_index, n) if kf_index is not None else ([], np.arange(n))
    out = np.empty((n, 4))
    if blocks:
        dq = qb - qa
        LT = np.concatenate([np.swapaxes(_left_product_matrices(qa), 1, 2),
                             np.swapaxes(_left_product_matrices(dq), 1, 2)], axis=1)  # (k-1, 8, 4)
        n0, n1, n2 = np.einsum("ki,ki->k", qa, qa), 2.0 * np.einsum("ki,ki->k", qa, dq), np.einsum("ki,ki->k", dq, dq)
        for s, m, c in blocks:
            rows = slice(int(kf_index[s]), int(kf_index[s]) + m * c)
            A = alpha[rows].reshape(m, c)
            inv = 1.0 / np.sqrt(n0[s:s + m, None] + A * (n1[s:s + m, None] + A * n2[s:s + m, None]))
            blk = out[rows].reshape(m, c, 4)
            if b_q is None:
                np.add(qa[s:s + m, None, :], A[:, :, None] * dq[s:s + m, None, :], out=blk)
            else:
                # one batched product: [b, alpha b] (m, c, 8) @ [L(q_a)^T; L(dq)^T] (m, 8, 4)
                X = np.empty((m * c, 8))
                X[:, :4] = b_q[rows]
                np.multiply(X[:, :4], alpha[rows][:, None], out=X[:, 4:])
                np.matmul(X.reshape(m, c, 8), LT[s:s + m], out=blk)
            blk *= inv[:, :, None]
    if len(rest):
        sr, ar = seg[rest], alpha[rest]
        table = np.ascontiguousarray(np.concatenate([qa, qb - qa], axis=1).T)  # (8, k-1)
        G = np.take(table, sr, axis=1)
        w, x, y, z = (G[i] + ar * G[4 + i] for i in range(4))
        inv = 1.0 / np.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * inv, x * inv, y * inv, z * inv
        if b_q is None:
            out[rest] = np.stack([w, x, y, z], axis=1)
        else:
            bw, bx, by, bz = b_q[rest].T
            out[rest, 0] = w * bw - x * bx - y * by - z * bz
            out[rest, 1] = w * bx + x * bw + y * bz - z * by
            out[rest, 2] = w * by - x * bz + y * bw + z * bx
            out[rest, 3] = w * bz + x * by - y * bx + z * bw
    wide_seg = angle > 0.05
    if np.any(wide_seg):
        wide = np.flatnonzero(wide_seg[seg])
        exact = rot.slerp_quat(qa[seg[wide]], qb[seg[wide]], alpha[wide])
        out[wide] = exact if b_q is None else rot.quat_multiply(exact, b_q[wide])
    return out


def propagate_corrections(
    t_s: np.ndarray,
    p_rep_enu_m: np.ndarray,
    kf_index: np.ndarray,
    kf_p_enu_m: np.ndarray,
    c_kf_wxyz: np.ndarray,
    mode: str = "distance",
    along_m: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corrected positions (n,3), and each row's segment (n,) and fraction alpha (n,).

    ``c_kf_wxyz`` (k,4) is each keyframe's world-frame correction ``C_k = q_k q~_k^-1``.
    The translation step rotates each sample's deviation from the reported chord by the
    correction; that deviation is centimetres within a keyframe interval and consecutive
    corrections differ by at most milliradians, so the segment's start correction C_a is
    used for the whole segment (error below 0.1 mm).  Per segment the map is affine,
    ``p_s = M p~_s + o0 + alpha o1`` with ``M = C_a``, ``o0 = p_a - M p~_a`` and
    ``o1 = (p_b - p_a) - M (p~_b - p~_a)``, evaluated column-wise over the rows.
    The orientation of a row is ``interpolate_rotations(c_kf, seg, alpha) * q~``.  Runs of
    segments with equal row counts (see ``segment_blocks``) are evaluated as batched 3x3
    matrix products on reshaped rows; the other rows gather their segment's values.
    """
    t_s = np.asarray(t_s, dtype=float)
    p_rep = np.asarray(p_rep_enu_m, dtype=float)
    kf_index = np.asarray(kf_index, dtype=np.int64)
    kf_p = np.asarray(kf_p_enu_m, dtype=float)
    if mode == "distance" and along_m is None:
        along_m = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p_rep, axis=0), axis=1))])
    if len(kf_index) < 2:
        R = rot.quat_to_matrix(c_kf_wxyz[:1])[0]
        d = p_rep - p_rep[kf_index[0]]
        return kf_p[0] + d @ R.T, np.zeros(len(t_s), dtype=np.int64), np.zeros(len(t_s))
    seg, alpha = interpolation_fraction(t_s, along_m, kf_index, mode)
    M = rot.quat_to_matrix(c_kf_wxyz[:-1])  # (k-1,3,3)
    A = p_rep[kf_index[:-1]]
    B = p_rep[kf_index[1:]] - A
    o0 = kf_p[:-1] - np.einsum("kij,kj->ki", M, A)
    o1 = (kf_p[1:] - kf_p[:-1]) - np.einsum("kij,kj->ki", M, B)
    n = len(t_s)
    out = np.empty((n, 3))
    # runs of equal segments: (m, c, 3) @ M^T per segment, no per-row gather of 15 values
    blocks, rest = segment_blocks(kf_index, n)
    MT = np.swapaxes(M, 1, 2)
    if blocks:
        # one batched product per block: [p~_s, 1, alpha_s] (m, c, 5) @ [M^T; o0; o1] (m, 5, 3)
        W = np.concatenate([MT, o0[:, None, :], o1[:, None, :]], axis=1)
        for s, m, c in blocks:
            r0 = int(kf_index[s])
            rows = slice(r0, r0 + m * c)
            X = np.empty((m * c, 5))
            X[:, :3] = p_rep[rows]
            X[:, 3] = 1.0
            X[:, 4] = alpha[rows]
            np.matmul(X.reshape(m, c, 5), W[s:s + m], out=out[rows].reshape(m, c, 3))
    if len(rest):
        table = np.ascontiguousarray(np.concatenate([M.reshape(-1, 9), o0, o1], axis=1).T)  # (15, k-1)
        sr, ar = seg[rest], alpha[rest]
        G = np.take(table, sr, axis=1)
        px, py, pz = np.ascontiguousarray(p_rep[rest].T)
        for j in range(3):
            out[rest, j] = G[3 * j] * px + G[3 * j + 1] * py + G[3 * j + 2] * pz + G[9 + j] + ar * G[12 + j]
    return out, seg, alpha


def propagate(
    t_s: np.ndarray,
    p_rep_enu_m: np.ndarray,
    q_rep_wxyz: np.ndarray,
    kf_index: np.ndarray,
    kf_p_enu_m: np.ndarray,
    kf_q_wxyz: np.ndarray,
    mode: str = "distance",
    along_m: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected positions (n,3) metres and orientations (n,4) of every sample.

    Parameters
    ----------
    t_s : (n,) sample times, s.         p_rep_enu_m, q_rep_wxyz : (n,3), (n,4) reported poses.
    kf_index : (k,) keyframe rows, sorted, including the first and last rows to correct.
    kf_p_enu_m, kf_q_wxyz : (k,3), (k,4) corrected keyframe poses (same frame as the input).
    mode : "distance" | "time".        along_m : (n,) distance travelled, computed if None.
    """
    q_rep = np.asarray(q_rep_wxyz, dtype=float)
    kf_index = np.asarray(kf_index, dtype=np.int64)
    c_kf = rot.quat_multiply(kf_q_wxyz, rot.quat_conjugate(q_rep[kf_index]))
    p_out, seg, alpha = propagate_corrections(t_s, p_rep_enu_m, kf_index, kf_p_enu_m, c_kf, mode, along_m)
    return p_out, interpolate_rotations(c_kf, seg, alpha, then_multiply_wxyz=q_rep, kf_index=kf_index)
