"""Every residual's analytic Jacobian against central finite differences."""

import numpy as np
import pytest

from posefix.core import terms as T
from tests.unit.engine_helpers import random_terms


def _numeric_jacobian(terms, x, h=1e-6):
    f0 = T.evaluate(terms, x, with_jac=False).residual_vector()
    J = np.zeros((f0.size, x.size))
    for j in range(x.size):
        d = np.zeros_like(x)
        d[j] = h
        J[:, j] = (T.evaluate(terms, x + d, with_jac=False).residual_vector()
                   - T.evaluate(terms, x - d, with_jac=False).residual_vector()) / (2 * h)
    return J


@pytest.mark.parametrize("loss", ["none", "huber", "soft_l1", "cauchy"])
def test_every_jacobian_matches_finite_differences(loss):
    terms = random_terms(k=10, loss=loss)
    rng = np.random.default_rng(5)
    x = T.initial_state(terms).reshape(-1, 6)
    x[:, :3] += rng.normal(0, 3.0, (len(x), 3))  # away from the data so robust losses bend
    x[:, 3:] += rng.normal(0, 0.2, (len(x), 3))  # non-trivial rotation perturbations
    x = x.ravel()
    J = T.sparse_jacobian(terms, T.evaluate(terms, x)).toarray()
    Jn = _numeric_jacobian(terms, x)
    assert np.max(np.abs(J - Jn)) < 1e-6 * max(1.0, np.max(np.abs(Jn)))
    # each term separately: the block rows of every term are compared above; check they are not all zero
    assert np.count_nonzero(np.abs(J) > 1e-9) > 0.5 * np.count_nonzero(np.abs(Jn) > 1e-9)


def test_jacobian_at_zero_residual_and_large_outlier():
    terms = random_terms(k=6, loss="cauchy")
    x = T.initial_state(terms).reshape(-1, 6)
    x[:, :3] = terms.loc_g_m  # location residual exactly zero: series branch of the loss
    x[2, :3] += 50.0  # and one 50 m outlier
    x = x.ravel()
    J = T.sparse_jacobian(terms, T.evaluate(terms, x)).toarray()
    assert np.allclose(J, _numeric_jacobian(terms, x), atol=1e-6)


def test_robust_residual_squares_to_the_scipy_loss():
    s = np.array([0.0, 1e-6, 0.5, 3.0, 400.0])
    for loss, rho0 in {
        "none": lambda z: z,
        "huber": lambda z: np.where(z <= 1, z, 2 * np.sqrt(z) - 1),
        "soft_l1": lambda z: 2 * (np.sqrt(1 + z) - 1),
        "cauchy": np.log1p,
    }.items():
        c = 2.0
        assert np.allclose(T.robust_cost(s, loss, c), c * c * rho0(s / (c * c)), rtol=1e-12, atol=1e-15)


def test_reported_poses_cost_nothing_but_location_and_user():
    terms = random_terms(k=8)
    costs = T.evaluate(terms, T.initial_state(terms), with_jac=False).costs()
    assert costs["relative_translation"] < 1e-20
    assert costs["relative_rotation"] < 1e-20
    assert costs["gravity"] < 1e-20
    assert costs["location"] > 0 and costs["user"] > 0


