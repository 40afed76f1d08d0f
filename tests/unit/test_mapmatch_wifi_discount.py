"""WiFi evidence discounted for its correlation in time (f3, f4): the AR(1) share of new
information per scan, and what the tracker makes of it online and offline."""

import numpy as np
import pytest

from posefix.mapmatch.features import WIFI_CORR_S, FeatureSigmas, evidence_share, evidence_shares
from posefix.mapmatch.floorplan import raster_from_polygons
from posefix.mapmatch.graph import build_graph
from posefix.mapmatch.model import Model, ModelFormatError, load_model, save_model
from posefix.mapmatch.tracker import Tracker, smooth


def gls_information(t_s, tau_s):
    """1ᵀ C⁻¹ 1: the information about a constant from observations whose errors have unit
    variance and correlation exp(-|Δt| / τ) (generalised least squares)."""
    t = np.asarray(t_s, float)
    c = np.exp(-np.abs(t[:, None] - t[None, :]) / tau_s)
    return float(np.ones(t.size) @ np.linalg.solve(c, np.ones(t.size)))


def test_shares_add_up_to_the_information_of_correlated_observations():
    rng = np.random.default_rng(0)
    for tau in (5.0, 20.0, 60.0):
        t = np.cumsum(rng.uniform(0.5, 30.0, size=12))  # irregular scan times, s
        assert np.isclose(evidence_shares(t, tau).sum(), gls_information(t, tau), rtol=1e-9)
    # τ = 0: the scans are independent, each counts in full (the behaviour before the discount).
    assert np.all(evidence_shares(np.arange(10.0), 0.0) == 1.0)
    assert evidence_share(None, WIFI_CORR_S) == 1.0  # the first scan of a walk


def test_identical_scans_close_in_time_are_one_observation_far_apart_two():
    assert evidence_share(0.0, 20.0) == 0.0  # the same scan delivered twice adds nothing
    assert evidence_share(1.0, 20.0) < 0.03  # a second later: barely more than one scan
    assert evidence_share(200.0, 20.0) > 0.999  # ten correlation times later: independent
    # A walk's evidence depends on how long it scanned, not on how often: one scan a second
    # or one every 4 s over a minute both come to about 1 + T/(2τ) = 2.5 independent scans.
    fast = evidence_shares(np.arange(0.0, 60.5, 1.0), 20.0).sum()
    slow = evidence_shares(np.arange(0.0, 60.5, 4.0), 20.0).sum()
    assert abs(fast - 2.5) < 0.05 and abs(slow - 2.5) < 0.05
    assert evidence_shares(np.arange(0.0, 60.5, 1.0), 0.0).sum() == 61.0  # independent: 61 scans


def room_model(tau_s=WIFI_CORR_S):
    ring = np.array([[0, 0], [40, 0], [40, 40], [0, 40]], float)
    r = raster_from_polygons(40.0, 40.0, [[ring]], res_m=0.2)
    return Model(graph=build_graph(r, cell_m=0.8, reach_m=1.7, min_component_m2=5.0),
                 sigmas=FeatureSigmas(wifi_corr_s=tau_s))


SCAN = (np.array([20.0, 20.0]), np.eye(2) * 3.0**2)  # a WiFi fix: (μ m, Σ m²), 3 m 1σ


def posterior_sigma_after_two_scans(model, dt_ms, **kw):
    """1σ major semi-axis of the live position after one scan, and after the same scan again
    ``dt_ms`` later, for a walker standing still (zero steps) with an unknown start."""
    tr = Tracker(model, start_xy_m=None, **kw)
    one = tr.step(np.zeros(2), 1000, wifi=SCAN).summary
    two = tr.step(np.zeros(2), 1000 + dt_ms, wifi=SCAN).summary
    # Online and offline see the same discounted evidence: at the last step the smoothed
    # marginal is the live one.
    _, sm = smooth(tr)
    assert np.allclose(sm[-1].cov_m2, two.cov_m2, rtol=1e-6)
    return tr, one.sigma_major_m, two.sigma_major_m


def test_tracker_counts_a_repeated_scan_by_its_share_online_and_offline():
    model = room_model()
    # A second later: the position is barely surer than after the first scan (independent
    # scans would shrink σ by √2, to 0.71 of it).
    tr, s1, s2 = posterior_sigma_after_two_scans(model, 1000)
    assert 2.5 < s1 < 3.5  # the first scan counts in full (σ 3 m, plus standing-still jitter)
    assert s2 / s1 > 0.95
    assert [round(s, 3) for _, _, s in tr.shares] == [1.0, round(evidence_share(1.0, WIFI_CORR_S), 3)]
    # Two minutes later the scans are independent: σ shrinks by about √2.
    _, s1, s2 = posterior_sigma_after_two_scans(model, 120_000)
    assert 0.68 < s2 / s1 < 0.76
    # The old behaviour is one parameter away: τ = 0 in the model or the tracker.
    for m, kw in ((room_model(0.0), {}), (model, {"wifi_corr_s": 0.0})):
        _, s1, s2 = posterior_sigma_after_two_scans(m, 1000, **kw)
        assert 0.68 < s2 / s1 < 0.76


