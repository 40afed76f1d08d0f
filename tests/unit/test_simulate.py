"""The simulator: plausible vehicle motion, each GNSS regime's error, edits near truth."""

from __future__ import annotations

import numpy as np
import pytest

from posefix.core.geodesy import geodetic_to_enu
from posefix.core.rotations import quat_to_matrix
from posefix.core.simulate import REGIMES, load_osm_graph, simulate

from .io_helpers import osm_extract


def _enu(run, o):
    return geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, o)


def _gnss_enu(run, o):
    return geodetic_to_enu(run.gnss_lat_deg, run.gnss_lon_deg, run.gnss_alt_m, o)


def _motion_checks(sim, rate_hz):
    o = sim.origin
    p = _enu(sim.truth, o)
    v = np.diff(p, axis=0) * rate_hz
    speed = np.hypot(v[:, 0], v[:, 1])
    assert speed.min() > 4.5 and speed.max() < 20.5  # 5-20 m/s
    fwd = quat_to_matrix(sim.truth.q_body_to_enu_wxyz[:-1])[:, :, 0]
    cos = np.einsum("ni,ni->n", fwd[:, :2], v[:, :2]) / speed / np.linalg.norm(fwd[:, :2], axis=1)
    assert cos.min() > 0.95  # the truth heading follows the track
    assert np.all(quat_to_matrix(sim.truth.q_body_to_enu_wxyz)[:, 2, 2] > 0.98)  # nearly level


def test_same_seed_same_drive_and_shapes():
    a = simulate(120, 10, 30, seed=5, regime="white")
    b = simulate(120, 10, 30, seed=5, regime="white")
    c = simulate(120, 10, 30, seed=6, regime="white")
    assert a.run.n == 1201 and a.truth.n == 1201
    assert np.array_equal(a.run.lat_deg, b.run.lat_deg)
    assert not np.array_equal(a.run.lat_deg, c.run.lat_deg)
    assert np.array_equal(a.run.t_s, a.truth.t_s)
    assert [e.t_s - a.run.t_s[0] for e in a.edits] == pytest.approx([15.0, 45.0, 75.0, 105.0])


@pytest.mark.parametrize("regime", REGIMES)
def test_every_regime_is_plausible(regime):
    sim = simulate(900, 10, 100, seed=2, regime=regime)
    _motion_checks(sim, 10)
    o = sim.origin
    pose_err = _enu(sim.run, o) - _enu(sim.truth, o)
    g_err = _gnss_enu(sim.run, o) - _enu(sim.truth, o)
    # the reported pose keeps its local shape: its error changes slowly (< 0.5 m over 1 s
    # outside canyon transitions)
    step_1s = np.linalg.norm(pose_err[10:, :2] - pose_err[:-10, :2], axis=1)
    assert np.percentile(step_1s, 90) < 0.5
    horiz = np.hypot(g_err[:, 0], g_err[:, 1])
    if regime in ("outliers", "mixed"):
        frac = np.mean(horiz > 35.0)
        assert 0.003 < frac < 0.1  # bursts of ~50 m outliers
    else:
        assert horiz.max() < 35.0
    if regime in ("canyon", "canyon_ins", "mixed"):
        # minutes-long offsets of 5-20 m: the 60 s moving mean of the GNSS error reaches them
        k = 600
        mean60 = np.column_stack([np.convolve(g_err[:, i], np.ones(k) / k, mode="valid") for i in range(2)])
        m = np.hypot(mean60[:, 0], mean60[:, 1])
        assert 4.0 < m.max() < 25.0
    if regime == "canyon_ins":
        assert np.sqrt(np.mean(pose_err[:, :2] ** 2)) < 6.0  # the pose bridged the offsets
    if regime == "white":
        assert 2.0 < np.sqrt(np.mean(g_err[:, 0] ** 2)) < 3.0  # 2.5 m per axis
    if regime == "drift":
        rate = np.linalg.norm(np.diff(pose_err[::10, :2], axis=0), axis=1)  # m per s
        assert 0.01 < np.sqrt(np.mean(rate ** 2)) < 0.15  # a few cm/s


def test_edits_are_truth_plus_click_noise():
    sim = simulate(1000, 10, 50, seed=3, regime="mixed", click_noise_m=0.5)
    o = sim.origin
    truth = _enu(sim.truth, o)
    idx = np.array([e.index for e in sim.edits])
    assert len(idx) == 20
    assert np.array_equal(sim.truth.t_s[idx], [e.t_s for e in sim.edits])
    p_edit = geodetic_to_enu(np.array([e.lat_deg for e in sim.edits]), np.array([e.lon_deg for e in sim.edits]),
                             sim.truth.alt_m[idx], o)
    d = np.hypot(*(p_edit - truth[idx])[:, :2].T)
    assert 0.1 < np.sqrt(np.mean(d ** 2)) < 1.5 and d.max() < 3.0


def test_no_gnss_columns_and_no_edits():
    sim = simulate(60, 5, 0, seed=1, regime="drift", gnss_columns=False)
    assert not sim.run.has_gnss and sim.edits == []


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown regime"):
        simulate(10, 10, 5, regime="rainy")
    with pytest.raises(ValueError, match="positive"):
        simulate(0, 10, 5)


def test_drive_along_osm_streets():
    path = osm_extract()
    graph = load_osm_graph(str(path))
    sim = simulate(600, 10, 100, seed=4, regime="white", osm_path=str(path))
    _motion_checks(sim, 10)
    # every truth position lies near a street: within a few metres of the graph's edges
    from scipy.spatial import cKDTree

    rows, cols = graph.lengths.nonzero()
    a, b = graph.xy_m[rows], graph.xy_m[cols]
    f = np.linspace(0, 1, 50)[:, None, None]
    dense = (a[None] * (1 - f) + b[None] * f).reshape(-1, 2)
    truth = geodetic_to_enu(sim.truth.lat_deg, sim.truth.lon_deg, sim.truth.alt_m, graph.origin)[:, :2]
    dist, _ = cKDTree(dense).query(truth)
    assert np.percentile(dist, 99) < 6.0
    assert sim.info["path_length_m"] > 600 * 5.0
