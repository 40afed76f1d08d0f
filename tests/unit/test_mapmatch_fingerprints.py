"""WiFi fingerprints: k-NN and path-loss predictions, access-point fits and RSSI peaks on a simulated survey."""

import numpy as np
import pytest

from posefix.mapmatch.fingerprints import (CALIBRATION_COVER, FingerprintMap, build_fingerprints, fit_access_points, load_fingerprints,
                                           save_fingerprints)
from posefix.mapmatch.sensors import Walk, WalkFormatError, read_walk, wifi_scans

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
    # One survey walk: f4's σ cannot be calibrated (no held-out walk), so the map gives no
    # f4 observation rather than one with a guessed σ, though the peaks are found.
    assert fp.peak_sigma_m is None and fp.peaks_in_walk(w) == []
    scans = wifi_scans(w, fp.max_age_ms, fp.scan_time)
    assert [int(tp) for tp, _ in fp.scan_peaks(scans)] == [3000, 33000]
    fp.peak_sigma_m = 4.0  # a σ given by the caller is used
    peaks = fp.peaks_in_walk(w)
    assert sorted(int(tp) for tp, _, _ in peaks) == [3000, 33000] and all(s == 4.0 for _, _, s in peaks)


def test_scans_drop_stale_entries_and_are_timed_when_measured():
    # One delivery at 10 000 ms: two fresh entries (seen 9 300 and 9 500) and one the phone
    # cached from a scan 6 s earlier; a second delivery at 12 000 ms.
    wifi = [(10000, "a", -50.0, 9300), (10000, "b", -60.0, 9500), (10000, "old", -45.0, 4000),
            (12000, "a", -52.0, 11400)]
    z = np.zeros((0, 4))
    w = Walk(path="sim", acc=z, gyro=z, mag=z, rotvec=z, wifi=wifi, waypoints=np.zeros((0, 3)))
    scans = wifi_scans(w)
    assert [t for t, _ in scans] == [9400, 11400]  # median last-seen of the kept entries
    assert scans[0][1] == {"a": -50.0, "b": -60.0}  # the stale entry is gone
    assert wifi_scans(w, max_age_ms=None, scan_time="line")[0] == (10000, {"a": -50.0, "b": -60.0, "old": -45.0})
    # Rows without a last-seen time (3-tuples) are timed by their line.
    w3 = Walk(path="sim", acc=z, gyro=z, mag=z, rotvec=z, wifi=[(5, "a", -50.0)], waypoints=np.zeros((0, 3)))
    assert wifi_scans(w3) == [(5, {"a": -50.0})]


def test_read_walk_keeps_the_last_seen_time(tmp_path):
    lines = [f"{1000 + 20 * i}\tTYPE_ACCELEROMETER\t0\t0\t9.8\t3" for i in range(12)]
    lines += [f"{1000 + 20 * i}\tTYPE_ROTATION_VECTOR\t0\t0\t0\t3" for i in range(12)]
    lines += ["1300\tTYPE_WIFI\tnet\taa:bb\t-61\t2412\t900", "1300\tTYPE_WIFI\tnet\tcc:dd\t-70\t2412"]
    p = tmp_path / "w.txt"
    p.write_text("\n".join(lines) + "\n")
    w = read_walk(p)
    assert w.wifi == [(1300, "aa:bb", -61.0, 900), (1300, "cc:dd", -70.0, 1300)]
    p.write_text("\n".join(lines + ["1300\tTYPE_WIFI\tnet\tee:ff\t-70\t2412\tsoon"]) + "\n")
    with pytest.raises(WalkFormatError, match=r"w.txt:27: field last_seen_timestamp"):
        read_walk(p)


