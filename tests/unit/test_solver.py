"""Both solver paths reach the same minimum; warm starts save iterations; the band is right."""

import dataclasses

import numpy as np
import pytest

from posefix.core import solver as S
from posefix.core import terms as T
from posefix.core.solver_reference import solve, solve_scipy
from tests.unit.engine_helpers import random_terms


@pytest.mark.parametrize("loss", ["cauchy", "huber", "soft_l1", "none"])
def test_banded_and_scipy_reach_the_same_cost(loss):
    terms = random_terms(k=80, loss=loss, n_user=6)
    x_b, r_b = S.solve_banded(terms)
    x_s, r_s = solve_scipy(terms)
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
        solve(terms, method="magic")


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


def _one_more_edit(terms, x_star, kf=150, shift=(4.0, -3.0, 0.0)):
    """``terms`` plus a 2-D edit pulling keyframe ``kf`` ``shift`` metres from the solution."""
    return dataclasses.replace(
        terms,
        user_idx=np.append(terms.user_idx, kf),
        user_c_m=np.vstack([terms.user_c_m, x_star.reshape(-1, 6)[kf, :3] + shift]),
        user_w=np.vstack([terms.user_w, [2.0, 2.0, 0.0]]),
    )


def _window(terms, lo, hi):
    fixed = np.zeros(hi - lo + 1, dtype=bool)
    fixed[[0, -1]] = True
    return T.window_terms(terms, lo, hi), fixed


def test_kept_linearisation_is_the_fresh_model_of_the_relative_and_gravity_terms():
    terms = random_terms(k=60, n_user=5, seed=8)
    x, r = S.solve_banded(terms, linearise=True)
    lin = r.extra["linearisation"]
    assert lin.matches(terms) and np.array_equal(lin.x_lin, x)
    ev = T.evaluate(terms, x)
    no_user = dataclasses.replace(terms, user_idx=terms.user_idx[:0], user_c_m=terms.user_c_m[:0],
                                  user_w=terms.user_w[:0])
    D, U, g = T.normal_equations(no_user, dataclasses.replace(
        ev, user_r=ev.user_r[:0], jac={**ev.jac, "user_p": ev.jac["user_p"][:0]}), location=False)
    assert np.allclose(lin.ab, S.pack_banded(D, U), rtol=1e-12, atol=1e-9)
    assert np.allclose(lin.g, g, rtol=1e-12, atol=1e-9)
    costs = ev.costs()
    win = lin.window_costs(0, 59)
    for name in ("relative_translation", "relative_rotation", "gravity"):
        assert win[name] == pytest.approx(costs[name], rel=1e-12)
    # a model with some relative-translation weights changed (edits loosening the shape between
    # them) equals the model built afresh with those weights
    rew = dataclasses.replace(terms, rel_w_t=terms.rel_w_t * np.where(np.arange(59) % 7 == 3, 0.3, 1.0))
    x_lin, ab, g_c = S._model_from_linearisation(rew, lin.window(0, 59))
    D2, U2, g2 = T.normal_equations(rew, T.evaluate(rew, x), location=False)  # user terms included
    assert np.allclose(ab, S.pack_banded(D2, U2), rtol=1e-10, atol=1e-8)
    assert np.allclose(g_c, g2, rtol=1e-10, atol=1e-8)
    assert lin.window_costs(0, 59, rew.rel_w_t)["relative_translation"] == pytest.approx(
        T.evaluate(rew, x, with_jac=False).costs()["relative_translation"], rel=1e-12)
    assert not lin.matches(dataclasses.replace(terms, grav_w=terms.grav_w * 2.0))


def _solved_then_one_more_edit(seed: int, lo: int = 90, hi: int = 210):
    """A 300-keyframe problem solved with its linearisation kept, then one more edit: the
    window lo..hi of the new problem (terms and held ends) beside the old solution."""
    terms = random_terms(k=300, n_user=6, seed=seed)
    x_star, r = S.solve_banded(terms, linearise=True)
    sub, fixed = _window(_one_more_edit(terms, x_star), lo, hi)
    return x_star, r.extra["linearisation"], sub, fixed, lo, hi


def test_local_newton_from_the_kept_linearisation_matches_linearising_the_window():
    x_star, lin, sub, fixed, lo, hi = _solved_then_one_more_edit(seed=9)
    x0 = x_star.reshape(-1, 6)[lo:hi + 1].ravel()
    x_fresh, r_fresh = S.solve_local_newton(sub, x0, fixed)
    x_kept, r_kept = S.solve_local_newton(sub, x0, fixed, linearisation=lin.window(lo, hi))
    # the same model (built at the same state): the same Newton steps up to rounding
    assert np.max(np.abs(x_kept - x_fresh)) < 1e-9
    assert r_kept.iterations == r_fresh.iterations
    assert r_kept.cost == pytest.approx(r_fresh.cost, rel=1e-12)
    assert r_kept.cost_before == pytest.approx(r_fresh.cost_before, rel=1e-12)


def test_a_held_keyframe_moved_since_the_linearisation_still_pulls_its_neighbour():
    # a drag: the window solved before moved keyframes away from the kept linearisation point,
    # among them the one now held at the boundary of the next window
    x_star, lin, sub, fixed, lo, hi = _solved_then_one_more_edit(seed=10)
    x0 = x_star.reshape(-1, 6)[lo:hi + 1].copy()
    x0[:12, :3] += [0.8, -0.5, 0.0]  # held keyframe and its neighbours moved earlier (positions only)
    x0[0, :3] += [0.3, 0.2, 0.0]  # the held one a little more: its relative term to the next is stretched
    x0 = x0.ravel()
    x_fresh, _ = S.solve_local_newton(sub, x0, fixed)
    x_kept, _ = S.solve_local_newton(sub, x0, fixed, linearisation=lin.window(lo, hi))
    # the models differ only at second order (positions moved, orientations did not): 2e-5 m here;
    # without the held keyframe's pull on its neighbour they differ by 1.4 mm
    assert np.max(np.abs((x_kept - x_fresh).reshape(-1, 6)[:, :3])) < 2e-4
    assert np.allclose(x_kept.reshape(-1, 6)[0], x0.reshape(-1, 6)[0])  # held


def test_chord_steps_land_where_newton_steps_do(monkeypatch):
    terms = random_terms(k=300, n_user=6, seed=7)
    x_star, r = S.solve_banded(terms, linearise=True)
    more = _one_more_edit(terms, x_star, shift=(6.0, -4.0, 0.0))
    sub, fixed = _window(more, 80, 220)
    x0 = x_star.reshape(-1, 6)[80:221].ravel()
    x_chord, r_chord = S.solve_local_newton(sub, x0, fixed, linearisation=r.extra["linearisation"].window(80, 220))
    monkeypatch.setattr(S, "CHORD_AFTER_STEPS", 0.0)  # every step a Newton step
    x_newton, r_newton = S.solve_local_newton(sub, x0, fixed, linearisation=r.extra["linearisation"].window(80, 220))
    assert np.max(np.abs((x_chord - x_newton).reshape(-1, 6)[:, :3])) < 1e-3
    assert r_chord.cost == pytest.approx(r_newton.cost, rel=1e-7)
