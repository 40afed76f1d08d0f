"""Each feature function, step detection and the walk reader's errors."""

import numpy as np
import pytest

from posefix.mapmatch.features import (FeatureSigmas, f_gaussian_position, f_step, heading_errors_from_path,
                                       quantised_increments, rotate_steps)
from posefix.mapmatch.sensors import WalkFormatError, detect_steps, heading_from_rotation_vector, read_walk

OFFSETS = np.array([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1], [1, 1]], dtype=float) * 0.8


def test_quantised_increments_telescope_to_the_rounded_total():
    rng = np.random.default_rng(0)
    steps = rng.normal(0.5, 0.3, size=(40, 2))
    inc = quantised_increments(steps, 0.8)
    assert np.allclose(inc / 0.8, np.round(inc / 0.8))  # lattice moves only
    total = steps.sum(axis=0)
    assert np.all(np.abs(inc.sum(axis=0) - total) <= 0.4 + 1e-9)  # unbiased within half a cell


def test_f1_prefers_the_move_equal_to_the_increment_and_penalises_across_more_than_along():
    sig = FeatureSigmas(len_m=0.3, heading_rad=np.deg2rad(10))
    step = np.array([[0.7, 0.0]])
    f = f_step(OFFSETS, step, np.array([[0.8, 0.0]]), sig)[0]
    assert np.argmax(f) == 1 and np.isclose(f[1], 0.0)
    # Standing still (0.8 m short along) vs going sideways (0.8 m across + 0.8 m short).
    assert f[0] > f[2]
    # Closed form for the stay move: r_along = -0.8, r_across = 0.
    assert np.isclose(f[0], -0.5 * (0.8 / 0.3) ** 2)


def test_f2_rotation_and_heading_error_from_path():
    steps = np.tile([[0.8, 0.0]], (8, 1))
    path = np.vstack([[0.0, 0.0], np.cumsum(rotate_steps(steps, np.deg2rad(30)), axis=0)])
    err = heading_errors_from_path(path, steps, FeatureSigmas(window_steps=5, min_span_m=1.0))
    assert err[0] == 0.0 and np.allclose(err[3:], np.deg2rad(30))
    r = rotate_steps(np.array([[1.0, 0.0]]), np.pi / 2)
    assert np.allclose(r, [[0.0, 1.0]])


def test_f3_f4_gaussian_position():
    p = np.array([[1.0, 2.0], [3.0, 2.0], [1.0, 5.0]])
    f = f_gaussian_position(p, np.array([1.0, 2.0]), np.diag([4.0, 9.0]))
    assert np.allclose(f, [0.0, -0.5 * 4 / 4, -0.5 * 9 / 9])


def test_detect_steps_on_a_synthetic_gait():
    t = np.arange(0, 10_000, 20)  # 50 Hz, 10 s
    a = 9.81 + 2.0 * np.sin(2 * np.pi * 1.8 * t / 1000.0)
    acc = np.column_stack([t, np.zeros_like(a), np.zeros_like(a), a])
    t_ms, f = detect_steps(acc)
    assert abs(len(t_ms) - 18) <= 1
    assert np.allclose(np.median(f), 1.8, atol=0.1)


def test_heading_from_rotation_vector_flat_phone():
    # Rotation about z by +90°: the device y axis points west (heading 180° from east).
    rv = np.array([[0.0, 0.0, np.sin(np.pi / 4)]])
    assert np.isclose(heading_from_rotation_vector(rv)[0], np.pi)
    assert np.isclose(heading_from_rotation_vector(np.zeros((1, 3)))[0], np.pi / 2)  # north


def test_read_walk_names_file_line_and_field(tmp_path):
    p = tmp_path / "bad.txt"
    p.write_text("#\tstartTime:1\n1000\tTYPE_ACCELEROMETER\t0.1\tnot-a-number\t9.8\t3\n")
    with pytest.raises(WalkFormatError) as ei:
        read_walk(p)
    assert "bad.txt:2: field TYPE_ACCELEROMETER" in str(ei.value)


def flat_turning_walk(offset_rad=0.0):
    """A phone held flat turning at 0.2 rad/s for 10 s (50 Hz), starting pointing north."""
    from posefix.mapmatch.sensors import Walk

    t = np.arange(0, 10_000, 20, dtype=float)
    psi = 0.2 * t / 1000.0
    m_world = np.array([0.0, 20.0, -40.0])  # east, north, up (µT)
    c, s = np.cos(psi), np.sin(psi)
    m_dev = np.column_stack([c * m_world[0] + s * m_world[1], -s * m_world[0] + c * m_world[1], np.full_like(psi, m_world[2])])
    half = (psi + offset_rad) / 2.0
    rv = np.column_stack([np.zeros_like(psi), np.zeros_like(psi), np.sin(half)])
    col = lambda a: np.column_stack([t, a])  # noqa: E731
    acc = col(np.tile([0.0, 0.0, 9.81], (t.size, 1)))
    gyro = col(np.tile([0.0, 0.0, 0.2], (t.size, 1)))
    return Walk(path="sim", acc=acc, gyro=gyro, mag=col(m_dev), rotvec=col(rv), wifi=[], waypoints=np.zeros((0, 3))), t, psi


def test_heading_from_gyro_and_magnetometer_follows_the_turn():
    from posefix.mapmatch.sensors import heading_from_gyro_mag

    walk, t, psi = flat_turning_walk()
    th = heading_from_gyro_mag(walk, t)
    err = (th - (np.pi / 2 + psi) + np.pi) % (2 * np.pi) - np.pi
    assert np.max(np.abs(err)) < np.deg2rad(2.0)
    d = heading_from_rotation_vector(walk.rotvec[:, 1:4]) - (np.pi / 2 + psi)
    assert np.allclose(np.angle(np.exp(1j * d)), 0.0, atol=1e-9)


def test_initial_heading_bias_between_rotation_vector_and_gyro_mag():
    from posefix.mapmatch.sensors import initial_heading_bias_gyro_mag

    walk, _, _ = flat_turning_walk(offset_rad=np.deg2rad(10.0))
    assert np.isclose(np.degrees(initial_heading_bias_gyro_mag(walk)), -10.0, atol=1.0)