def test_survey_positions_at_measurement_time_not_delivery():
    # 1 m/s along x; every scan delivered 1.5 s after it was measured.
    t = np.arange(0, 30001, 2000)
    wifi = []
    for tm in t:
        q = np.array([[2.0 + tm / 1000.0, 5.0]])
        for i, v in enumerate(rssi_at(q)[0]):
            wifi.append((int(tm) + 1500, f"ap{i}", float(v), int(tm)))
    z = np.zeros((0, 4))
    w = Walk(path="sim", acc=z, gyro=z, mag=z, rotvec=z, wifi=wifi, waypoints=np.array([[0, 2.0, 5.0], [40000, 42.0, 5.0]]))
    fp = build_fingerprints([w], calibrate=False)
    assert np.allclose(fp.p_xy_m[:, 0], 2.0 + t / 1000.0)


def survey_walks(rng, noise_db=4.0):
    """Eight walks along the rows of a 40 × 30 m floor, a scan every metre, noisy RSSI."""
    walks = []
    for row, y in enumerate(np.linspace(3.0, 27.0, 8)):
        t = np.arange(0, 36001, 1000)
        pos = np.column_stack([2.0 + t / 1000.0, np.full(t.size, y)])
        r = rssi_at(pos, rng, noise_db)
        wifi = [(int(tm), f"ap{i}", float(v), int(tm)) for tm, rr in zip(t, r) for i, v in enumerate(rr)]
        z = np.zeros((0, 4))
        walks.append(Walk(path=f"row{row}", acc=z, gyro=z, mag=z, rotvec=z, wifi=wifi,
                          waypoints=np.array([[0, 2.0, y], [36000, 38.0, y]])))
    return walks


def test_covariance_is_calibrated_on_the_survey():
    rng = np.random.default_rng(3)
    walks = survey_walks(rng, noise_db=8.0)
    # σ0 = 0.3 m: a survey point's own uncertainty set too small, so the raw Σ is overconfident.
    fp_raw = build_fingerprints(walks, calibrate=False, sigma0_m=0.3)
    fp = build_fingerprints(walks, sigma0_m=0.3)
    assert fp.cov_scale > 1.5  # the neighbours' spread alone is overconfident here
    # Fresh scans at random places: the calibrated Σ makes their Mahalanobis distances χ²₂-like.
    truth = rng.uniform([3.0, 4.0], [37.0, 26.0], size=(200, 2))
    r = rssi_at(truth, rng, 8.0)
    m2_raw, m2 = [], []
    for p, rr in zip(truth, r):
        scan = {f"ap{i}": float(v) for i, v in enumerate(rr)}
        for f, out in ((fp_raw, m2_raw), (fp, m2)):
            mu, cov = f.predict(scan)
            d = p - mu
            out.append(d @ np.linalg.solve(cov, d))
    chi2_median = 2.0 * np.log(2.0)
    assert np.median(m2_raw) > 1.3 * chi2_median
    # Σ's scale puts 86.5 % of held-out survey fixes inside the 2σ ellipse (CALIBRATION_COVER);
    # held-out walks leave whole rows out, so on fresh scans it errs wide, never narrow.
    m2 = np.asarray(m2)
    assert np.mean(np.asarray(m2_raw) <= 4.0) < 0.8
    assert np.mean(m2 <= 4.0) >= CALIBRATION_COVER
    assert 0.2 * chi2_median < np.median(m2) < 1.2 * chi2_median
    assert 0.0 <= fp.outlier_frac < 0.2
    # k-NN: the scale grows with how badly the scan matches its best fingerprint.
    assert fp.scale_by_match is not None and np.all(np.diff(fp.scale_by_match) >= 0.0)
    assert fp.scale_for(0.0) == fp.scale_by_match[0] and fp.scale_for(1e3) == fp.scale_by_match[-1]


