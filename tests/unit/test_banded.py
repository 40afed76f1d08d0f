"""The numpy block-tridiagonal solver (core/banded.py) and running filters (core/filters.py)
against scipy's LAPACK banded Cholesky, ndimage filters and chdtri, on random inputs."""

import numpy as np
import pytest
from scipy.linalg import solveh_banded
from scipy.ndimage import median_filter, minimum_filter1d
from scipy.special import chdtri

from posefix.core import banded
from posefix.core.filters import chi2_upper_quantile, running_median, running_min
from posefix.core.solver import pack_banded


def random_system(rng, n: int, b: int, ridge: float = 1.0):
    """J^T J + ridge I of rows r_k = A_k x_k + B_k x_k+1: SPD, block-tridiagonal."""
    A, B = rng.normal(size=(n, b, b)), rng.normal(size=(n - 1, b, b))
    D = np.einsum("kji,kjl->kil", A, A) + ridge * np.eye(b)
    D[1:] += np.einsum("kji,kjl->kil", B, B)
    U = np.einsum("kji,kjl->kil", A[:-1], B)
    return D, U


# banded.factor calls numpy's own LAPACK where it finds it; the cyclic reduction stands in elsewhere
FACTORS = [banded.factor, banded.factor_reduction]


def test_numpy_wheel_lapack_is_found():
    # this project's numpy wheels ship it: the fast path must not fall back silently here
    assert banded._lapack() is not None
    assert isinstance(banded.factor(*random_system(np.random.default_rng(0), 5, 6)), banded.BandFactor)


@pytest.mark.parametrize("n", [1, 2, 3, 7, 8, 9, 17, 121, 1500])
@pytest.mark.parametrize("b", [3, 6])
@pytest.mark.parametrize("factor", FACTORS)
def test_solve_matches_lapack_banded_cholesky(n, b, factor):
    rng = np.random.default_rng(n * 10 + b)
    D, U = random_system(rng, n, b)
    rhs = rng.normal(size=(n * b, 3))
    x = banded.solve(factor(D, U), rhs)
    ab = np.zeros((2 * b, n * b))  # LAPACK upper band of the same matrix, built entry by entry
    dense = np.zeros((n * b, n * b))
    for k in range(n):
        dense[k * b:(k + 1) * b, k * b:(k + 1) * b] = D[k]
        if k < n - 1:
            dense[k * b:(k + 1) * b, (k + 1) * b:(k + 2) * b] = U[k]
            dense[(k + 1) * b:(k + 2) * b, k * b:(k + 1) * b] = U[k].T
    for j in range(n * b):
        for i in range(max(0, j - 2 * b + 1), j + 1):
            ab[2 * b - 1 + i - j, j] = dense[i, j]
    ref = solveh_banded(ab, rhs)
    assert np.allclose(x, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    assert np.allclose(dense @ x, rhs, atol=1e-10 * np.abs(rhs).max())
    D2, U2 = banded.from_upper_band(ab, b)
    assert np.array_equal(D2, D) and np.array_equal(U2, U)
    v = rng.normal(size=n * b)
    assert np.allclose(banded.upper_band_matvec(ab, v), dense @ v, rtol=1e-12, atol=1e-12)
    assert np.allclose(banded.matvec(D, U, v), dense @ v, rtol=1e-12, atol=1e-12)
    assert np.allclose(banded.solve(factor(D, U), rhs[:, 0]), x[:, 0])
    assert np.array_equal(banded.pack_upper(D, U), ab)


def test_large_batches_take_the_entry_by_entry_path():
    rng = np.random.default_rng(3)
    n = 2 * banded.BATCHED_LAPACK_BELOW + 5
    D, U = random_system(rng, n, 6)
    rhs = rng.normal(size=6 * n)
    x = banded.solve(banded.factor_reduction(D, U), rhs)
    assert np.allclose(x, solveh_banded(pack_banded(D, U), rhs), rtol=1e-9, atol=1e-12)


def test_long_systems_agree_with_lapack():
    rng = np.random.default_rng(4)
    n = 20_000
    D, U = random_system(rng, n, 6)
    rhs = rng.normal(size=(6 * n, 2))
    ref = solveh_banded(pack_banded(D, U), rhs)
    x = banded.solve(banded.factor_band(pack_banded(D, U), 6), rhs)
    assert np.allclose(x, ref, rtol=1e-9, atol=1e-12)
    assert np.allclose(banded.solve(banded.factor_reduction(D, U), rhs), ref, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("n", [1, 5, 3000])
@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize("bad", ["negative", "nan"])
def test_not_positive_definite_raises(n, factor, bad):
    D, U = random_system(np.random.default_rng(1), n, 6)
    if bad == "negative":
        D[n // 2] = -np.eye(6)
    elif n > 1:
        U[n // 2 - 1, 1, 4] = np.nan
    else:
        D[0, 1, 4] = D[0, 4, 1] = np.nan
    with pytest.raises(banded.LinAlgError):
        factor(D, U)


def test_solver_band_form_round_trips():
    D, U = random_system(np.random.default_rng(2), 40, 6)
    D2, U2 = banded.from_upper_band(pack_banded(D, U), 6)
    assert np.array_equal(D2, D) and np.array_equal(U2, U)


@pytest.mark.parametrize("k", [1, 2, 5, 100, 1000])
@pytest.mark.parametrize("size", [1, 2, 4, 5, 9, 60, 61])
def test_running_filters_match_scipy_nearest_mode(k, size):
    rng = np.random.default_rng(k + size)
    x = rng.normal(size=(k, 2))
    x[rng.random((k, 2)) < 0.1] = 5.0  # ties and outliers
    assert np.array_equal(running_median(x, size), median_filter(x, size=(size, 1), mode="nearest"))
    assert np.array_equal(running_median(x[:, 0], size), median_filter(x[:, 0], size, mode="nearest"))
    assert np.array_equal(running_min(x[:, 1], size), minimum_filter1d(x[:, 1], size, mode="nearest"))


@pytest.mark.parametrize("df", [2, 4, 10, 72, 720])
@pytest.mark.parametrize("p", [0.001, 0.01, 0.5, 0.99])
def test_chi2_quantile_matches_chdtri(df, p):
    assert chi2_upper_quantile(df, p) == pytest.approx(chdtri(df, p), rel=1e-10)


def test_chi2_quantile_refuses_odd_degrees():
    with pytest.raises(ValueError):
        chi2_upper_quantile(3, 0.01)
