"""Symmetric positive definite block-tridiagonal systems in numpy: factor once, solve many.

The keyframe problem's normal equations (6x6 blocks, ``solver``) and the GNSS level model's
information matrix (3x3 blocks, ``drift.levels``) are block-tridiagonal:

    A = [[D_0,   U_0,                 ],
         [U_0^T, D_1,   U_1,          ],
         [       U_1^T, D_2,   ...    ]],   D (n, b, b) symmetric, U (n-1, b, b).

``factor`` eliminates them by block cyclic reduction (odd-even elimination): the odd blocks
are eliminated at once, which leaves a block-tridiagonal Schur complement on the even
blocks, half the size, and so on.  This is block Cholesky after the odd-even (nested
dissection) permutation, so it is as stable as Cholesky on an SPD matrix, with O(n b^3)
work in log2(n) rounds of batched numpy operations instead of a loop over blocks.  With
``L_i L_i^T = D_i`` (i odd) and ``G = L_i^-1 [A_i,i-1  A_i,i+1]`` the even blocks become

    D'_i-1 = D_i-1 - G_l^T G_l,   D'_i+1 = D_i+1 - G_r^T G_r,   U'(i-1, i+1) = -G_l^T G_r,

and the right-hand side ``b'_i+-1 = b_i+-1 - G^T (L_i^-1 b_i)``; back-substitution gives
``x_i = L_i^-T (L_i^-1 b_i - G_l x_i-1 - G_r x_i+1)``.

LAPACK's banded Cholesky (``dpbtrf``/``dpbtrs``) does the same work in one call, 5-10x
faster than these rounds of numpy calls (2 ms against 15 ms for 3,600 6x6 blocks).  A
correction must not import scipy for it (``scipy.linalg`` costs about a quarter of a second
of CPU at start-up, more than all the solves of a short run), so ``factor`` calls the LAPACK
that numpy's own wheels ship (OpenBLAS with 64-bit integers, already loaded by numpy) through
ctypes, and falls back to the cyclic reduction where that library is not found (a numpy
built on another BLAS).  Both are Cholesky factorisations of the same matrix: answers agree
to round-off.  A matrix that is not positive definite raises ``numpy.linalg.LinAlgError``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LinAlgError = np.linalg.LinAlgError


@dataclass(frozen=True)
class Round:
    """One elimination round: the odd blocks' inverse Cholesky factors Li (m, b, b) and
    ``G = Li [A_i,i-1  A_i,i+1]`` (m, b, 2b) (the last odd block of an even count has no
    right neighbour: zeros there)."""

    Li: np.ndarray
    G: np.ndarray


@dataclass(frozen=True)
class Factor:
    """``factor``'s answer: the rounds, then the inverse Cholesky factor (m b, m b) of the
    last m <= ``DENSE_TAIL_BLOCKS`` blocks' Schur complement, assembled dense."""

    rounds: tuple[Round, ...]
    last_Li: np.ndarray
    n: int
    b: int


def _t(a: np.ndarray) -> np.ndarray:
    return a.transpose(0, 2, 1)


# The last few blocks are factored as one dense matrix: fewer rounds of small numpy calls.
DENSE_TAIL_BLOCKS = 8
# Below this many blocks, numpy's batched LAPACK calls (one per block, but two calls in all)
# beat the entry-by-entry loop (some 60 numpy calls whatever the batch).
BATCHED_LAPACK_BELOW = 200


def _inv_cholesky(D: np.ndarray) -> np.ndarray:
    """L^-1 for L L^T = D (m, b, b) batched; raises LinAlgError unless every D is positive definite.

    Written out entry by entry over the batch (vectors of length m, contiguous): numpy's
    batched ``cholesky`` and ``inv`` call LAPACK once per 6x6 block, several times slower.
    """
    if len(D) < BATCHED_LAPACK_BELOW:
        return np.linalg.inv(np.linalg.cholesky(D))
    b = D.shape[1]
    A = np.ascontiguousarray(D.transpose(1, 2, 0))  # (b, b, m)
    L = np.zeros_like(A)
    for j in range(b):
        pivot = A[j, j] - np.einsum("km,km->m", L[j, :j], L[j, :j])
        if not (pivot > 0.0).all():  # also catches NaN
            raise LinAlgError("Matrix is not positive definite")
        L[j, j] = np.sqrt(pivot)
        for i in range(j + 1, b):
            L[i, j] = (A[i, j] - np.einsum("km,km->m", L[i, :j], L[j, :j])) / L[j, j]
    Li = np.zeros_like(A)
    for i in range(b):
        Li[i, i] = 1.0 / L[i, i]
        for j in range(i):
            Li[i, j] = -np.einsum("km,km->m", L[i, j:i], Li[j:i, j]) * Li[i, i]
    return np.ascontiguousarray(Li.transpose(2, 0, 1))


