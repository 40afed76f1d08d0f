"""WiFi fingerprints: k-NN and path-loss predictions, access-point fits and RSSI peaks on a simulated survey."""

import numpy as np

from posefix.mapmatch.fingerprints import FingerprintMap, build_fingerprints, fit_access_points
from posefix.mapmatch.sensors import Walk

APS = np.array([[5.0, 5.0], [35.0, 5.0], [20.0, 25.0], [5.0, 25.0], [35.0, 25.0]])
P0 = np.array([-35.0, -38.0, -33.0, -40.0, -36.0])


def rssi_at(p, rng=None, noise_db=0.0):
    d2 = np.sum((p[:, None, :] - APS[None]) ** 2, axis=2) + 1.0
    r = P0[None] - 12.5 * np.log10(d2)  # 10·n·log10(d), n = 2.5
    if rng is not None:
        r = r + rng.normal(0.0, noise_db, size=r.shape)
    return r


def survey(rng):
    xs, ys = np.meshgrid(np.arange(2.0, 39.0, 3.0), np.arange(2.0, 29.0, 3.0))
    p = np.column_stack([xs.ravel(), ys.ravel()])
    return p, rssi_at(p, rng, 2.0).astype(np.float32)


def test_path_loss_fit_recovers_access_points():
    rng = np.random.default_rng(0)
    p, r = survey(rng)
    xy, p0, ok = fit_access_points(p, r)
    assert ok.all()
    assert np.max(np.linalg.norm(xy - APS, axis=1)) < 2.0  # the centroid prior pulls edge APs in a little
    assert np.max(np.abs(p0 - P0)) < 2.0


def test_predictions_knn_pathloss_and_hybrid():
    rng = np.random.default_rng(1)
    p, r = survey(rng)
    bssids = np.array([f"ap{i}" for i in range(len(APS))])
    grid = np.stack(np.meshgrid(np.arange(0.5, 40, 1.0), np.arange(0.5, 30, 1.0)), axis=-1).reshape(-1, 2)
    truth = np.array([[17.0, 12.0]])  # between survey points
    scan = dict(zip(bssids.tolist(), rssi_at(truth)[0].tolist()))
    for method, tol in (("knn", 3.0), ("pathloss", 1.5), ("hybrid", 3.0)):
        fp = FingerprintMap(bssids=bssids, p_xy_m=p, rssi_dbm=r, method=method)
        mu, cov = fp.predict(scan, grid)
        assert np.linalg.norm(mu - truth[0]) < tol, method
        assert np.all(np.linalg.eigvalsh(cov) >= fp.sigma0_m**2 - 1e-9)
    # Far outside the survey (k-NN can only answer with a survey point; path loss extrapolates).
    far = np.array([[39.5, 29.5]])
    scan_far = dict(zip(bssids.tolist(), rssi_at(far)[0].tolist()))
    mu_pl, _ = FingerprintMap(bssids=bssids, p_xy_m=p[p[:, 0] < 30], rssi_dbm=r[p[:, 0] < 30],
                              method="pathloss").predict(scan_far, grid)
    mu_knn, _ = FingerprintMap(bssids=bssids, p_xy_m=p[p[:, 0] < 30], rssi_dbm=r[p[:, 0] < 30],
                               method="knn").predict(scan_far)
    assert np.linalg.norm(mu_pl - far[0]) < np.linalg.norm(mu_knn - far[0])
    # Too few known access points: no prediction.
    assert FingerprintMap(bssids=bssids, p_xy_m=p, rssi_dbm=r, method="knn").predict({"ap0": -50.0, "x": -40.0}) is None


def walk_with_scans(t_ms, pos, waypoints):
    wifi = []
    for t, q in zip(t_ms, pos):
        for i, v in enumerate(rssi_at(q[None])[0]):
            wifi.append((int(t), f"ap{i}", float(v)))
    z = np.zeros((0, 4))
    return Walk(path="sim", acc=z, gyro=z, mag=z, rotvec=z, wifi=wifi, waypoints=np.asarray(waypoints, float))


def test_build_from_walks_places_scans_on_the_waypoint_line_and_finds_peaks():
    # A walk from (2, 5) to (38, 5) in 36 s, one scan a second, passing under ap0 and ap1.
    t = np.arange(0, 36001, 1000)
    pos = np.column_stack([2.0 + t / 1000.0, np.full(t.size, 5.0)])
    w = walk_with_scans(t, pos, [[0, 2.0, 5.0], [36000, 38.0, 5.0]])
    fp = build_fingerprints([w], method="knn")
    assert np.allclose(fp.p_xy_m, pos)
    assert set(fp.peak_xy_m) == {"ap0", "ap1"}  # only those come within -55 dBm
    assert np.allclose(fp.peak_xy_m["ap0"], [5.0, 5.0])
    peaks = fp.peaks_in_walk(w)
    assert sorted(int(tp) for tp, _, _ in peaks) == [3000, 33000]
