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