@dataclass(frozen=True)
class BandFactor:
    """LAPACK's answer: the upper Cholesky factor in upper band form (2b, n b), Fortran order."""

    ab: np.ndarray
    n: int
    b: int


_LAPACK: list = []  # [(dpbtrf, dpbtrs, ctypes) or None], found on first use


def _lapack():
    """``(dpbtrf, dpbtrs, ctypes)`` of the LAPACK in numpy's wheel, or None."""
    if not _LAPACK:
        _LAPACK.append(_find_lapack())
    return _LAPACK[0]


def has_lapack() -> bool:
    """Whether ``factor`` runs on LAPACK (else the cyclic reduction)."""
    return _lapack() is not None


def _find_lapack():
    import ctypes
    import glob
    import os

    if os.environ.get("POSEFIX_NUMPY_BANDED"):  # the cyclic reduction alone (tests compare the two)
        return None
    root = os.path.dirname(os.path.dirname(np.__file__))
    names = ("scipy_dpbtrf_64_", "scipy_dpbtrs_64_")  # numpy >= 2 wheels: scipy-openblas, ILP64
    for pattern in ("numpy.libs/libscipy_openblas64_*", "numpy/.dylibs/libscipy_openblas64_*"):
        for path in sorted(glob.glob(os.path.join(root, pattern))):
            try:
                lib = ctypes.CDLL(path)
                trf, trs = (getattr(lib, name) for name in names)
            except (OSError, AttributeError):
                continue
            trf.restype = trs.restype = None
            return trf, trs, ctypes
    return None


def _i64(ctypes, v: int):
    return ctypes.byref(ctypes.c_int64(v))


_PACK_INDEX: dict[int, np.ndarray] = {}


def _pack_index(b: int) -> np.ndarray:
    """Where each entry of a block column's band (b columns x 2b rows) comes from in the row
    ``[U[k-1] (b*b), D[k] (b*b), 0]``: U[k-1][:, c] fills band rows b-1-c .. 2b-2-c and
    D[k][:c+1, c] the rows below; what lies above the band reads the 0."""
    idx = _PACK_INDEX.get(b)
    if idx is None:
        idx = np.full((b, 2 * b), 2 * b * b, dtype=np.int64)
        for c in range(b):
            for i in range(b):
                idx[c, b - 1 - c + i] = i * b + c
            for i in range(c + 1):
                idx[c, 2 * b - 1 - c + i] = b * b + i * b + c
        idx = _PACK_INDEX[b] = idx.ravel()
    return idx


def pack_upper(D: np.ndarray, U: np.ndarray) -> np.ndarray:
    """The matrix in LAPACK's upper band form (2b, n b), Fortran order (a new array): one
    gather from the blocks (strided writes block column by block column cost twice as long)."""
    n, b = D.shape[0], D.shape[1]
    src = np.zeros((n, 2 * b * b + 1))
    if n > 1:
        src[1:, :b * b] = U.reshape(n - 1, b * b)
    src[:, b * b:2 * b * b] = D.reshape(n, b * b)
    # rows [block, column in block, band row]: the Fortran order of (2b, n b)
    return np.take(src, _pack_index(b), axis=1).reshape(n * b, 2 * b).T


