"""Honest ellipses: the reported covariance scaled so that 90 % of the training walks'
surveyed waypoints fall inside the 2σ ellipse (a Gaussian's draws: 86.5 %), kept in the
model file."""

from pathlib import Path

import numpy as np
import pytest

from posefix.mapmatch import build_model, load_model, read_walk, save_model, track_walk
from posefix.mapmatch.evaluate import ELLIPSE_COVER, mahalanobis2_at_waypoints
from posefix.mapmatch.learn import learn_ellipse_scale
from posefix.mapmatch.model import ModelFormatError
from posefix.mapmatch.viterbi import gaussian_summary

FLOOR = Path(__file__).resolve().parents[2] / "data" / "indoor-site1-F1"


def test_covariance_scale_widens_the_ellipse_not_the_mean():
    p = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]])
    lp = np.log(np.array([0.5, 0.25, 0.25]))
    one, four = gaussian_summary(p, lp, min_sigma_m=0.1), gaussian_summary(p, lp, min_sigma_m=0.1, cov_scale=4.0)
    assert np.allclose(four.mean_xy_m, one.mean_xy_m) and np.allclose(four.cov_m2, 4.0 * one.cov_m2)
    assert np.isclose(four.sigma_major_m, 2.0 * one.sigma_major_m) and np.isclose(four.angle_deg, one.angle_deg)


def test_learned_scale_makes_the_training_waypoints_covered_as_a_gaussian_would():
    model = build_model(FLOOR)
    walks = [read_walk(f) for f in sorted((FLOOR / "walks").glob("*.txt"))]
    scale, n = learn_ellipse_scale(model, walks)
    assert n == sum(w.waypoints.shape[0] - 1 for w in walks) and 0.25 <= scale <= 25.0
    cal = model.with_(ellipse_scale=scale)
    m2 = np.concatenate([mahalanobis2_at_waypoints(w.waypoints, track_walk(cal, w, start_xy_m=tuple(w.waypoints[0, 1:3])),
                                                   skip_first=True) for w in walks])
    # The quantile was set at 4: the target share inside (to one waypoint).
    assert abs(np.mean(m2 <= 4.0 + 1e-9) - ELLIPSE_COVER) <= 1.0 / n + 1e-9
    # Scaling is relative: learning again on the calibrated model changes nothing.
    again, _ = learn_ellipse_scale(cal, walks)
    assert np.isclose(again, scale, rtol=1e-6)


def test_model_file_keeps_the_ellipse_scale(tmp_path):
    model = build_model(FLOOR).with_(ellipse_scale=2.5)
    save_model(model, tmp_path / "m.npz")
    assert load_model(tmp_path / "m.npz").ellipse_scale == 2.5
    z = dict(np.load(tmp_path / "m.npz"))
    del z["ellipse_scale"]  # a file from before it: scale 1
    np.savez(tmp_path / "old.npz", **z)
    assert load_model(tmp_path / "old.npz").ellipse_scale == 1.0
    z["ellipse_scale"] = np.array(-1.0)
    np.savez(tmp_path / "bad.npz", **z)
    with pytest.raises(ModelFormatError, match="bad.npz:0: field ellipse_scale"):
        load_model(tmp_path / "bad.npz")