def test_fingerprint_file_keeps_the_calibration(tmp_path):
    walks = survey_walks(np.random.default_rng(4), noise_db=8.0)
    fp = build_fingerprints(walks, sigma0_m=0.3)
    save_fingerprints(fp, tmp_path / "fp.npz")
    back = load_fingerprints(tmp_path / "fp.npz")
    assert back.cov_scale == fp.cov_scale and back.outlier_frac == fp.outlier_frac
    assert np.allclose(back.scale_match_db, fp.scale_match_db) and np.allclose(back.scale_by_match, fp.scale_by_match)
    assert fp.robust and back.robust  # f3's heavy-tailed form, kept in the file
    # A file written before the member existed was tracked with the plain Gaussian: kept so.
    with np.load(tmp_path / "fp.npz") as z:
        old = {k: z[k] for k in z.files if k != "f3_robust"}
    np.savez_compressed(tmp_path / "old.npz", **old)
    assert not load_fingerprints(tmp_path / "old.npz").robust
    np.savez_compressed(tmp_path / "bad.npz", **old, f3_robust=np.array(2, dtype=np.int8))
    with pytest.raises(ValueError, match="field f3_robust"):
        load_fingerprints(tmp_path / "bad.npz")
    np.savez_compressed(tmp_path / "bad.npz", **{**old, "outlier_frac": np.array(1.5)})
    with pytest.raises(ValueError, match="field outlier_frac: must be a number in"):
        load_fingerprints(tmp_path / "bad.npz")


def test_a_scan_gives_at_most_one_peak_the_strongest():
    fp = FingerprintMap(bssids=np.array(["a", "b", "c"]), p_xy_m=np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]]),
                        rssi_dbm=np.array([[-40, -90, -90], [-90, -45, -90], [-90, -90, -50]], dtype=np.float32))
    assert set(fp.peak_xy_m) == {"a", "b", "c"}
    scans = [(0.0, {"a": -60.0, "b": -60.0, "c": -70.0}),
             (1000.0, {"a": -50.0, "b": -45.0, "c": -52.0}),  # all three peak here: b is strongest
             (2000.0, {"a": -58.0, "b": -60.0, "c": -53.0}),  # c still rising: not a peak yet
             (3000.0, {"a": -70.0, "b": -70.0, "c": -52.0})]  # c peaks alone
    assert fp.scan_peaks(scans) == [(1000.0, "b"), (3000.0, "c")]


