"""The map-matching benchmark's walk bootstrap (benchmarks/mapmatch.py)."""

import numpy as np

from benchmarks.mapmatch import walk_bootstrap


def test_walk_bootstrap_pools_waypoints_and_resamples_walks():
    # Identical walks: every resample has the same mean, so the interval collapses onto it.
    lo, hi = walk_bootstrap([np.array([1.0, 3.0]), np.array([1.0, 3.0])])
    assert lo == hi == 2.0
    # One bad walk among good ones: the interval straddles the pooled mean and is wide,
    # bounded by "no bad walk drawn" and "several drawn".
    errs = [np.full(5, 1.0)] * 9 + [np.full(5, 41.0)]
    lo, hi = walk_bootstrap(errs, n_boot=4000)
    pooled = np.concatenate(errs).mean()  # 5.0
    assert lo < pooled < hi
    assert lo == 1.0  # a resample without the bad walk is 1 m throughout (35 % of resamples)
    assert 12.0 < hi < 21.0  # 3-4 bad walks of 10 drawn at the 95 % point
    # Waypoints are pooled, not walk means averaged: at the 95 % point two of 20 draws are the
    # one-waypoint 10 m walk, 20 m over 164 waypoints (0.12 m), not 2 walks of 20 at 10 m (1 m).
    lo, hi = walk_bootstrap([np.full(9, 0.0)] * 19 + [np.full(1, 10.0)], n_boot=4000)
    assert lo == 0.0 and 0.05 < hi < 0.2


def test_mahalanobis_at_waypoints_reads_the_reported_ellipse():
    from types import SimpleNamespace

    from benchmarks.mapmatch import mahalanobis2_at_waypoints

    # A track standing at the origin with a 2 m x 1 m (1σ) ellipse, major axis at 30°.
    t = np.array([0.0, 1000.0, 2000.0])
    res = SimpleNamespace(t_ms=t, p_xy_m=np.zeros((3, 2)), sigma_major_m=np.full(3, 2.0),
                          sigma_minor_m=np.full(3, 1.0), angle_deg=np.full(3, 30.0))
    a = np.radians(30.0)
    major, minor = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    wp = np.array([[0.0, 0.0, 0.0],
                   [900.0, *(4.0 * major)],  # 2σ along the major axis: m² = 4
                   [2000.0, *(2.0 * minor)],  # 2σ along the minor axis: m² = 4
                   [1500.0, *(2.0 * major + 1.0 * minor)]])  # 1σ along each: m² = 2
    m2 = mahalanobis2_at_waypoints(wp, res)
    assert np.allclose(m2, [0.0, 4.0, 4.0, 2.0])
    assert np.allclose(mahalanobis2_at_waypoints(wp, res, skip_first=True), [4.0, 4.0, 2.0])
    # Swapping the axes (an ellipse turned the wrong way) changes the answer.
    res.angle_deg = np.full(3, 120.0)
    assert np.allclose(mahalanobis2_at_waypoints(wp, res)[1:3], [16.0, 1.0])
