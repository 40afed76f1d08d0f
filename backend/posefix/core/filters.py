"""Running median and minimum over samples, and the chi-square quantile the drift tests use (numpy only).

They stand in for ``scipy.ndimage.median_filter`` / ``minimum_filter1d`` (``mode="nearest"``:
the ends repeat the first and last sample; a window of ``size`` samples starting ``size // 2``
before the sample; the median of an even window is its upper middle value, as scipy's rank
filter takes it) and ``scipy.special.chdtri``, so that a correction imports no scipy.
"""

from __future__ import annotations

import math

import numpy as np

CHUNK_ROWS = 1 << 15  # rows per pass: bounds the (rows, size) window copy a partition makes


def _windows(x: np.ndarray, size: int):
    """(k, ..., size) view of the windows of x (k, ...) along axis 0, ends padded by repetition."""
    before, after = size // 2, size - 1 - size // 2
    pad = [(before, after)] + [(0, 0)] * (x.ndim - 1)
    padded = np.pad(x, pad, mode="edge")
    return np.lib.stride_tricks.sliding_window_view(padded, size, axis=0)  # (k, ..., size)


def running_median(x: np.ndarray, size: int) -> np.ndarray:
    """Median of the ``size`` samples around each one along axis 0 of x (k,) or (k, c)."""
    x = np.asarray(x, dtype=float)
    size = max(int(size), 1)
    if size == 1 or len(x) == 0:
        return x.copy()
    w = _windows(x, size)
    out = np.empty_like(x)
    rank = size // 2
    for lo in range(0, len(x), CHUNK_ROWS):
        out[lo:lo + CHUNK_ROWS] = np.partition(w[lo:lo + CHUNK_ROWS], rank, axis=-1)[..., rank]
    return out


def running_min(x: np.ndarray, size: int) -> np.ndarray:
    """Minimum of the ``size`` samples around each one along axis 0 of x (k,) or (k, c)."""
    x = np.asarray(x, dtype=float)
    size = max(int(size), 1)
    if size == 1 or len(x) == 0:
        return x.copy()
    return _windows(x, size).min(axis=-1)


def chi2_upper_quantile(df: int, p: float) -> float:
    """x with P(X > x) = p for X chi-square with an even number ``df`` of degrees of freedom.

    For df = 2m the survival function is the Poisson sum ``exp(-x/2) sum_{i<m} (x/2)^i / i!``
    (exact); it falls monotonically in x, so bisection finds x to machine precision.
    """
    if df <= 0 or df % 2:
        raise ValueError(f"df must be a positive even number, got {df}")
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must lie in (0, 1), got {p}")
    i = np.arange(df // 2)
    log_factorial = np.array([math.lgamma(v + 1.0) for v in i])

    def log_survival(x: float) -> float:
        if x <= 0.0:
            return 0.0
        terms = i * math.log(0.5 * x) - log_factorial
        top = float(terms.max())
        return -0.5 * x + top + math.log(float(np.exp(terms - top).sum()))

    target = math.log(p)
    lo, hi = 0.0, float(df)
    while log_survival(hi) > target:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if log_survival(mid) > target:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return 0.5 * (lo + hi)