def test_wifi_and_peak_discounts_keep_separate_clocks_and_the_start_scan_counts():
    model = room_model()
    peak = (np.array([10.0, 10.0]), 6.0)
    tr = Tracker(model, start_xy_m=None, start_wifi=SCAN, start_wifi_t_ms=500, t0_ms=0)
    tr.step(np.zeros(2), 1000, peak=peak)  # the first peak: in full, whatever f3 did
    tr.step(np.zeros(2), 2000, wifi=SCAN, wifi_t_ms=1500)  # 1 s after the start scan
    tr.step(np.zeros(2), 3000, wifi=SCAN, peak=peak, peak_t_ms=2900)
    got = [(f, t, round(s, 4)) for f, t, s in tr.shares]
    want = [("f4", 1000, 1.0), ("f3", 1500, round(evidence_share(1.0, 20.0), 4)),
            ("f3", 3000, round(evidence_share(1.5, 20.0), 4)), ("f4", 2900, round(evidence_share(1.9, 20.0), 4))]
    assert got == want
    # The state row is the weighted score times its share: the scan's f3 at step 2.
    d2 = np.sum((tr.p_xy_m - SCAN[0]) ** 2, axis=1) / 9.0
    assert np.allclose(tr.state_rows[1], -0.5 * d2 * model.weights["f3"] * evidence_share(1.0, 20.0))
    with pytest.raises(ValueError, match="wifi_corr_s"):
        Tracker(model, wifi_corr_s=-1.0)
    with pytest.raises(ValueError, match="time"):
        tr.state_scores(wifi=SCAN)


def test_model_file_keeps_the_correlation_time(tmp_path):
    model = room_model(7.5)
    save_model(model, tmp_path / "m.npz")
    assert load_model(tmp_path / "m.npz").sigmas.wifi_corr_s == 7.5
    # A file from before the parameter (four sigmas) reads with the default, 20 s.
    z = dict(np.load(tmp_path / "m.npz"))
    z["sigmas"] = z["sigmas"][:4]
    np.savez_compressed(tmp_path / "old.npz", **z)
    assert load_model(tmp_path / "old.npz").sigmas.wifi_corr_s == WIFI_CORR_S == 20.0
    z["sigmas"] = np.r_[z["sigmas"], -3.0]
    np.savez_compressed(tmp_path / "bad.npz", **z)
    with pytest.raises(ModelFormatError, match=r"bad\.npz:0: field sigmas: wifi_corr_s"):
        load_model(tmp_path / "bad.npz")


def equicorrelated_information(n, rho):
    """1ᵀ C⁻¹ 1 for n observations of unit variance, any two correlated ρ."""
    c = np.full((n, n), rho) + np.eye(n) * (1.0 - rho)
    return float(np.ones(n) @ np.linalg.solve(c, np.ones(n)))


def test_walk_long_correlation_caps_the_information_of_a_walks_scans():
    from posefix.mapmatch.features import capped_information

    for rho in (0.1, 0.3, 0.7):
        for n in (1, 2, 5, 40):
            assert np.isclose(capped_information(n, rho), equicorrelated_information(n, rho), rtol=1e-9)
        assert capped_information(1e6, rho) < 1.0 / rho  # never more than 1/ρ scans, however many
    assert capped_information(7.0, 0.0) == 7.0 and capped_information(0.4, 0.5) == 0.4
    # The tracker's shares: scans two minutes apart (AR(1) shares ≈ 1) add up to the capped
    # information, online, so a long walk's WiFi never outweighs what its errors allow.
    model = room_model()
    tr = Tracker(model, start_xy_m=None, wifi_walk_corr=0.5)
    for i in range(6):
        tr.step(np.zeros(2), 1000 + 120_000 * i, wifi=SCAN)
    got = sum(s for _, _, s in tr.shares)
    ar = evidence_shares(1.0 + 120.0 * np.arange(6), WIFI_CORR_S).sum()
    assert np.isclose(got, capped_information(ar, 0.5)) and got < 2.0
    with pytest.raises(ValueError, match="wifi_walk_corr"):
        Tracker(model, wifi_walk_corr=1.0)
