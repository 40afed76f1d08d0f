"""Both solver paths reach the same minimum; warm starts save iterations; the band is right."""

import dataclasses

import numpy as np
import pytest

from posefix.core import solver as S
from posefix.core import terms as T
from tests.unit.engine_helpers import random_terms


@pytest.mark.parametrize("loss", ["cauchy", "huber", "soft_l1", "none"])
def test_banded_and_scipy_reach_the_same_cost(loss):
    terms = random_terms(k=80, loss=loss, n_user=6)
    x_b, r_b = S.solve_banded(terms)
    x_s, r_s = S.solve_scipy(terms)
    assert r_b.status == "converged", r_b.message
    assert abs(r_b.cost - r_s.cost) <= 1e-6 * r_s.cost
    assert r_b.cost < sum(r_b.cost_before.values())
    assert set(r_b.cost_after) == set(T.TERM_NAMES)
    # and the solution is a stationary point of the cost: the gradient vanishes
    ev = T.evaluate(terms, x_b)
    _, _, g = T.normal_equations(terms, ev)
    assert np.max(np.abs(g)) < 1e-4


def test_packed_band_solves_like_the_dense_matrix():
    terms = random_terms(k=7)
    ev = T.evaluate(terms, T.initial_state(terms) + 0.01)
    D, U, g = T.normal_equations(terms, ev)
    H = np.zeros((42, 42))
    for i in range(7):
        H[6 * i:6 * i + 6, 6 * i:6 * i + 6] = D[i]
    for i in range(6):
        H[6 * i:6 * i + 6, 6 * i + 6:6 * i + 12] = U[i]
        H[6 * i + 6:6 * i + 12, 6 * i:6 * i + 6] = U[i].T
    from scipy.linalg import solveh_banded

    dx = solveh_banded(S.pack_banded(D, U, 1e-3 * np.diag(H)), g)
    assert np.allclose((H + np.diag(1e-3 * np.diag(H))) @ dx, g)
    v = np.random.default_rng(0).normal(size=42)
    assert np.allclose(S.banded_matvec(D, U, v), H @ v)


def test_warm_start_after_one_more_edit_needs_fewer_iterations():
    terms = random_terms(k=300, n_user=6, seed=4)
    x_prev, r_prev = S.solve_banded(terms)
    # one more edit: keyframe 150 pulled 3 m east
    more = dataclasses.replace(
        terms,
        user_idx=np.append(terms.user_idx, 150),
        user_c_m=np.vstack([terms.user_c_m, x_prev.reshape(-1, 6)[150, :3] + [3.0, 0.0, 0.0]]),
        user_w=np.vstack([terms.user_w, [2.0, 2.0, 0.0]]),
    )
    _, cold = S.solve_banded(more)
    _, warm = S.solve_banded(more, x0=x_prev)
    assert warm.iterations < cold.iterations
    assert abs(warm.cost - cold.cost) <= 1e-6 * cold.cost


def test_result_reports_status_message_and_time():
    terms = random_terms(k=20)
    _, r = S.solve_banded(terms, max_iterations=1)
    assert r.status == "max_iterations" and "1 iterations" in r.message
    assert r.time_s > 0 and r.iterations == 1
    assert set(r.to_json()) >= {"status", "message", "iterations", "cost_before", "cost_after", "time_s"}
    with pytest.raises(ValueError, match="unknown solver"):
        S.solve(terms, method="magic")


def test_windowed_solve_with_held_boundaries_matches_the_full_solve_locally():
    terms = random_terms(k=400, n_user=8, seed=6)
    x_star, _ = S.solve_banded(terms)
    more = dataclasses.replace(
        terms,
        user_idx=np.append(terms.user_idx, 200),
        user_c_m=np.vstack([terms.user_c_m, x_star.reshape(-1, 6)[200, :3] + [2.0, 1.0, 0.0]]),
        user_w=np.vstack([terms.user_w, [2.0, 2.0, 0.0]]),
    )
    changed = T.changed_keyframes(more, terms)
    assert np.flatnonzero(changed).tolist() == [200]
    x_full, _ = S.solve_banded(more, x0=x_star)
    lo, hi = 120, 280
    sub = T.window_terms(more, lo, hi)
    fixed = np.zeros(hi - lo + 1, dtype=bool)
    fixed[[0, -1]] = True
    x_sub, r = S.solve_banded(sub, x_star.reshape(-1, 6)[lo:hi + 1].ravel(), fixed=fixed)
    x_sub = x_sub.reshape(-1, 6)
    assert np.allclose(x_sub[[0, -1]], x_star.reshape(-1, 6)[[lo, hi]])  # held
    near = slice(200 - lo - 30, 200 - lo + 31)
    assert np.max(np.abs(x_sub[near, :3] - x_full.reshape(-1, 6)[170:231, :3])) < 0.05
    assert r.status == "converged"


def test_local_newton_steps_reach_the_damped_solve_of_the_same_window():
    terms = random_terms(k=400, n_user=8, seed=7)
    x_star, _ = S.solve_banded(terms)
    more = dataclasses.replace(
        terms,
        user_idx=np.append(terms.user_idx, 200),
        user_c_m=np.vstack([terms.user_c_m, x_star.reshape(-1, 6)[200, :3] + [6.0, -4.0, 0.0]]),
        user_w=np.vstack([terms.user_w, [2.0, 2.0, 0.0]]),
    )
    lo, hi = 100, 300
    sub = T.window_terms(more, lo, hi)
    fixed = np.zeros(hi - lo + 1, dtype=bool)
    fixed[[0, -1]] = True
    x0 = x_star.reshape(-1, 6)[lo:hi + 1].ravel()
    x_lm, r_lm = S.solve_banded(sub, x0, fixed=fixed)
    out = S.solve_local_newton(sub, x0, fixed=fixed)
    assert out is not None
    x_nt, r_nt = out
    assert np.allclose(x_nt.reshape(-1, 6)[[0, -1]], x0.reshape(-1, 6)[[0, -1]])  # held
    assert np.max(np.abs(x_nt.reshape(-1, 6)[:, :3] - x_lm.reshape(-1, 6)[:, :3])) < 2e-3
    assert abs(r_nt.cost - r_lm.cost) <= 1e-6 * r_lm.cost
    assert r_nt.cost < sum(r_nt.cost_before.values())
    # from far away (a start it cannot settle from in two steps) it declines rather than guess
    assert S.solve_local_newton(sub, x0 + 50.0, fixed=None, max_steps=2) is None