def test_peak_sigma_is_calibrated_on_the_survey():
    rng = np.random.default_rng(5)
    walks = survey_walks(rng, noise_db=6.0)
    assert build_fingerprints(walks, calibrate=False).peak_sigma_m is None  # uncalibrated: no f4
    fp = build_fingerprints(walks)
    # Fresh walks along the rows halfway between the survey's, noisy like it: the distance
    # from each detected peak's location to the walker is Rayleigh-like with the calibrated σ.
    r = []
    for y in np.linspace(3.0, 27.0, 8)[:-1] + 1.7:
        t = np.arange(0, 36001, 1000)
        pos = np.column_stack([2.0 + t / 1000.0, np.full(t.size, y)])
        rr = rssi_at(pos, rng, 6.0)
        scans = [(float(tm), {f"ap{i}": float(v) for i, v in enumerate(row)}) for tm, row in zip(t, rr)]
        for tm, b in fp.scan_peaks(scans):
            r.append(np.linalg.norm(pos[int(tm) // 1000] - fp.peak_xy_m[b]))
    assert len(r) >= 10
    ratio = np.median(r) / (fp.peak_sigma_m * np.sqrt(2.0 * np.log(2.0)))
    assert 0.6 < ratio < 1.6, (np.median(r), fp.peak_sigma_m)


def test_peak_sigma_is_left_uncalibrated_with_too_few_held_out_peaks():
    from posefix.mapmatch.fingerprints import MIN_PEAKS_TO_CALIBRATE, calibrate_peak_sigma

    walks = survey_walks(np.random.default_rng(5), noise_db=6.0)
    # Three survey rows have a few held-out peaks: a σ from them (about 3.9 m here) would be
    # a noisy median, so f4 is left out rather than given it; eight rows calibrate it.
    few = build_fingerprints(walks[:3])
    assert few.peak_sigma_m is None and few.peaks_in_walk(walks[0]) == []
    assert calibrate_peak_sigma(build_fingerprints(walks[:3], calibrate=False), min_peaks=1) > 0.0
    assert MIN_PEAKS_TO_CALIBRATE == 30
    assert build_fingerprints(walks).peak_sigma_m > 0.0


def test_fingerprint_file_keeps_the_peak_sigma(tmp_path):
    fp = build_fingerprints(survey_walks(np.random.default_rng(6), noise_db=6.0))
    fp.peak_sigma_m = 7.25
    save_fingerprints(fp, tmp_path / "fp.npz")
    assert load_fingerprints(tmp_path / "fp.npz").peak_sigma_m == 7.25
    # Not calibrated: the file has no peak_sigma_m and reads back uncalibrated (f4 left
    # out), as do files written before f4's calibration — not as the old 3 m guess.
    fp.peak_sigma_m = None
    save_fingerprints(fp, tmp_path / "none.npz")
    back = load_fingerprints(tmp_path / "none.npz")
    walk = survey_walks(np.random.default_rng(7), noise_db=6.0)[0]  # passes 2 m from ap0 and ap1
    assert back.peak_sigma_m is None and back.peaks_in_walk(walk) == []
    back.peak_sigma_m = 7.25
    assert len(back.peaks_in_walk(walk)) >= 2  # the same map with a σ does see its peaks
    fp.peak_sigma_m = 0.0
    save_fingerprints(fp, tmp_path / "bad.npz")
    with pytest.raises(ValueError, match=r"bad\.npz:0: field peak_sigma_m"):
        load_fingerprints(tmp_path / "bad.npz")


def long_survey_walks(rng, shift_m):
    """Eight 80 s walks up and down the rows (a scan a second); each walk's surveyed line is
    off the true one by its own offset of ``shift_m`` metres (a survey error the walk shares)."""
    walks = []
    for row, y in enumerate(np.linspace(3.0, 27.0, 8)):
        t = np.arange(0, 80001, 1000)
        x = 2.0 + 36.0 * (1.0 - np.abs(1.0 - t / 40000.0))  # out and back
        r = rssi_at(np.column_stack([x, np.full(t.size, y)]), rng, 4.0)
        wifi = [(int(tm), f"ap{i}", float(v), int(tm)) for tm, rr in zip(t, r) for i, v in enumerate(rr)]
        off = shift_m * np.array([np.cos(row * 2.4), np.sin(row * 2.4)])
        z = np.zeros((0, 4))
        wp = np.array([[0, 2.0, y], [40000, 38.0, y], [80000, 2.0, y]]) + np.r_[0.0, off][None, :]
        walks.append(Walk(path=f"row{row}", acc=z, gyro=z, mag=z, rotvec=z, wifi=wifi, waypoints=wp))
    return walks


def test_walk_long_error_correlation_is_calibrated_on_the_survey(tmp_path):
    rng = np.random.default_rng(5)
    honest = build_fingerprints(long_survey_walks(rng, 0.0))
    shifted = build_fingerprints(long_survey_walks(rng, 6.0))
    # Even an honest survey's k-NN errors last a walk: an edge row's neighbours all lie on one
    # side of it, and out and back passes the same places. A shared offset adds to that.
    assert 0.0 < honest.walk_corr < 0.45
    assert shifted.walk_corr > honest.walk_corr + 0.2
    save_fingerprints(shifted, tmp_path / "fp.npz")
    assert load_fingerprints(tmp_path / "fp.npz").walk_corr == shifted.walk_corr
    # Walks too short for scans 40 s apart: nothing measured, the AR(1) discount alone.
    assert build_fingerprints(survey_walks(rng)).walk_corr == 0.0
