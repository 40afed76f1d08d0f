"""Propagation: continuous at keyframes, shape-preserving, distance- or time-weighted."""

import numpy as np
import pytest

from posefix.core import rotations as rot
from posefix.core.propagate import interpolate_rotations, interpolation_fraction, propagate


def curvy(n=2001, rate_hz=100.0):
    t = np.arange(n) / rate_hz
    yaw = 0.3 * np.sin(t / 3.0)
    v = 8.0 + 4.0 * np.sin(t)
    step = np.stack([np.cos(yaw), np.sin(yaw), 0.01 * np.ones(n)], 1) * (v / rate_hz)[:, None]
    p = np.cumsum(step, axis=0)
    q = rot.exp_quat(np.stack([np.zeros(n), np.zeros(n), yaw], 1))
    return t, p, q


def test_keyframes_land_exactly_and_rows_between_are_continuous():
    t, p, q = curvy()
    kf = np.arange(0, len(t), 100)
    kf = np.append(kf, len(t) - 1) if kf[-1] != len(t) - 1 else kf
    rng = np.random.default_rng(1)
    kp = p[kf] + np.cumsum(rng.normal(0, 0.3, (len(kf), 3)), axis=0)
    kq = rot.quat_multiply(rot.exp_quat(rng.normal(0, 0.01, (len(kf), 3))), q[kf])
    for mode in ("distance", "time"):
        out_p, out_q = propagate(t, p, q, kf, kp, kq, mode)
        assert np.allclose(out_p[kf], kp, atol=1e-9)
        assert np.allclose(np.abs(np.einsum("ni,ni->n", out_q[kf], kq)), 1.0, atol=1e-12)
        # no jumps: consecutive corrected samples move about as far as reported ones
        step_out = np.linalg.norm(np.diff(out_p, axis=0), axis=1)
        step_in = np.linalg.norm(np.diff(p, axis=0), axis=1)
        assert np.max(np.abs(step_out - step_in)) < 0.02


def test_a_rigid_correction_keeps_the_shape_exactly():
    t, p, q = curvy()
    kf = np.arange(0, len(t), 100)
    R = rot.exp_matrix(np.array([[0.0, 0.0, 0.05]]))[0]
    shift = np.array([5.0, -3.0, 1.0])
    kp = p[kf] @ R.T + shift
    kq = rot.quat_multiply(rot.matrix_to_quat(R[None]), q[kf])
    out_p, out_q = propagate(t, p, q, kf, kp, kq)
    assert np.allclose(out_p, p @ R.T + shift, atol=1e-9)
    assert np.allclose(rot.quat_to_matrix(out_q), R @ rot.quat_to_matrix(q), atol=1e-12)


def test_no_correction_changes_nothing():
    t, p, q = curvy(501)
    kf = np.array([0, 120, 380, 500])
    out_p, out_q = propagate(t, p, q, kf, p[kf], q[kf])
    assert np.allclose(out_p, p, atol=1e-12) and np.allclose(out_q, q, atol=1e-12)


def test_distance_weighting_puts_no_correction_on_a_stopped_vehicle():
    t = np.arange(300) / 100.0
    x = np.concatenate([np.linspace(0, 10, 100), np.full(100, 10.0), np.linspace(10, 20, 100)])
    p = np.stack([x, np.zeros(300), np.zeros(300)], 1)
    seg, a = interpolation_fraction(t, np.abs(np.concatenate([[0], np.cumsum(np.diff(x))])), np.array([0, 299]), "distance")
    assert np.allclose(a[100:200], a[100])  # stopped: no progress, no change in the share of correction
    _, a_t = interpolation_fraction(t, None, np.array([0, 299]), "time")
    assert np.allclose(a_t, t / t[-1])
    with pytest.raises(ValueError, match="distance or time|'distance' or 'time'"):
        interpolation_fraction(t, None, np.array([0, 299]), "speed")


def test_rotation_interpolation_matches_slerp_for_small_and_large_steps():
    rng = np.random.default_rng(2)
    for scale in (0.001, 0.5):
        qk = rot.exp_quat(np.cumsum(rng.normal(0, scale, (20, 3)), axis=0))
        seg = np.repeat(np.arange(19), 7)
        alpha = np.tile(np.linspace(0, 1, 7, endpoint=False), 19)
        got = interpolate_rotations(qk, seg, alpha)
        want = rot.slerp_quat(qk[seg], qk[seg + 1], alpha)
        assert np.allclose(np.abs(np.einsum("ni,ni->n", got, want)), 1.0, atol=1e-12)


def test_block_evaluation_equals_the_row_by_row_formula():
    """Runs of equal segments are evaluated block-wise; irregular ones row by row: same numbers."""
    from posefix.core.propagate import propagate_corrections, segment_blocks

    rng = np.random.default_rng(7)
    n = 5000
    t = np.cumsum(rng.uniform(0.005, 0.015, n))
    p = np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0)
    q = rot.normalize_quat(rng.normal(size=(n, 4)))
    # a regular stretch, a few extra keyframes (edits) that break it, rows before the first keyframe
    kf = np.unique(np.r_[np.arange(13, n, 100), [777, 2345, 2346, 4100], n - 1])
    blocks, rest = segment_blocks(kf, n)
    assert len(blocks) >= 2 and 0 < len(rest) < n // 4
    kp = p[kf] + rng.normal(0, 2, (len(kf), 3))
    c = rot.exp_quat(rng.normal(0, 0.2, (len(kf), 3)))  # wide corrections: some segments take true slerp
    got_p, seg, alpha = propagate_corrections(t, p, kf, kp, c, "time")
    M = rot.quat_to_matrix(c)
    a, b = seg, seg + 1
    chord = (1 - alpha)[:, None] * p[kf[a]] + alpha[:, None] * p[kf[b]]
    want_p = (1 - alpha)[:, None] * kp[a] + alpha[:, None] * kp[b] + np.einsum("nij,nj->ni", M[a], p - chord)
    assert np.max(np.abs(got_p - want_p)) < 1e-9
    blockwise = interpolate_rotations(c, seg, alpha, then_multiply_wxyz=q, kf_index=kf)
    rowwise = interpolate_rotations(c, seg, alpha, then_multiply_wxyz=q)
    assert np.max(np.abs(np.abs(np.einsum("ni,ni->n", blockwise, rowwise)) - 1.0)) < 1e-12
    assert np.max(np.abs(interpolate_rotations(c, seg, alpha, kf_index=kf) - interpolate_rotations(c, seg, alpha))) < 1e-12
