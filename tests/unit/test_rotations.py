"""Rotation helpers checked by identities on random inputs."""

import numpy as np

from posefix.core import rotations as rot

RNG = np.random.default_rng(3)


def random_phi(n=200, scale=1.0):
    phi = RNG.normal(0, scale, (n, 3))
    norms = np.linalg.norm(phi, axis=1, keepdims=True)
    return np.where(norms > 3.0, phi / norms * 3.0, phi)  # keep below pi


def test_exp_log_round_trip_including_tiny_angles():
    for scale in (1.0, 1e-3, 1e-9):
        phi = random_phi(scale=scale)
        assert np.allclose(rot.log_quat(rot.exp_quat(phi)), phi, atol=1e-12, rtol=1e-9)
    assert np.allclose(rot.log_quat(np.array([[1.0, 0, 0, 0]])), 0.0)


def test_quaternion_matrix_round_trip_and_orthonormal():
    q = rot.normalize_quat(RNG.normal(size=(300, 4)))
    R = rot.quat_to_matrix(q)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(rot.matrix_to_quat(R), q, atol=1e-12)


def test_product_inverse_and_rotate_agree_with_matrices():
    a = rot.normalize_quat(RNG.normal(size=(50, 4)))
    b = rot.normalize_quat(RNG.normal(size=(50, 4)))
    v = RNG.normal(size=(50, 3))
    assert np.allclose(rot.quat_to_matrix(rot.quat_multiply(a, b)), rot.quat_to_matrix(a) @ rot.quat_to_matrix(b))
    ident = rot.quat_multiply(rot.quat_conjugate(a), a)
    assert np.allclose(np.abs(ident[:, 0]), 1.0)
    assert np.allclose(rot.rotate(a, v), np.einsum("nij,nj->ni", rot.quat_to_matrix(a), v))


def test_right_jacobian_definition_and_inverse():
    phi = random_phi(100, 0.8)
    d = RNG.normal(0, 1e-6, (100, 3))
    lhs = rot.exp_matrix(phi + d)
    rhs = rot.exp_matrix(phi) @ rot.exp_matrix(np.einsum("nij,nj->ni", rot.right_jacobian(phi), d))
    assert np.allclose(lhs, rhs, atol=1e-11)
    assert np.allclose(rot.right_jacobian(phi) @ rot.right_jacobian_inverse(phi), np.eye(3), atol=1e-10)
    assert np.allclose(rot.right_jacobian(np.zeros((1, 3))), np.eye(3))


def test_log_perturbation_identities():
    phi = random_phi(50, 0.8)
    d = RNG.normal(0, 1e-6, (50, 3))
    R = rot.exp_matrix(phi)
    right = rot.log_matrix(R @ rot.exp_matrix(d)) - phi
    left = rot.log_matrix(rot.exp_matrix(d) @ R) - phi
    assert np.allclose(right, np.einsum("nij,nj->ni", rot.right_jacobian_inverse(phi), d), atol=1e-11)
    assert np.allclose(left, np.einsum("nij,nj->ni", rot.left_jacobian_inverse(phi), d), atol=1e-11)


def test_slerp_endpoints_midpoint_and_yaw():
    a = rot.exp_quat(np.array([[0, 0, 0.2]]))
    b = rot.exp_quat(np.array([[0, 0, 1.0]]))
    assert np.allclose(rot.slerp_quat(a, b, np.array([0.0])), a)
    assert np.allclose(rot.slerp_quat(a, b, np.array([1.0])), b)
    assert np.allclose(rot.yaw_rad(rot.slerp_quat(a, b, np.array([0.5]))), 0.6)


def test_jacobian_inverses_at_once_equal_each_alone():
    rng = np.random.default_rng(5)
    phi = np.concatenate([rng.standard_normal((200, 3)) * 10.0 ** rng.integers(-8, 1, (200, 1)), np.zeros((2, 3))])
    jr_inv, jl_inv = rot.jacobian_inverses(phi)
    assert np.array_equal(jr_inv, rot.right_jacobian_inverse(phi))
    assert np.array_equal(jl_inv, rot.left_jacobian_inverse(phi))
    assert np.allclose(jr_inv @ rot.right_jacobian(phi), np.eye(3), atol=1e-9)