def factor_upper(ab: np.ndarray, b: int, overwrite: bool = False) -> Factor | BandFactor:
    """``factor`` of the matrix in LAPACK's upper band form ab (2b, n b); ``overwrite`` lets
    LAPACK factor ab itself when it is a Fortran-ordered float array."""
    lapack = _lapack()
    if lapack is None:
        return factor(*from_upper_band(ab, b))
    if ab.shape[0] != 2 * b:
        raise ValueError(f"band of {ab.shape[0] - 1} super-diagonals is not block-tridiagonal with {b}x{b} blocks")
    if not (overwrite and ab.dtype == np.float64 and ab.flags.f_contiguous and ab.flags.writeable):
        ab = np.array(ab, dtype=float, order="F", copy=True)
    trf, _, ctypes = lapack
    N, kd = ab.shape[1], ab.shape[0] - 1
    if N == 0:
        raise ValueError("empty system")
    info = ctypes.c_int64(0)
    trf(b"U", _i64(ctypes, N), _i64(ctypes, kd), ctypes.c_void_p(ab.ctypes.data), _i64(ctypes, kd + 1),
        ctypes.byref(info), ctypes.c_size_t(1))
    # a NaN anywhere reaches the factor's diagonal, which LAPACK's positivity test lets pass
    if info.value != 0 or not np.isfinite(ab[kd]).all():
        raise LinAlgError("Matrix is not positive definite")
    return BandFactor(ab, N // b, b)


def factor(D: np.ndarray, U: np.ndarray) -> Factor | BandFactor:
    """Factor the block-tridiagonal SPD matrix with diagonal blocks D (n, b, b) and upper
    blocks U (n-1, b, b) (``U[i] = A[i, i+1]``).  The inputs are not changed."""
    D = np.asarray(D, dtype=float)
    U = np.asarray(U, dtype=float)
    n, b = D.shape[0], D.shape[1]
    if n == 0:
        raise ValueError("empty system")
    if _lapack() is not None:
        return factor_upper(pack_upper(D, U), b, overwrite=True)
    return factor_reduction(D, U)


def factor_reduction(D: np.ndarray, U: np.ndarray) -> Factor:
    """``factor`` by block cyclic reduction in numpy (module docstring)."""
    D = np.asarray(D, dtype=float)
    U = np.asarray(U, dtype=float)
    n, b = D.shape[0], D.shape[1]
    if n == 0:
        raise ValueError("empty system")
    rounds = []
    while D.shape[0] > DENSE_TAIL_BLOCKS:
        m = D.shape[0]
        ne, no = (m + 1) // 2, m // 2  # even blocks kept; odd ones 1, 3, ... eliminated
        r = ne - 1  # odd blocks with a right neighbour
        Li = _inv_cholesky(D[1::2])
        C = np.zeros((no, b, 2 * b))
        C[:, :, :b] = _t(U[0::2])  # A[i, i-1] = U[i-1]^T
        C[:r, :, b:] = U[1::2]  # A[i, i+1]
        G = Li @ C
        S = _t(G) @ G  # [[G_l^T G_l, G_l^T G_r], [., G_r^T G_r]]
        Dn = D[0::2].copy()
        Dn[:no] -= S[:, :b, :b]
        Dn[1:] -= S[:r, b:, b:]
        U = -S[:r, :b, b:]
        D = 0.5 * (Dn + _t(Dn))  # symmetric to the last bit: the next Cholesky reads one triangle
        rounds.append(Round(Li, G))
    last = _inv_cholesky(_dense(D, U)[None])[0]
    if not np.isfinite(last).all():  # numpy's batched Cholesky passes NaN through
        raise LinAlgError("Matrix is not positive definite")
    return Factor(tuple(rounds), last, n, b)


def _dense(D: np.ndarray, U: np.ndarray) -> np.ndarray:
    """The block-tridiagonal matrix (m b, m b) as a dense array."""
    m, b = D.shape[0], D.shape[1]
    A = np.zeros((m, b, m, b))
    k = np.arange(m)
    A[k, :, k, :] = D
    A[k[:-1], :, k[1:], :] = U
    A[k[1:], :, k[:-1], :] = _t(U)
    return A.reshape(m * b, m * b)


def factor_band(ab: np.ndarray, b: int) -> Factor | BandFactor:
    """``factor`` of the matrix in LAPACK's upper band form ab (2b, n b) (not changed)."""
    return factor_upper(ab, b)


def solve(F: Factor | BandFactor, rhs: np.ndarray) -> np.ndarray:
    """x with A x = rhs for A factored in F; rhs (n b,) or (n b, k) (block by block, as the state)."""
    rhs = np.asarray(rhs, dtype=float)
    shape = rhs.shape
    if isinstance(F, BandFactor):
        _, trs, ctypes = _lapack()
        x = np.array(rhs.reshape(len(rhs), -1), order="F", copy=True)
        N, kd = F.ab.shape[1], F.ab.shape[0] - 1
        info = ctypes.c_int64(0)
        trs(b"U", _i64(ctypes, N), _i64(ctypes, kd), _i64(ctypes, x.shape[1]), ctypes.c_void_p(F.ab.ctypes.data),
            _i64(ctypes, kd + 1), ctypes.c_void_p(x.ctypes.data), _i64(ctypes, N), ctypes.byref(info), ctypes.c_size_t(1))
        return x.reshape(shape)
    b = F.b
    y = rhs.reshape(F.n, b, -1)
    cs = []
    for rd in F.rounds:
        c = rd.Li @ y[1::2]  # L_i^-1 b_i
        no = len(c)
        w = _t(rd.G) @ c  # (G_l^T c; G_r^T c)
        yn = y[0::2].copy()
        yn[:no] -= w[:, :b]
        r = len(yn) - 1
        yn[1:] -= w[:r, b:]
        cs.append(c)
        y = yn
    m = len(y)
    x = (F.last_Li.T @ (F.last_Li @ y.reshape(m * b, -1))).reshape(y.shape)
    for rd, c in zip(reversed(F.rounds), reversed(cs)):
        no, ne = len(c), len(x)
        full = np.empty((ne + no,) + x.shape[1:])
        full[0::2] = x
        nb = np.zeros((no, 2 * b, x.shape[2]))  # each odd block's neighbours (right: 0 past the end)
        nb[:, :b] = x[:no]
        nb[:ne - 1, b:] = x[1:]
        full[1::2] = _t(rd.Li) @ (c - rd.G @ nb)
        x = full
    return x.reshape(shape)


def matvec(D: np.ndarray, U: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A v for the block-tridiagonal A given by D (n, b, b), U (n-1, b, b); v (n b,)."""
    b = D.shape[1]
    v = np.asarray(v, dtype=float).reshape(-1, b)
    out = np.einsum("kij,kj->ki", D, v)
    if len(U):
        out[:-1] += np.einsum("kij,kj->ki", U, v[1:])
        out[1:] += np.einsum("kji,kj->ki", U, v[:-1])
    return out.ravel()


def from_upper_band(ab: np.ndarray, b: int) -> tuple[np.ndarray, np.ndarray]:
    """(D, U) of the symmetric matrix in LAPACK's upper band form ``ab`` (2b, n b)
    (``ab[2b - 1 + i - j, j] = A[i, j]`` for j - 2b < i <= j), block size b."""
    bw = ab.shape[0] - 1
    if bw != 2 * b - 1:
        raise ValueError(f"band of {bw} super-diagonals is not block-tridiagonal with {b}x{b} blocks")
    n = ab.shape[1] // b
    i, j = np.meshgrid(np.arange(b), np.arange(b), indexing="ij")
    blk = np.arange(n)[:, None, None]
    # D block k: A[kb + i, kb + j] for i <= j, mirrored
    Du = np.where(i <= j, ab[np.where(i <= j, bw + i - j, bw)[None], blk * b + j[None]], 0.0)
    D = Du + np.where(i > j, 1.0, 0.0) * _t(Du)
    blk_u = np.arange(n - 1)[:, None, None]
    U = ab[(bw + i - b - j)[None], (blk_u + 1) * b + j[None]]  # A[kb + i, (k+1)b + j]
    return D, U


def upper_band_matvec(ab: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A v for A symmetric in LAPACK's upper band form ``ab`` (bw + 1, N); v (N,)."""
    bw = ab.shape[0] - 1
    v = np.asarray(v, dtype=float)
    out = ab[bw] * v
    for d in range(1, min(bw, len(v) - 1) + 1):
        a = ab[bw - d, d:]  # A[j - d, j]
        out[:-d] += a * v[d:]
        out[d:] += a * v[:-d]
    return out

