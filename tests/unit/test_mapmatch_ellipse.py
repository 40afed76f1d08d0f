"""Honest ellipses: a walk's own heading offset and step scale, which last the whole walk, are
marginalised (the walk smoothed at the quadrature nodes of their distribution), with their
spread measured between training walks and kept in the model file."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from posefix.mapmatch import build_model, load_model, read_walk, save_model, track_walk
from posefix.mapmatch.evaluate import mahalanobis2_at_waypoints
from posefix.mapmatch.learn import learn_heading_bias, learn_walk_spread, waypoint_segments
from posefix.mapmatch.model import WALK_HEADING_SD_RAD, WALK_SCALE_SD, ModelFormatError
from posefix.mapmatch.modes import CONVERGED_MASS, CONVERGED_SIGMA_M, posterior_modes
from posefix.mapmatch.tracker import WALK_NODES, _marginalise_walk, _row_covariances, walk_modes
from posefix.mapmatch.viterbi import gaussian_summary

FLOOR = Path(__file__).resolve().parents[2] / "data" / "indoor-site1-F1"


def test_covariance_scale_widens_the_ellipse_not_the_mean():
    p = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]])
    lp = np.log(np.array([0.5, 0.25, 0.25]))
    one, four = gaussian_summary(p, lp, min_sigma_m=0.1), gaussian_summary(p, lp, min_sigma_m=0.1, cov_scale=4.0)
    assert np.allclose(four.mean_xy_m, one.mean_xy_m) and np.allclose(four.cov_m2, 4.0 * one.cov_m2)
    assert np.isclose(four.sigma_major_m, 2.0 * one.sigma_major_m) and np.isclose(four.angle_deg, one.angle_deg)


def test_quadrature_integrates_each_axis_and_no_cross_term():
    w = WALK_NODES[:, 2] / WALK_NODES[:, 2].sum()
    for axis in (0, 1):
        z = WALK_NODES[:, axis]
        for k, want in ((0, 1.0), (1, 0.0), (2, 1.0), (3, 0.0), (4, 3.0), (5, 0.0)):  # E[z^k], z ~ N(0, 1)
            assert np.isclose(np.sum(w * z**k), want)
    assert np.isclose(np.sum(w * WALK_NODES[:, 0] * WALK_NODES[:, 1]), 0.0)
    assert tuple(WALK_NODES[int(np.argmax(w)), :2]) == (0.0, 0.0)  # the centre is the walk as calibrated


def test_the_ellipse_is_the_mixtures_mean_squared_error_about_the_centre():
    model = build_model(FLOOR)
    walk = read_walk(sorted((FLOOR / "walks").glob("*.txt"))[0])
    start = tuple(walk.waypoints[0, 1:3])
    a = track_walk(model, walk, start_xy_m=start, walk_spread=(0.0, 0.0))
    b = replace(a, p_xy_m=a.p_xy_m + np.array([3.0, 0.0]))  # the same walk placed 3 m east
    mix = _marginalise_walk([a, b], np.array([3.0, 1.0]))
    assert np.allclose(mix.p_xy_m, a.p_xy_m)  # the centre's position
    # Equal covariances, the other run 3 m east with weight 1/4: Σ + diag(9/4, 0) about the centre.
    want = _row_covariances(a) + np.array([[2.25, 0.0], [0.0, 0.0]])
    assert np.allclose(_row_covariances(mix), want, atol=1e-9)
    assert mix.modes == a.modes


def test_marginalising_widens_the_ellipses_keeps_the_positions_with_or_without_a_start():
    model = build_model(FLOOR)
    walk = read_walk(sorted((FLOOR / "walks").glob("*.txt"))[0])
    start = tuple(walk.waypoints[0, 1:3])
    # Without the EM (whose prior is the spread too), so the central run is the same walk.
    fixed = track_walk(model, walk, start_xy_m=start, walk_spread=(0.0, 0.0), self_calibrate=False)
    mixed = track_walk(model, walk, start_xy_m=start, self_calibrate=False)  # the model's spread (10°, 7 %)
    assert (model.walk_heading_sd_rad, model.walk_scale_sd) == (WALK_HEADING_SD_RAD, WALK_SCALE_SD)
    assert np.allclose(mixed.p_xy_m, fixed.p_xy_m) and np.allclose(mixed.online_xy_m, fixed.online_xy_m)
    area = lambda r: r.sigma_major_m * r.sigma_minor_m  # noqa: E731
    assert np.all(area(mixed) >= area(fixed) - 1e-9) and np.mean(area(mixed)) > 1.2 * np.mean(area(fixed))
    m2_fixed = mahalanobis2_at_waypoints(walk.waypoints, fixed, skip_first=True)
    m2_mixed = mahalanobis2_at_waypoints(walk.waypoints, mixed, skip_first=True)
    assert np.median(m2_mixed) < np.median(m2_fixed)
    # Unknown start: the same marginalisation (a converged place is then as uncertain as the
    # walk's heading and stride), the positions the central run's; the modes are the mixture's
    # and "converged" is judged on them and on the reported (marginalised) ellipse.
    unknown = track_walk(model, walk, start_xy_m=None)
    plain = track_walk(model, walk, start_xy_m=None, walk_spread=(0.0, 0.0))
    assert np.allclose(unknown.p_xy_m, plain.p_xy_m)
    assert not np.allclose(unknown.sigma_major_m, plain.sigma_major_m)  # marginalised, not off
    assert np.allclose([m.sigma_major_m for m in unknown.modes], unknown.sigma_major_m)
    assert np.array_equal(unknown.converged, [m.mass[0] >= CONVERGED_MASS and m.sigma_major_m <= CONVERGED_SIGMA_M
                                              for m in unknown.modes])


def test_a_place_only_the_calibrated_heading_finds_is_not_converged():
    # The walk's marginalised posterior is the mixture over its heading and stride nodes: if the
    # central node is sure of one place and a turned node of another 30 m away, it is two places.
    xx, yy = np.meshgrid(np.arange(80) * 0.8, np.arange(40) * 0.8)
    p = np.column_stack([xx.ravel(), yy.ravel()])
    blob = lambda c: np.exp(-0.5 * np.sum((p - np.asarray(c)) ** 2, axis=1) / 1.5**2)  # noqa: E731
    central, turned = blob((10, 15)) / blob((10, 15)).sum(), blob((40, 15)) / blob((40, 15)).sum()
    assert posterior_modes(p, central).converged
    w = WALK_NODES[:, 2] / WALK_NODES[:, 2].sum()
    mix = w[0] * central + w[1] * turned + (1.0 - w[0] - w[1]) * central
    m = walk_modes(p, mix, 2.0)
    assert m.n == 2 and not m.converged and m.mass[0] == pytest.approx(1.0 - w[1], abs=0.005)  # within the 99.5 % support
    # One place, but the reported ellipse (the mixture's spread about the centre) is a wing.
    assert walk_modes(p, central, 2.0).converged and not walk_modes(p, central, 6.0).converged
    assert walk_modes(p, central, 6.0).sigma_major_m == 6.0


def test_walk_spread_is_the_rms_of_each_walks_offset_and_log_scale():
    walks = [read_walk(f) for f in sorted((FLOOR / "walks").glob("*.txt"))]
    sm = build_model(FLOOR).step_model
    sd_h, sd_k, n = learn_walk_spread(walks, sm)
    assert n == 3 and 0.0 < sd_h < np.pi / 4 and 0.0 < sd_k < 0.5
    offs = [learn_heading_bias([w], sm) for w in walks]
    assert np.isclose(sd_h, np.sqrt(np.mean(np.square(offs))))
    ks = []
    for w in walks:
        dd, dw = waypoint_segments([w], sm)
        ks.append(np.log(np.linalg.norm(dw, axis=1).sum() / np.linalg.norm(dd, axis=1).sum()))
    assert np.isclose(sd_k, np.sqrt(np.mean(np.square(ks))))
    assert learn_walk_spread(walks[:2], sm) == (None, None, 2)  # too few walks: not measured


def test_model_file_keeps_the_walk_spread_and_the_ellipse_scale(tmp_path):
    model = build_model(FLOOR).with_(ellipse_scale=2.5, walk_heading_sd_rad=0.1, walk_scale_sd=0.05)
    save_model(model, tmp_path / "m.npz")
    back = load_model(tmp_path / "m.npz")
    assert back.ellipse_scale == 2.5 and (back.walk_heading_sd_rad, back.walk_scale_sd) == (0.1, 0.05)
    z = dict(np.load(tmp_path / "m.npz"))
    del z["ellipse_scale"], z["walk_spread"]  # a file from before them: scale 1, the default spread
    np.savez(tmp_path / "old.npz", **z)
    old = load_model(tmp_path / "old.npz")
    assert old.ellipse_scale == 1.0 and (old.walk_heading_sd_rad, old.walk_scale_sd) == (WALK_HEADING_SD_RAD,
                                                                                         WALK_SCALE_SD)
    z["ellipse_scale"] = np.array(-1.0)
    np.savez(tmp_path / "bad.npz", **z)
    with pytest.raises(ModelFormatError, match="bad.npz:0: field ellipse_scale"):
        load_model(tmp_path / "bad.npz")
    z["ellipse_scale"], z["walk_spread"] = np.array(1.0), np.array([2.0, 0.05])
    np.savez(tmp_path / "bad2.npz", **z)
    with pytest.raises(ModelFormatError, match="bad2.npz:0: field walk_spread"):
        load_model(tmp_path / "bad2.npz")
