"""Trajectory error statistics against a truth run."""

from __future__ import annotations

import numpy as np
import pytest

from posefix.core.evaluate import evaluate
from posefix.core.geodesy import enu_to_geodetic, geodetic_to_enu
from posefix.core.run import PoseRun

from .io_helpers import small_run


def _shifted(run: PoseRun, d_enu_m) -> PoseRun:
    o = (run.lat_deg[0], run.lon_deg[0], run.alt_m[0])
    p = geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, o) + np.asarray(d_enu_m)
    return run.with_poses(*enu_to_geodetic(p, o))


def test_constant_horizontal_offset():
    truth = small_run(n=200)
    ev = evaluate(truth, _shifted(truth, [3.0, -4.0, 0.0]))
    for st in (ev.horizontal, ev.three_d):
        assert st.rmse_m == pytest.approx(5.0, abs=1e-6)
        assert st.max_m == pytest.approx(5.0, abs=1e-6) and st.p95_m == pytest.approx(5.0, abs=1e-6)
    assert ev.n_compared == 200 and ev.n_outside == 0


def test_vertical_offset_is_not_horizontal():
    truth = small_run(n=100)
    # 2 m up along each sample's own vertical (the ellipsoid normal)
    ev = evaluate(truth, truth.with_poses(truth.lat_deg, truth.lon_deg, truth.alt_m + 2.0))
    assert ev.horizontal.max_m < 1e-9
    assert ev.three_d.mean_m == pytest.approx(2.0, abs=1e-6)


def test_truth_is_interpolated_at_the_run_times():
    truth = small_run(n=101, rate_hz=1.0)
    # run sampled half-way between truth samples, on the truth's own straight chords
    mid_t = 0.5 * (truth.t_s[1:] + truth.t_s[:-1])
    o = (truth.lat_deg[0], truth.lon_deg[0], truth.alt_m[0])
    p = geodetic_to_enu(truth.lat_deg, truth.lon_deg, truth.alt_m, o)
    mid = 0.5 * (p[1:] + p[:-1])
    lat, lon, alt = enu_to_geodetic(mid, o)
    run = PoseRun(mid_t, lat, lon, alt, truth.q_body_to_enu_wxyz[:-1])
    assert evaluate(truth, run).three_d.max_m < 1e-6


def test_statistics_of_varying_error_and_samples_outside():
    truth = small_run(n=100)
    err = np.r_[np.zeros(90), np.full(10, 10.0)]
    o = (truth.lat_deg[0], truth.lon_deg[0], truth.alt_m[0])
    p = geodetic_to_enu(truth.lat_deg, truth.lon_deg, truth.alt_m, o)
    p[:, 1] += err
    run = truth.with_poses(*enu_to_geodetic(p, o))
    ev = evaluate(truth, run)
    assert ev.horizontal.rmse_m == pytest.approx(np.sqrt(10.0), rel=1e-6)
    assert ev.horizontal.mean_m == pytest.approx(1.0, rel=1e-6)
    assert ev.horizontal.median_m == pytest.approx(0.0, abs=1e-6)
    assert ev.horizontal.max_m == pytest.approx(10.0, rel=1e-6)
    late = truth.take(np.arange(50, 100))
    ev2 = evaluate(late, truth)
    assert ev2.n_compared == 50 and ev2.n_outside == 50
    assert set(ev.to_dict()) == {"horizontal", "3d", "n_compared", "n_outside"}


def test_no_overlap_is_an_error():
    truth = small_run(n=10)
    later = PoseRun(truth.t_s + 100.0, truth.lat_deg, truth.lon_deg, truth.alt_m, truth.q_body_to_enu_wxyz)
    with pytest.raises(ValueError, match="no sample of the run"):
        evaluate(truth, later)
