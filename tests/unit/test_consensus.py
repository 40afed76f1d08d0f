"""Consensus maths on known cases: geometric median (Weiszfeld / Vardi-Zhang) and conflicts."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from posefix.tasks.consensus import (
    disagreement_m, edit_conflicts, geometric_median, pairwise_separation_m, track_conflicts,
)


def _objective(y: np.ndarray, pts: np.ndarray) -> float:
    return float(np.linalg.norm(pts - y, axis=1).sum())


def test_median_of_two_points_is_their_midpoint() -> None:
    x = np.array([[[0.0, 0.0]], [[10.0, 0.0]]])
    assert np.allclose(geometric_median(x), [[5.0, 0.0]])


def test_median_of_a_symmetric_triangle_is_its_centre_and_equilateral_fermat_point() -> None:
    s = np.sqrt(3.0)
    pts = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, s]])
    y = geometric_median(pts[:, None, :])[0]
    assert np.allclose(y, [1.0, s / 3], atol=1e-4)


def test_majority_on_one_point_wins_exactly() -> None:
    # three operators agree, one is 50 m off: the median is the agreed point (Vardi-Zhang case)
    x = np.array([[[3.0, 4.0]], [[3.0, 4.0]], [[3.0, 4.0]], [[53.0, 4.0]]])
    assert np.allclose(geometric_median(x), [[3.0, 4.0]], atol=1e-6)


def test_obtuse_triangle_median_is_the_obtuse_vertex() -> None:
    # angle at (0,0) is > 120 degrees: the Fermat point is that vertex
    pts = np.array([[0.0, 0.0], [10.0, 1.0], [-10.0, 1.0]])
    assert np.allclose(geometric_median(pts[:, None, :])[0], [0.0, 0.0], atol=1e-4)


def test_matches_a_generic_minimiser_on_random_clouds() -> None:
    rng = np.random.default_rng(7)
    x = rng.normal(size=(7, 40, 2)) * 5.0 + rng.normal(size=(1, 40, 2)) * 100.0
    y = geometric_median(x, tol_m=1e-7)
    for j in range(40):
        ref = minimize(_objective, x[:, j].mean(axis=0), args=(x[:, j],), method="Nelder-Mead",
                       options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 5000}).x
        assert _objective(y[j], x[:, j]) <= _objective(ref, x[:, j]) + 1e-6


def test_is_robust_one_outlier_cannot_drag_it_far() -> None:
    base = np.array([[[0.0, 0.0]], [[1.0, 0.0]], [[0.0, 1.0]], [[1.0, 1.0]]])
    far = np.concatenate([base, [[[1000.0, 1000.0]]]])
    moved = np.linalg.norm(geometric_median(far) - geometric_median(base))
    assert moved < 1.0


def test_translation_and_rotation_equivariance() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(5, 10, 2)) * 3.0
    theta = 0.7
    r = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    t = np.array([100.0, -40.0])
    y = geometric_median(x, tol_m=1e-9)
    y2 = geometric_median(x @ r.T + t, tol_m=1e-9)
    assert np.allclose(y @ r.T + t, y2, atol=1e-5)


def test_invalid_positions_are_ignored_and_all_invalid_gives_nan() -> None:
    x = np.array([[[0.0, 0.0], [5.0, 5.0]], [[2.0, 0.0], [7.0, 5.0]], [[900.0, 0.0], [9.0, 5.0]]])
    valid = np.array([[True, False], [True, False], [False, False]])
    y = geometric_median(x, valid)
    assert np.allclose(y[0], [1.0, 0.0]) and np.isnan(y[1]).all()


def test_weights_pull_towards_the_heavier_operator() -> None:
    x = np.array([[[0.0, 0.0]], [[10.0, 0.0]], [[0.0, 10.0]]])
    y = geometric_median(x, weights=np.array([5.0, 1.0, 1.0]))
    assert np.allclose(y, [[0.0, 0.0]], atol=1e-6)  # weight >= sum of others: that point


def test_shape_is_checked() -> None:
    with pytest.raises(ValueError, match="shape"):
        geometric_median(np.zeros((3, 2)))


def test_pairwise_separation_and_disagreement() -> None:
    x = np.zeros((3, 4, 2))
    x[1, :, 0] = 3.0
    x[2, :, 1] = 4.0
    sep = pairwise_separation_m(x)
    assert sep.shape == (3, 3, 4) and np.allclose(sep[1, 2], 5.0) and np.allclose(np.diagonal(sep, axis1=0, axis2=1), 0)
    assert np.allclose(disagreement_m(x), 5.0)
    valid = np.ones((3, 4), bool)
    valid[2] = False
    assert np.allclose(disagreement_m(x, valid), 3.0)


def test_track_conflicts_need_enough_consecutive_keyframes() -> None:
    k = 20
    a = np.zeros((k, 2))
    b = np.zeros((k, 2))
    b[5:8, 0] = 6.0    # 3 keyframes 6 m apart
    b[12, 0] = 50.0    # a single spike
    x = np.stack([a, b])
    found = track_conflicts(x, distance_m=5.0, min_keyframes=3)
    assert [(c.a, c.b, c.first, c.last) for c in found] == [(0, 1, 5, 7)]
    assert found[0].max_separation_m == pytest.approx(6.0)
    assert track_conflicts(x, distance_m=5.0, min_keyframes=4) == []
    assert [(c.first, c.last) for c in track_conflicts(x, distance_m=5.0, min_keyframes=1)] == [(5, 7), (12, 12)]
    # exactly at the threshold is not "more than"
    assert track_conflicts(x, distance_m=6.0, min_keyframes=3) == []
    # a deleted keyframe breaks a run
    valid = np.ones((2, k), bool)
    valid[1, 6] = False
    assert track_conflicts(x, distance_m=5.0, min_keyframes=2, valid=valid) == []
    with pytest.raises(ValueError):
        track_conflicts(x, distance_m=0.0, min_keyframes=3)


def test_conflict_running_to_the_last_keyframe_is_found() -> None:
    x = np.zeros((2, 6, 2))
    x[1, 3:, 1] = 10.0
    found = track_conflicts(x, 5.0, 3)
    assert [(c.first, c.last) for c in found] == [(3, 5)]


def test_edit_conflicts_only_on_keyframes_both_moved() -> None:
    moves = [
        {4: np.array([0.0, 0.0]), 9: np.array([0.0, 0.0])},
        {4: np.array([0.0, 12.0]), 10: np.array([100.0, 0.0])},
        {4: np.array([0.0, 3.0]), 9: np.array([1.0, 0.0])},
    ]
    found = edit_conflicts(moves, distance_m=5.0)
    assert sorted((c.a, c.b, c.index, round(c.distance_m, 3)) for c in found) == [(0, 1, 4, 12.0), (1, 2, 4, 9.0)]


def test_fused_metres_go_back_to_the_points_they_came_from_on_a_long_run() -> None:
    """The merge turns fused metres back into lon/lat; 60 km from the origin the way back
    must land on the clicked point, not a metre outwards of it."""
    from posefix.core import geodesy
    from posefix.tasks.states import local_m, to_lonlat
    origin = geodesy.EnuOrigin(35.17, 136.88, 0.0)
    lon = np.array([136.88, 137.20, 137.45, 136.30])
    lat = np.array([35.17, 35.40, 34.90, 35.60])
    back_lon, back_lat = to_lonlat(local_m(lon, lat, origin), origin)
    miss_m = np.hypot((back_lon - lon) * 111e3 * np.cos(np.radians(lat)), (back_lat - lat) * 111e3)
    assert miss_m.max() < 1e-3
