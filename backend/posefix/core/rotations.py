"""Rotations: unit quaternions (w, x, y, z), rotation matrices and rotation vectors.

Everything is vectorised over a leading axis: ``q_wxyz`` has shape (n, 4), rotation
vectors ``phi_rad`` shape (n, 3), matrices ``R`` shape (n, 3, 3).  A quaternion
``q_body_to_enu_wxyz`` rotates body-frame vectors into ENU: ``v_enu = R(q) v_body``.

Lie-group conventions (SO(3)), following Sola, Deray & Atchuthan, "A micro Lie theory
for state estimation in robotics" (2018):

* ``exp(phi) = I + sin|phi|/|phi| [phi]x + (1 - cos|phi|)/|phi|^2 [phi]x^2``  (Rodrigues)
* right Jacobian ``Jr(phi)``: ``exp(phi + d) ~= exp(phi) exp(Jr(phi) d)``
* ``log(R exp(d)) ~= log(R) + Jr^-1(log R) d`` and ``log(exp(d) R) ~= log(R) + Jl^-1(log R) d``
  with ``Jl(phi) = Jr(-phi)``.

Small-angle branches use Taylor series so every function is smooth through zero.
"""

from __future__ import annotations

import numpy as np

_SMALL_RAD = 1e-4


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` of v, shape (n, 3) -> (n, 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def normalize_quat(q_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternions with w >= 0 (one representative of +-q), shape (n, 4)."""
    q = np.asarray(q_wxyz, dtype=float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm == 0.0):
        raise ValueError("zero quaternion cannot be normalised")
    q = q / norm
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_multiply(a_wxyz: np.ndarray, b_wxyz: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply b first, then a), broadcasting over rows."""
    a = np.asarray(a_wxyz, dtype=float)
    b = np.asarray(b_wxyz, dtype=float)
    # components as views (np.moveaxis costs more than the product on a few hundred rows)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q_wxyz: np.ndarray) -> np.ndarray:
    """Inverse of unit quaternions."""
    q = np.array(q_wxyz, dtype=float, copy=True)
    q[..., 1:] *= -1.0
    return q


def quat_to_matrix(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions, (n, 4) -> (n, 3, 3)."""
    q = np.asarray(q_wxyz, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.shape(w) + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w >= 0) of rotation matrices, (n, 3, 3) -> (n, 4).

    Shepperd's method: pick the largest of the four squared components so the
    division is always well conditioned.
    """
    R = np.asarray(R, dtype=float)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    cand = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    k = np.argmax(cand, axis=-1)
    s = 2.0 * np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300))
    q = np.empty(R.shape[:-2] + (4,))
    d21, d12 = R[..., 2, 1], R[..., 1, 2]
    d02, d20 = R[..., 0, 2], R[..., 2, 0]
    d10, d01 = R[..., 1, 0], R[..., 0, 1]
    q0 = np.stack([0.25 * s, (d21 - d12) / s, (d02 - d20) / s, (d10 - d01) / s], -1)
    q1 = np.stack([(d21 - d12) / s, 0.25 * s, (d01 + d10) / s, (d02 + d20) / s], -1)
    q2 = np.stack([(d02 - d20) / s, (d01 + d10) / s, 0.25 * s, (d12 + d21) / s], -1)
    q3 = np.stack([(d10 - d01) / s, (d02 + d20) / s, (d12 + d21) / s, 0.25 * s], -1)
    q = np.choose(k[..., None], [q0, q1, q2, q3])
    return normalize_quat(q)


def exp_quat(phi_rad: np.ndarray) -> np.ndarray:
    """Quaternions of rotation vectors, (n, 3) -> (n, 4)."""
    phi = np.asarray(phi_rad, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    half = 0.5 * theta
    small = theta < _SMALL_RAD
    safe = np.where(small, 1.0, theta)
    # sin(theta/2)/theta -> 1/2 - theta^2/48 near zero
    k = np.where(small, 0.5 - theta * theta / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half)[..., None], k[..., None] * phi], axis=-1)


def log_quat(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation vectors (angle <= pi) of unit quaternions, (n, 4) -> (n, 3)."""
    q = normalize_quat(q_wxyz)
    w = q[..., 0]
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    theta = 2.0 * np.arctan2(s, w)
    small = s < 1e-8
    # theta/s -> 2/w near zero (w ~ 1)
    k = np.where(small, 2.0 / np.where(small, w, 1.0), theta / np.where(small, 1.0, s))
    return k[..., None] * v


def exp_matrix(phi_rad: np.ndarray) -> np.ndarray:
    """Rotation matrices of rotation vectors (Rodrigues), (n, 3) -> (n, 3, 3)."""
    return quat_to_matrix(exp_quat(phi_rad))


def log_matrix(R: np.ndarray) -> np.ndarray:
    """Rotation vectors of rotation matrices, (n, 3, 3) -> (n, 3)."""
    return log_quat(matrix_to_quat(R))


def _jacobian_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """a = (1 - cos t)/t^2 and b = (t - sin t)/t^3 with series near zero."""
    small = theta < 1e-3
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, (1.0 - np.cos(t)) / (t * t))
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0, (t - np.sin(t)) / (t * t * t))
    return a, b


def right_jacobian(phi_rad: np.ndarray) -> np.ndarray:
    """Jr(phi) = I - a [phi]x + b [phi]x^2, (n, 3) -> (n, 3, 3)."""
    phi = np.asarray(phi_rad, dtype=float)
    a, b = _jacobian_coefficients(np.linalg.norm(phi, axis=-1))
    K = skew(phi)
    return np.eye(3) - a[..., None, None] * K + b[..., None, None] * (K @ K)


def right_jacobian_inverse(phi_rad: np.ndarray) -> np.ndarray:
    """Jr^-1(phi) = I + [phi]x/2 + (1/t^2 - (1+cos t)/(2 t sin t)) [phi]x^2."""
    return jacobian_inverses(phi_rad)[0]


def left_jacobian_inverse(phi_rad: np.ndarray) -> np.ndarray:
    """Jl^-1(phi) = Jr^-1(-phi)."""
    return right_jacobian_inverse(-np.asarray(phi_rad, dtype=float))


def jacobian_inverses(phi_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Jr^-1(phi), Jl^-1(phi)) at once: [-phi]x = -[phi]x and its square is the same, so the
    two share every term (the same values as the two functions above)."""
    phi = np.asarray(phi_rad, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < 1e-3
    t = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12.0 + theta * theta / 720.0, 1.0 / (t * t) - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    K = skew(phi)
    common = np.eye(3) + c[..., None, None] * (K @ K)
    half = 0.5 * K
    return common + half, common - half


def rotate(q_wxyz: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (n, 3) by quaternions (n, 4) without building matrices.

    Uses ``v' = v + 2 w (u x v) + 2 u x (u x v)`` with u the vector part.
    """
    q = np.asarray(q_wxyz, dtype=float)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def slerp_quat(a_wxyz: np.ndarray, b_wxyz: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation ``a exp(frac log(a^-1 b))``, frac (n,) in [0, 1]."""
    rel = quat_multiply(quat_conjugate(a_wxyz), b_wxyz)
    phi = log_quat(rel)
    return quat_multiply(a_wxyz, exp_quat(np.asarray(frac, dtype=float)[..., None] * phi))


def yaw_rad(q_body_to_enu_wxyz: np.ndarray) -> np.ndarray:
    """Heading of the body x axis in ENU, radians counter-clockwise from east."""
    x_enu = rotate(q_body_to_enu_wxyz, np.broadcast_to([1.0, 0.0, 0.0], np.shape(q_body_to_enu_wxyz)[:-1] + (3,)))
    return np.arctan2(x_enu[..., 1], x_enu[..., 0])