def test_normal_equations_equal_dense_products():
    terms = random_terms(k=9, loss="none")  # with no robust loss the location model is exactly J^T J
    x = T.initial_state(terms) + np.random.default_rng(2).normal(0, 0.1, 54)
    ev = T.evaluate(terms, x)
    J = T.sparse_jacobian(terms, ev).toarray()
    D, U, g = T.normal_equations(terms, ev)
    H = J.T @ J
    for i in range(9):
        assert np.allclose(D[i], H[6 * i:6 * i + 6, 6 * i:6 * i + 6])
    for i in range(8):
        assert np.allclose(U[i], H[6 * i:6 * i + 6, 6 * i + 6:6 * i + 12])
    assert np.allclose(g, J.T @ ev.residual_vector())
    # nothing outside the band
    mask = np.abs(np.subtract.outer(np.arange(54) // 6, np.arange(54) // 6)) > 1
    assert np.all(H[mask] == 0)


def test_location_hessian_is_the_exact_loss_hessian_where_convex():
    terms = random_terms(k=5, loss="cauchy")
    x = T.initial_state(terms).reshape(-1, 6)
    x[:, :3] = terms.loc_g_m + 0.3  # small residuals: the Cauchy loss is convex there
    x = x.ravel()

    def loc_cost(p_flat):
        xx = x.reshape(-1, 6).copy()
        xx[:, :3] = p_flat.reshape(-1, 3)
        return T.evaluate(terms, xx.ravel(), with_jac=False).costs()["location"]

    p0 = x.reshape(-1, 6)[:, :3].ravel()
    h = 1e-4
    H = T.location_hessian(terms, p0.reshape(-1, 3))
    for i in range(2):
        for a in range(3):
            for b in range(3):
                da = np.zeros_like(p0); da[3 * i + a] = h
                db = np.zeros_like(p0); db[3 * i + b] = h
                num = (loc_cost(p0 + da + db) - loc_cost(p0 + da - db) - loc_cost(p0 - da + db) + loc_cost(p0 - da - db)) / (4 * h * h)
                assert abs(num - H[i, a, b]) < 1e-5


def test_a_car_turning_does_not_count_as_sliding_sideways():
    """Sideways motion is measured half-way through the step: a steady turn moves along the chord."""
    from posefix.core import rotations as rot

    rate = np.radians(20.0)  # a tight corner: 20 deg/s at 8 m/s
    k = 8
    yaw = rate * np.arange(k)
    radius = 8.0 / rate
    p = np.stack([radius * np.sin(yaw), radius * (1 - np.cos(yaw)), np.zeros(k)], 1)
    R = rot.exp_matrix(np.stack([np.zeros(k), np.zeros(k), yaw], 1))
    delta = np.einsum("kji,kj->ki", R[:-1], np.diff(p, axis=0))
    dR = np.einsum("kji,kjl->kil", R[:-1], R[1:])
    s, _, side = T.sideways_steps(delta, dR)
    assert np.abs(s[:, 1]).max() < 1e-9 and np.abs(side).max() < 1e-9  # all along the mid-step heading
    assert np.abs(delta[:, 1]).max() > 1.0  # in the frame of the step's start it would look like 1.4 m/s
    out, excess = T.vehicle_motion(delta, dR, np.ones(k - 1), 0.5)
    assert np.all(excess == 0.0) and np.array_equal(out, delta)


def test_sideways_motion_beyond_the_limit_is_taken_out_of_the_step():
    from posefix.core import rotations as rot

    rng = np.random.default_rng(2)
    n = 30
    delta = np.stack([np.full(n, 10.0), rng.normal(0, 0.05, n), rng.normal(0, 0.05, n)], 1)  # a good attitude
    delta[7, 1] = 3.0  # one jump of the pose's error, 3 m sideways in 1 s
    dR = np.tile(np.eye(3), (n, 1, 1))
    out, excess = T.vehicle_motion(delta, dR, np.ones(n), 0.5)
    assert np.flatnonzero(excess).tolist() == [7]
    assert np.hypot(*out[7, 1:]) == pytest.approx(0.5, abs=0.05)  # sideways cut to about 0.5 m/s
    assert out[7, 0] == delta[7, 0]  # forward kept
    assert np.array_equal(np.delete(out, 7, axis=0), np.delete(delta, 7, axis=0))
    off, none = T.vehicle_motion(delta, dR, np.ones(n), 0.0)  # check off
    assert off is delta and np.all(none == 0.0)
    # in a turn the cut is made in the mid-step frame and rotated back
    dR2 = rot.exp_matrix(np.tile([0.0, 0.0, 0.4], (n, 1)))
    out2, ex2 = T.vehicle_motion(delta, dR2, np.ones(n), 0.5)
    _, _, side2 = T.sideways_steps(out2, dR2)
    assert ex2[7] > 2.0 and np.hypot(*side2[7]) < 0.6
    # an attitude that jitters by itself raises the limit: its own noise is not read as jumps
    noisy = delta.copy()
    noisy[:, 1:] = rng.normal(0, 0.8, (n, 2))
    assert np.count_nonzero(T.vehicle_motion(noisy, dR, np.ones(n), 0.5)[1]) <= 1


def test_a_sensor_frame_pitched_against_the_vehicle_is_not_a_jump():
    """A dashboard device pitched 4 degrees shows vertical motion proportional to speed: not error."""
    k = 40
    speed = 10.0 + 8.0 * np.sin(np.arange(k - 1) / 5.0)
    pitch = np.radians(4.0)
    delta = np.stack([speed * np.cos(pitch), np.zeros(k - 1), speed * np.sin(pitch)], 1)
    delta[20, 1] += 3.0  # one real sideways jump of 3 m
    dR = np.tile(np.eye(3), (k - 1, 1, 1))
    _, _, side = T.sideways_steps(delta, dR)
    assert np.abs(np.delete(side, 20, axis=0)).max() < 1e-9
    out, excess = T.vehicle_motion(delta, dR, np.ones(k - 1), 0.5)
    assert np.flatnonzero(excess) == [20] and excess[20] == pytest.approx(2.5)
    assert out[20] == pytest.approx(delta[20] - [0.0, 2.5, 0.0])  # only the jump's excess comes out
