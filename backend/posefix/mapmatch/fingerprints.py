"""WiFi fingerprint map (f3) and access-point RSSI peaks (f4), built from surveyed walks.

Survey: every WiFi scan of a walk with waypoints (grouped and timed by
:func:`posefix.mapmatch.sensors.wifi_scans`) is placed at the straight-line position
between the waypoints around its time (the competition's assumption); scans outside the
first..last waypoint span are not used. The map is the matrix of RSSI (dBm; -100 for an
access point not heard) over those positions.

f3 prediction (weighted k-nearest neighbours in signal space, ``method="knn"``, the
default): for a scan r, the distance to fingerprint i is the RMS RSSI difference over the
access points the scan heard, ``d_i = sqrt(mean_a (r_a - R_ia)²)`` (``similarity="scan"``;
``"union"``: over those either heard, see :meth:`FingerprintMap.signal_distances_db`);
the k nearest with weights ``1 / (d_i + 1 dB)`` give the mean position μ and covariance
``Σ = s·(Σ_i w_i (p_i - μ)(p_i - μ)ᵀ + σ0² I)`` with σ0 = 2 m (a survey point's own
uncertainty) and s the scale :func:`calibrate_covariance` fits on the survey itself (per
quartile of the best match's distance for k-NN) so that 86.5 % of the held-out fixes fall
inside their 2σ ellipse. Scans sharing fewer than ``min_common`` access points with the map
predict nothing. Tracking uses the heavy-tailed form (``robust``, the default)
``f3(v) = log((1 - ε)·c²·N(p_v; μ, Σ) + ε/V)``, ε the survey's outlier rate: a fix from
beyond the surveyed corridors (k-NN can only answer a surveyed place) costs the places
far from it at most ``-log(ε/V)`` nats however far they are, not their squared distance.

Path-loss alternative (``method="pathloss"``), for floors where the survey is sparse: each
access point heard at least 4 times (once ≥ -75 dBm) gets a position a and power P0 fitted
to the log-distance model ``r = P0 - 10·n·log10(sqrt(|p - a|² + 1 m²))`` (n = 2.5, a typical
indoor exponent) by iteratively reweighted Gauss-Newton (Huber, 5 dB), all access points
at once, with a weak prior (σ = 15 m) pulling a to the power-weighted centroid of its
readings. A scan's per-vertex log-likelihood is the Huber-robustified sum over heard,
fitted access points of ``-½ ((r - r_model(v)) / 6 dB)²``; its moment-matched Gaussian is
the prediction. Unlike k-NN it extrapolates beyond the surveyed corridors (leave-one-out on
site1/F1: median 7.1 m vs 11.2 m for k-NN; means 14.3 vs 16.9 m), but where the survey is
dense k-NN is better (tracking with fingerprints that cover the walk: 1.4 m vs 3.5 m).

``method="hybrid"`` uses k-NN when its best match is within ``knn_max_db`` (8 dB
RMS: a scan taken close to a survey point) and the path-loss prediction otherwise. (8 dB
was chosen on the even-numbered walks and checked on the odd ones; 4-12 dB all give the
same result within 0.3 m there.)

f4 peaks: an access point's peak location is the survey position of its strongest
reading, kept when that is at least ``peak_dbm`` (-55 dBm: within a few metres of it).
While tracking, a scan where that access point reads ≥ ``peak_dbm`` and more than in the
scans just before and after is a peak, at most one a scan (the strongest: one scan is one
place, however many access points peak in it); its observation is (peak location, σ) with
σ calibrated on the survey (:func:`calibrate_peak_sigma`, the held-out peaks' Rayleigh
median). A map whose σ could not be calibrated (``peak_sigma_m`` None: one survey walk, or
under 30 held-out peaks — on site1/F1 fewer than 5-8 survey walks) gives no f4 at all (:data:`UNCALIBRATED_PEAK_SIGMA` says why).
Measured on site1/F1 (leave-one-walk-out): 1 413 peaks in 403
scans before the one-a-scan rule (6 a scan where any), the peak location a median 10.5 m
from the walker (10 % within 3.2 m, 10 % beyond 29 m), so the calibrated σ is 9.7-10.6 m.
With σ = 3 m f4 outweighed f3 by hundreds of nats on a walk (06b57669: the wrong
placement 23 m away scored ~180 nats better on f4 while f3 preferred the truth by 26).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from posefix.mapmatch.sensors import WIFI_MAX_AGE_MS, Walk, wifi_scans

__all__ = ["FingerprintMap", "build_fingerprints", "save_fingerprints", "load_fingerprints"]

MISSING_DBM = -100.0

# f4's σ when it cannot be calibrated on the survey: None, i.e. f4 is left out. Physics
# gives only a floor for it, not a value: the peak is located no better than the distance
# walked between scans (3-4 s at 1.2 m/s) plus the survey's own spacing, and a -55 dBm
# reading is 3-6 m from an access point (-40 dBm at 1 m, path-loss exponent 2-3) but about
# 2x nearer or farther under the 6-8 dB shadowing of indoor walls and bodies; how far the
# survey passed from each access point, which dominates, is unknown without held-out
# peaks. A guess is then either too small — 3 m had been assumed, and held-out peaks on
# site1/F1 land a median 10.5 m away, so each peak scored ~10x too many nats and outvoted
# f3 on whole walks — or large enough to be safe, and then it carries little (σ = 10 m:
# 0.1-0.6 nats between places 5 m apart within 15 m of the peak). Leaving f4 out loses
# that little and never misleads; f3 (its Σ falls back to the k-NN spread) still uses
# the scans.
UNCALIBRATED_PEAK_SIGMA: float | None = None

# Survey walks f3 needs. Its Σ scale and walk-long correlation ρ are measured by holding
# walks out, and a walk's shared error (phone, body, route) is one draw per walk: with one
# walk nothing is held out; with two each is predicted from a one-route map, unlike the
# tracking map, and ρ rests on two draws. Below this f3 is left out, as f4 is when its σ
# cannot be calibrated: an uncalibrated f3 made every data/ walk "converge" 30-45 m off.
MIN_SURVEY_WALKS_F3 = 3


@dataclass
class FingerprintMap:
    """``bssids`` (A,) str; ``p_xy_m`` (N, 2) survey positions; ``rssi_dbm`` (N, A) float32."""

    bssids: np.ndarray
    p_xy_m: np.ndarray
    rssi_dbm: np.ndarray
    k: int = 5
    sigma0_m: float = 2.0
    min_common: int = 3
    peak_dbm: float = -55.0
    peak_sigma_m: float | None = UNCALIBRATED_PEAK_SIGMA  # f4's σ (m); None: not calibrated, no f4
    method: str = "knn"
    path_loss_exp: float = 2.5
    sigma_db: float = 6.0
    vertices_xy_m: np.ndarray | None = None  # where path-loss likelihoods are evaluated
    knn_max_db: float = 8.0  # hybrid: trust k-NN when its best match is this close (RMS dB)
    max_age_ms: float | None = WIFI_MAX_AGE_MS  # scan grouping (sensors.wifi_scans)
    scan_time: str = "median"
    similarity: str = "scan"  # k-NN signal distance (signal_distances_db)
    cov_scale: float = 1.0  # Σ multiplier, calibrated on the survey (calibrate_covariance)
    outlier_frac: float = 0.0  # ε of f3's robust form, calibrated with cov_scale
    scale_match_db: np.ndarray | None = None  # k-NN: Σ scale as a function of the best match's
    scale_by_match: np.ndarray | None = None  # RMS dB distance (calibrate_covariance); None: cov_scale
    robust: bool = True  # track with f3's heavy-tailed form (ε = outlier_frac; module docstring)
    walk_id: np.ndarray | None = None  # (N,) which survey walk each fingerprint came from
    t_s: np.ndarray | None = None  # (N,) when each fingerprint was scanned (s), for calibrate_walk_corr
    walk_corr: float = 0.0  # f3 errors' walk-long correlation ρ (calibrate_walk_corr; Tracker caps f3 with it)
    f3_calibrated: bool = True  # False: the survey could not calibrate f3, track_walk leaves it out
    f3_note: str = ""  # why f3 is left out (f3_calibration)

    def __post_init__(self):
        if self.method not in ("knn", "pathloss", "hybrid"):
            raise ValueError(f"method must be 'knn', 'pathloss' or 'hybrid', got {self.method!r}")
        self._ap = fit_access_points(self.p_xy_m, self.rssi_dbm, self.path_loss_exp) if self.method != "knn" else None
        self._col = {b: i for i, b in enumerate(self.bssids.tolist())}
        best = np.argmax(self.rssi_dbm, axis=0) if self.rssi_dbm.size else np.zeros(0, dtype=int)
        strong = self.rssi_dbm[best, np.arange(self.rssi_dbm.shape[1])] >= self.peak_dbm if self.rssi_dbm.size else np.zeros(0, bool)
        self.peak_xy_m = {self.bssids[a]: self.p_xy_m[best[a]] for a in np.nonzero(strong)[0]}

    @property
    def n_fitted_aps(self) -> int:
        """Access points with a fitted path-loss position (0 for ``method="knn"``)."""
        return 0 if self._ap is None else int(self._ap[2].sum())

    def _vector(self, scan: dict[str, float]) -> tuple[np.ndarray, int]:
        v = np.full(self.bssids.shape[0], MISSING_DBM, dtype=np.float32)
        n = 0
        for b, r in scan.items():
            j = self._col.get(b)
            if j is not None:
                v[j] = r
                n += 1
        return v, n

    def predict(self, scan: dict[str, float], vertices_xy_m: np.ndarray | None = None):
        """Position (μ (2,), Σ (2, 2)) in floor metres for one scan, or None.

        ``vertices_xy_m`` (V, 2): where the path-loss likelihood is evaluated (the model
        graph's vertices); needed by ``pathloss`` and by ``hybrid`` when k-NN is not trusted.
        """
        if self.method == "pathloss":
            return self._predict_pathloss(scan, vertices_xy_m)
        knn = self._predict_knn(scan)
        if self.method == "hybrid" and (knn is None or knn[2] > self.knn_max_db):
            return self._predict_pathloss(scan, vertices_xy_m)
        return None if knn is None else knn[:2]

    def _predict_knn(self, scan: dict[str, float]):
        v, n = self._vector(scan)
        if n < self.min_common or self.p_xy_m.shape[0] == 0:
            return None
        d = self.signal_distances_db(v)
        k = min(self.k, d.size)
        nn = np.argpartition(d, k - 1)[:k]
        w = 1.0 / (d[nn] + 1.0)
        w /= w.sum()
        p = self.p_xy_m[nn]
        mu = w @ p
        dp = p - mu
        d_best = float(d[nn].min())
        cov = ((dp * w[:, None]).T @ dp + np.eye(2) * self.sigma0_m**2) * self.scale_for(d_best)
        return mu, cov, d_best

    def scale_for(self, d_best_db: float) -> float:
        """The k-NN covariance scale for a scan whose best match is ``d_best_db`` (RMS dB)."""
        if self.scale_match_db is None or self.scale_by_match is None:
            return self.cov_scale
        return float(np.interp(d_best_db, self.scale_match_db, self.scale_by_match))

    def signal_distances_db(self, v: np.ndarray) -> np.ndarray:
        """RMS RSSI difference (N,) dB between a scan vector ``v`` (A,) and every fingerprint.

        ``similarity="scan"`` (default): over the access points the scan heard, a fingerprint
        that did not hear one counting as -100 dBm. ``"union"``: over the access points either
        heard — on the competition floor its normalisation lets a fingerprint that heard few
        access points match anything (leave-one-out mean 19.9 m vs 13.4 m for ``"scan"``).
        """
        if self.similarity == "scan":
            m = v > MISSING_DBM
            return np.sqrt(np.mean((self.rssi_dbm[:, m] - v[m][None, :]) ** 2, axis=1))
        heard = (self.rssi_dbm > MISSING_DBM) | (v > MISSING_DBM)[None, :]
        diff2 = np.where(heard, (self.rssi_dbm - v[None, :]) ** 2, 0.0)
        return np.sqrt(diff2.sum(axis=1) / np.maximum(heard.sum(axis=1), 1))

    def _predict_pathloss(self, scan: dict[str, float], vertices_xy_m: np.ndarray | None):
        p = vertices_xy_m if vertices_xy_m is not None else self.vertices_xy_m
        if p is None:
            raise ValueError(f"method {self.method!r} needs vertices_xy_m (the model graph's vertex positions)")
        xy_ap, p0, ok = self._ap
        ll = np.zeros(p.shape[0])
        n = 0
        for b, r in scan.items():
            j = self._col.get(b)
            if j is None or not ok[j] or r < -85.0:
                continue
            d2 = np.sum((p - xy_ap[j]) ** 2, axis=1) + 1.0
            e = (r - (p0[j] - 5.0 * self.path_loss_exp * np.log10(d2))) / self.sigma_db
            ll -= np.where(np.abs(e) < 2.0, 0.5 * e * e, 2.0 * np.abs(e) - 2.0)  # Huber at 2σ
            n += 1
        if n < self.min_common:
            return None
        w = np.exp(ll - ll.max())
        w /= w.sum()
        mu = w @ p
        dp = p - mu
        cov = ((dp * w[:, None]).T @ dp + np.eye(2) * self.sigma0_m**2) * self.cov_scale
        return mu, cov

    def predict_walk(self, walk: Walk, vertices_xy_m: np.ndarray | None = None):
        """[(t_ms, μ, Σ)] for every scan of a walk that predicts a position; none when f3 is
        not calibrated (``f3_calibrated`` False, :data:`MIN_SURVEY_WALKS_F3`)."""
        if not self.f3_calibrated:
            return []
        out = []
        for t_ms, scan in wifi_scans(walk, self.max_age_ms, self.scan_time):
            r = self.predict(scan, vertices_xy_m)
            if r is not None:
                out.append((t_ms, r[0], r[1]))
        return out

    def peaks_in_walk(self, walk: Walk):
        """[(t_ms, peak_xy (2,), sigma_m)] for RSSI peaks of known access points (f4): at most
        one a scan (:meth:`scan_peaks`); none when f4's σ is not calibrated (``peak_sigma_m``
        None, :data:`UNCALIBRATED_PEAK_SIGMA`)."""
        if self.peak_sigma_m is None:
            return []
        scans = wifi_scans(walk, self.max_age_ms, self.scan_time)
        return [(t_ms, self.peak_xy_m[b], self.peak_sigma_m) for t_ms, b in self.scan_peaks(scans)]

    def scan_peaks(self, scans: list[tuple[float, dict[str, float]]]) -> list[tuple[float, str]]:
        """[(t_ms, bssid)] of the scans (time-ordered ``(t_ms, {bssid: dBm})``) where a known
        access point peaks: it reads ≥ ``peak_dbm`` and more than in the scans just before and
        after. One a scan, the strongest: the readings of one scan were all taken at one
        place, so several access points peaking in it are one observation of that place, not
        several (site1/F1 has 6 peaking access points a scan on average, up to 34), and the
        strongest is the one the walker is nearest to."""
        out = []
        for j, (t_ms, scan) in enumerate(scans):
            best, best_r = None, -np.inf
            for b, r in scan.items():
                if b not in self.peak_xy_m or r < self.peak_dbm or r <= best_r:
                    continue
                before = scans[j - 1][1].get(b, MISSING_DBM) if j > 0 else MISSING_DBM
                after = scans[j + 1][1].get(b, MISSING_DBM) if j + 1 < len(scans) else MISSING_DBM
                if r > before and r >= after:
                    best, best_r = b, r
            if best is not None:
                out.append((t_ms, best))
        return out


def fit_access_points(p_xy_m: np.ndarray, rssi_dbm: np.ndarray, n_exp: float = 2.5, iters: int = 15,
                      prior_m: float = 15.0, huber_db: float = 5.0, min_n: int = 4, min_max_dbm: float = -75.0):
    """Fit every access point's position and power at once (module docstring).

    ``p_xy_m`` (N, 2) survey positions, ``rssi_dbm`` (N, A). Returns ``xy`` (A, 2),
    ``p0_dbm`` (A,) and ``ok`` (A,) — False for access points with too few or only weak readings.
    """
    r_all = np.asarray(rssi_dbm, dtype=float)
    heard_all = r_all > MISSING_DBM
    ok = (heard_all.sum(axis=0) >= min_n) & (np.where(heard_all, r_all, -np.inf).max(axis=0) >= min_max_dbm)
    xy_out = np.zeros((r_all.shape[1], 2))
    p0_out = np.full(r_all.shape[1], -40.0)
    if not np.any(ok):
        return xy_out, p0_out, ok
    # Fit only the usable access points, and only on the scans that heard any of them.
    r, heard = r_all[:, ok], heard_all[:, ok]
    rows = heard.any(axis=1)
    r, heard, p = r[rows], heard[rows], np.asarray(p_xy_m, dtype=float)[rows]
    w_pow = np.where(heard, 10.0 ** (r / 20.0), 0.0)
    c0 = (w_pow.T @ p) / np.maximum(w_pow.sum(axis=0), 1e-30)[:, None]  # (A', 2)
    xy = c0.copy()
    p0 = np.where(heard, r, -np.inf).max(axis=0) + 10.0
    k = 10.0 * n_exp / np.log(10.0)
    for _ in range(iters):
        dx = p[:, None, 0] - xy[None, :, 0]  # (N', A')
        dy = p[:, None, 1] - xy[None, :, 1]
        d2 = dx * dx + dy * dy + 1.0
        res = np.where(heard, p0[None, :] - 5.0 * n_exp * np.log10(d2) - r, 0.0)
        wt = np.where(heard, np.minimum(1.0, huber_db / np.maximum(np.abs(res), 1e-9)), 0.0)  # IRLS Huber
        jx, jy = k * dx / d2, k * dy / d2  # ∂model/∂(ax, ay); ∂/∂P0 = 1
        jtj = np.empty((xy.shape[0], 3, 3))
        jtj[:, 0, 0] = np.sum(wt * jx * jx, axis=0) + 1.0 / prior_m**2
        jtj[:, 1, 1] = np.sum(wt * jy * jy, axis=0) + 1.0 / prior_m**2
        jtj[:, 2, 2] = np.sum(wt, axis=0) + 1e-6
        jtj[:, 0, 1] = jtj[:, 1, 0] = np.sum(wt * jx * jy, axis=0)
        jtj[:, 0, 2] = jtj[:, 2, 0] = np.sum(wt * jx, axis=0)
        jtj[:, 1, 2] = jtj[:, 2, 1] = np.sum(wt * jy, axis=0)
        jtr = np.stack([np.sum(wt * jx * res, axis=0) + (xy[:, 0] - c0[:, 0]) / prior_m**2,
                        np.sum(wt * jy * res, axis=0) + (xy[:, 1] - c0[:, 1]) / prior_m**2,
                        np.sum(wt * res, axis=0)], axis=1)
        step = np.linalg.solve(jtj, jtr[..., None])[..., 0]
        xy -= step[:, :2]
        p0 -= step[:, 2]
    xy_out[ok], p0_out[ok] = xy, p0
    return xy_out, p0_out, ok


def build_fingerprints(walks: list[Walk], method: str = "knn", vertices_xy_m: np.ndarray | None = None,
                       max_age_ms: float | None = WIFI_MAX_AGE_MS, scan_time: str = "median",
                       calibrate: bool = True, **options) -> FingerprintMap:
    """Fingerprint map from walks with waypoints (module docstring). ``method`` is
    ``"knn"`` (default), ``"hybrid"`` or ``"pathloss"``; ``vertices_xy_m`` may be given here
    or at prediction time; ``max_age_ms``, ``scan_time``: scan grouping
    (:func:`posefix.mapmatch.sensors.wifi_scans`); ``calibrate``: fit Σ's scale and the
    outlier rate (:func:`calibrate_covariance`) and f4's σ (:func:`calibrate_peak_sigma`); ``options``: other ``FingerprintMap`` fields."""
    pos, scans, wid, t_s = [], [], [], []
    for iw, w in enumerate(walks):
        wp = w.waypoints
        if wp.shape[0] < 2:
            continue
        for t_ms, scan in wifi_scans(w, max_age_ms, scan_time):
            if wp[0, 0] <= t_ms <= wp[-1, 0]:
                pos.append([np.interp(t_ms, wp[:, 0], wp[:, 1]), np.interp(t_ms, wp[:, 0], wp[:, 2])])
                scans.append(scan)
                wid.append(iw)
                t_s.append(t_ms / 1000.0)
    if not scans:
        raise ValueError("no WiFi scan between two waypoints in the given walks: nothing to build a map from")
    bssids = np.array(sorted({b for s in scans for b in s}))
    col = {b: i for i, b in enumerate(bssids.tolist())}
    r = np.full((len(scans), bssids.size), MISSING_DBM, dtype=np.float32)
    for i, s in enumerate(scans):
        for b, v in s.items():
            r[i, col[b]] = v
    fp = FingerprintMap(bssids=bssids, p_xy_m=np.asarray(pos, dtype=float), rssi_dbm=r, method=method,
                        vertices_xy_m=vertices_xy_m, max_age_ms=max_age_ms, scan_time=scan_time,
                        walk_id=np.asarray(wid, dtype=np.int32), t_s=np.asarray(t_s, dtype=float), **options)
    rho = None
    if calibrate:
        fp.cov_scale, fp.outlier_frac, fp.scale_match_db, fp.scale_by_match = calibrate_covariance(fp)
        fp.peak_sigma_m = calibrate_peak_sigma(fp)
        rho = calibrate_walk_corr(fp)
        fp.walk_corr = 0.0 if rho is None else rho
    fp.f3_calibrated, fp.f3_note = f3_calibration(int(np.unique(fp.walk_id).size), calibrate, rho)
    return fp


def f3_calibration(n_walks: int, calibrated: bool, walk_corr: float | None) -> tuple[bool, str]:
    """(f3 usable, why not): f3 needs :data:`MIN_SURVEY_WALKS_F3` survey walks with WiFi and
    a measured walk-long correlation (:func:`calibrate_walk_corr` not None)."""
    if not calibrated:
        return False, "f3 left out: not calibrated (calibrate=False)"
    if n_walks < MIN_SURVEY_WALKS_F3:
        return False, (f"f3 left out: {n_walks} survey walk{'s' if n_walks != 1 else ''} with WiFi cannot calibrate "
                       f"its error and walk-long correlation (needs {MIN_SURVEY_WALKS_F3})")
    if walk_corr is None:
        return False, (f"f3 left out: its walk-long correlation needs {MIN_PAIRS_TO_CALIBRATE} held-out scan pairs "
                       f"≥ {WALK_CORR_MIN_LAG_S:.0f} s apart (longer survey walks)")
    return True, ""


CHI2_2_MEDIAN = 2.0 * np.log(2.0)  # median of a χ² with 2 degrees of freedom
CHI2_2_Q99 = -2.0 * np.log(0.01)  # its 99 % point (9.21)
# Share of held-out survey fixes Σ's scale puts inside their 2σ ellipse: a Gaussian's own
# 1 - e⁻² (86.5 %), i.e. the χ²₂ point 4. The tracker's ellipses answer for 2σ coverage,
# and k-NN errors are heavy-tailed (a scan beyond the survey matches the nearest surveyed
# place), so a scale fitted to the median (the bulk) left the tail's fixes 2-3x too sure.
CALIBRATION_COVER = 1.0 - float(np.exp(-2.0))


def calibrate_covariance(fp: FingerprintMap, folds: int = 5, vertices_xy_m: np.ndarray | None = None,
                         bins: int = 4) -> tuple[float, float, np.ndarray | None, np.ndarray | None]:
    """Σ scale that makes the predictions' Mahalanobis distances honest on the survey itself.

    The survey walks are split into ``folds`` groups (by ``fp.walk_id``); each group's scans
    are predicted from a map of the other groups, and ``s = q(m²) / χ²₂(q)`` with
    ``m² = (p - μ)ᵀ Σ⁻¹ (p - μ)`` for the scan's surveyed position p and q =
    :data:`CALIBRATION_COVER` (86.5 %: the scaled 2σ ellipse holds that share of the
    held-out fixes; never below 1). A quantile, not the mean: the errors are heavy-tailed
    (a scan now and then matches the wrong wing), and the tail beyond 99 % is f3's outlier
    rate ε, not a wider Gaussian.

    k-NN errors grow with how badly the scan matches its best fingerprint (d_min, RMS dB:
    a scan far from any survey point matches none well; on site1/F1 the held-out median
    error is 5.5 m in the best-matching quarter and 25 m in the worst). So for ``knn`` the
    scale is also fitted per ``bins`` quantile bins of d_min, made non-decreasing, and
    interpolated in d_min between the bins' medians (:meth:`FingerprintMap.scale_for`).

    Returns ``(s, ε, d_db, s_by_d)``: ε the outlier rate, the fraction of held-out scans
    beyond the scaled Gaussian's 99 % ellipse less the 1 % it expects there (f3's robust
    form, :func:`posefix.mapmatch.features.f_robust_position`); ``d_db``/``s_by_d`` the
    per-bin table, or None (fewer than 10 predictions a bin, or not k-NN). Without two
    survey walks or any held-out prediction: ``(1, 0, None, None)``.
    """
    if fp.walk_id is None or np.unique(fp.walk_id).size < 2:
        return 1.0, 0.0, None, None
    ids = np.unique(fp.walk_id)
    group = {w: i % folds for i, w in enumerate(ids)}
    g = np.array([group[w] for w in fp.walk_id.tolist()])
    m2, dmin = [], []
    for k in np.unique(g):
        tr, te = g != k, g == k
        sub = FingerprintMap(bssids=fp.bssids, p_xy_m=fp.p_xy_m[tr], rssi_dbm=fp.rssi_dbm[tr], k=fp.k,
                             sigma0_m=fp.sigma0_m, min_common=fp.min_common, method=fp.method,
                             path_loss_exp=fp.path_loss_exp, sigma_db=fp.sigma_db,
                             vertices_xy_m=vertices_xy_m if vertices_xy_m is not None else fp.vertices_xy_m,
                             knn_max_db=fp.knn_max_db, similarity=fp.similarity)
        for p, r in zip(fp.p_xy_m[te], fp.rssi_dbm[te]):
            scan = {b: float(x) for b, x in zip(fp.bssids.tolist(), r.tolist()) if x > MISSING_DBM}
            if fp.method == "knn":
                pred = sub._predict_knn(scan)
            else:
                pred = sub.predict(scan)
            if pred is not None:
                d = p - pred[0]
                m2.append(float(d @ np.linalg.solve(pred[1], d)))
                dmin.append(pred[2] if fp.method == "knn" else np.nan)
    if not m2:
        return 1.0, 0.0, None, None
    m2a, da = np.asarray(m2), np.asarray(dmin)
    qq = CALIBRATION_COVER
    chi = -2.0 * np.log(1.0 - qq)  # its χ²₂ point (4 for 2σ)
    scale = max(1.0, float(np.quantile(m2a, qq)) / chi)
    d_db = s_by_d = None
    per_scan = np.full(m2a.size, scale)
    if fp.method == "knn" and m2a.size >= 10 * bins:
        edges = np.quantile(da, np.linspace(0.0, 1.0, bins + 1))
        which = np.clip(np.searchsorted(edges, da, side="right") - 1, 0, bins - 1)
        d_db = np.array([np.median(da[which == b]) for b in range(bins)])
        s_by_d = np.maximum.accumulate(
            np.array([max(1.0, float(np.quantile(m2a[which == b], qq)) / chi) for b in range(bins)]))
        per_scan = np.interp(da, d_db, s_by_d)
    # Beyond the χ²₂ 99 % point a Gaussian leaves 1 %; the excess is the outlier rate.
    outlier = float(np.mean(m2a / per_scan > CHI2_2_Q99)) - 0.01
    return scale, float(np.clip(outlier, 0.0, 0.5)), d_db, s_by_d


RAYLEIGH_MEDIAN = np.sqrt(2.0 * np.log(2.0))  # median length of a 2-D N(0, σ² I) error, in σ


# Walk-long correlation: scans at least this far apart (2τ of features.WIFI_CORR_S), where the
# AR(1) part of the error has fallen to e⁻² (14 %), measure the part the whole walk shares.
WALK_CORR_MIN_LAG_S = 40.0
MIN_PAIRS_TO_CALIBRATE = 20


def calibrate_walk_corr(fp: FingerprintMap, folds: int = 5, min_lag_s: float = WALK_CORR_MIN_LAG_S,
                        min_pairs: int = MIN_PAIRS_TO_CALIBRATE) -> float | None:
    """Correlation ρ of f3's errors between scans of one walk far apart in time, on the survey.

    A walk's WiFi fixes share an error that does not decay while it walks (the phone, how it
    is held, a route the survey covers only from afar), beside the part that changes with
    the place (features.evidence_share's AR(1)). The survey walks are split into ``folds``
    groups as in :func:`calibrate_covariance`; each held-out scan's error is whitened by its
    predicted Σ (u = L⁻¹(μ - p), Σ = L Lᵀ, so the figure is on the scale the tracker weighs
    it), and over pairs of one walk at least ``min_lag_s`` apart
    ``ρ = Σ u_i·u_j / Σ ½(|u_i|² + |u_j|²)`` (clipped to [0, 0.9]). None (not measured: f3
    is left out, :func:`f3_calibration`) when there are fewer than ``min_pairs`` pairs (no
    times, one walk, short walks).
    """
    if fp.walk_id is None or fp.t_s is None or np.unique(fp.walk_id).size < 2:
        return None
    ids = np.unique(fp.walk_id)
    group = {w: i % folds for i, w in enumerate(ids)}
    g = np.array([group[w] for w in fp.walk_id.tolist()])
    names = fp.bssids.tolist()
    u = np.full((fp.p_xy_m.shape[0], 2), np.nan)
    for k in np.unique(g):
        tr = g != k
        sub = FingerprintMap(bssids=fp.bssids, p_xy_m=fp.p_xy_m[tr], rssi_dbm=fp.rssi_dbm[tr], k=fp.k,
                             sigma0_m=fp.sigma0_m, min_common=fp.min_common, similarity=fp.similarity,
                             cov_scale=fp.cov_scale, scale_match_db=fp.scale_match_db,
                             scale_by_match=fp.scale_by_match)
        for i in np.nonzero(~tr)[0]:
            pred = sub._predict_knn(_row_scan(names, fp.rssi_dbm[i]))
            if pred is not None:
                u[i] = np.linalg.solve(np.linalg.cholesky(pred[1]), pred[0] - fp.p_xy_m[i])
    num = den = 0.0
    pairs = 0
    for w in ids:
        rows = np.nonzero((fp.walk_id == w) & np.isfinite(u[:, 0]))[0]
        far = np.abs(fp.t_s[rows][:, None] - fp.t_s[rows][None, :]) >= min_lag_s
        i, j = np.nonzero(np.triu(far, 1))
        num += float(np.sum(u[rows[i]] * u[rows[j]]))
        den += float(np.sum(0.5 * (np.sum(u[rows[i]] ** 2, axis=1) + np.sum(u[rows[j]] ** 2, axis=1))))
        pairs += i.size
    if pairs < min_pairs or den <= 0.0:
        return None
    return float(np.clip(num / den, 0.0, 0.9))


def _row_scan(bssids: list[str], row: np.ndarray) -> dict[str, float]:
    """One fingerprint row (A,) dBm back to a scan ``{bssid: dBm}`` of the access points heard."""
    heard = np.nonzero(row > MISSING_DBM)[0]
    return {bssids[a]: float(row[a]) for a in heard}


# Held-out peaks needed to calibrate f4's σ. The median of n Rayleigh distances has a
# relative standard error of 0.72/√n (1 / (2 f(m) √n) at the median m = 1.18σ, over m):
# with 30 peaks σ is known to ±26 % (2 SE); with 10, ±46 %, and a σ half too small is the
# overconfidence the calibration is there to remove. On site1/F1 3-5 survey walks give
# 0-24 held-out peaks (σ 3.7-8.0 m where 29 walks give 9.7 m), 8 walks 41-57.
MIN_PEAKS_TO_CALIBRATE = 30


def calibrate_peak_sigma(fp: FingerprintMap, folds: int = 5,
                         min_peaks: int = MIN_PEAKS_TO_CALIBRATE) -> float | None:
    """f4's σ (m) that makes the peak observations honest on the survey itself.

    The survey walks are split into ``folds`` groups (by ``fp.walk_id``, as in
    :func:`calibrate_covariance`); each group's scans, in their walk's order, are searched
    for peaks (:meth:`FingerprintMap.scan_peaks`) against the peak locations of a map of the
    other groups, and each peak's distance r to the scan's surveyed position is measured.
    For a 2-D isotropic Gaussian error r has median σ·√(2 ln 2), so
    ``σ = median(r) / √(2 ln 2)`` (the median: the bulk, as for f3's scale). On site1/F1
    the held-out median r is about 11-12 m, i.e. σ ≈ 10 m, where 3 m had been assumed.

    Returns ``fp.peak_sigma_m`` unchanged (None unless given: f4 left out, see
    :data:`UNCALIBRATED_PEAK_SIGMA`) without two survey walks or with fewer than
    ``min_peaks`` held-out peaks.
    """
    if fp.walk_id is None or np.unique(fp.walk_id).size < 2:
        return fp.peak_sigma_m
    ids = np.unique(fp.walk_id)
    group = {w: i % folds for i, w in enumerate(ids)}
    g = np.array([group[w] for w in fp.walk_id.tolist()])
    names = fp.bssids.tolist()
    r = []
    for k in np.unique(g):
        tr = g != k
        sub = FingerprintMap(bssids=fp.bssids, p_xy_m=fp.p_xy_m[tr], rssi_dbm=fp.rssi_dbm[tr], method="knn",
                             peak_dbm=fp.peak_dbm)
        for w in ids[[group[i] == k for i in ids]]:
            rows = np.nonzero(fp.walk_id == w)[0]  # in the walk's time order (build_fingerprints)
            scans = [(float(i), _row_scan(names, fp.rssi_dbm[i])) for i in rows]
            for i, b in sub.scan_peaks(scans):
                r.append(float(np.linalg.norm(fp.p_xy_m[int(i)] - sub.peak_xy_m[b])))
    if len(r) < min_peaks:
        return fp.peak_sigma_m
    return float(np.median(r)) / RAYLEIGH_MEDIAN


def save_fingerprints(fp: FingerprintMap, path: str | Path) -> int:
    """Write ``.npz`` (members ``format``, ``version``, ``bssids``, ``p_xy_m``, ``rssi_dbm`` and the
    calibration: ``cov_scale``, ``outlier_frac``, ``peak_sigma_m`` (absent when f4's σ is not
    calibrated), ``scale_match_db``, ``scale_by_match``, ``walk_corr``, ``f3_calibrated`` (0/1),
    ``f3_note`` and ``f3_robust`` (0/1: f3's heavy-tailed form); returns bytes."""
    extra = {} if fp.peak_sigma_m is None else {"peak_sigma_m": np.array(fp.peak_sigma_m)}
    extra["walk_corr"] = np.array(fp.walk_corr)
    extra["f3_calibrated"] = np.array(int(fp.f3_calibrated), dtype=np.int8)
    extra["f3_note"] = np.array(fp.f3_note)
    extra["f3_robust"] = np.array(int(fp.robust), dtype=np.int8)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, format=np.array("posefix-fingerprints"), version=np.array(2, dtype=np.int32),
                            bssids=fp.bssids.astype(str), p_xy_m=fp.p_xy_m, rssi_dbm=fp.rssi_dbm,
                            cov_scale=np.array(fp.cov_scale), outlier_frac=np.array(fp.outlier_frac),
                            scale_match_db=np.asarray(fp.scale_match_db if fp.scale_match_db is not None else [], float),
                            scale_by_match=np.asarray(fp.scale_by_match if fp.scale_by_match is not None else [], float),
                            **extra)
    return Path(path).stat().st_size


def _read_flag(z, name: str, path) -> bool:
    flag = int(z[name])
    if flag not in (0, 1):
        raise ValueError(f"{path}:0: field {name}: must be 0 or 1, got {flag}")
    return bool(flag)


def load_fingerprints(path: str | Path, method: str = "knn") -> FingerprintMap:
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}:0: field file: not a fingerprint file: {exc}") from exc
    with z:
        if "format" not in z.files or str(z["format"]) != "posefix-fingerprints":
            raise ValueError(f"{path}:0: field format: not a posefix fingerprint file")
        # Version 1 files have no calibration: Σ as predicted (scale 1), no outliers.
        table: dict = {}
        scale = float(z["cov_scale"]) if "cov_scale" in z.files else 1.0
        eps = float(z["outlier_frac"]) if "outlier_frac" in z.files else 0.0
        if not (np.isfinite(eps) and 0.0 <= eps < 1.0):  # f3's heavy tail: log(ε/V) needs ε in (0, 1)
            raise ValueError(f"{path}:0: field outlier_frac: must be a number in [0, 1), got {eps}")
        # Files written before f4's calibration (or whose σ could not be calibrated) have no
        # peak_sigma_m: f4 is left out for them (UNCALIBRATED_PEAK_SIGMA), not given 3 m.
        if "peak_sigma_m" in z.files:
            sig = float(z["peak_sigma_m"])
            if not (np.isfinite(sig) and sig > 0.0):
                raise ValueError(f"{path}:0: field peak_sigma_m: must be a positive number of metres, got {sig}")
            table["peak_sigma_m"] = sig
        if "walk_corr" in z.files:  # files before it: 0, the AR(1) discount alone
            rho = float(z["walk_corr"])
            if not (np.isfinite(rho) and 0.0 <= rho < 1.0):
                raise ValueError(f"{path}:0: field walk_corr: must be a number in [0, 1), got {rho}")
            table["walk_corr"] = rho
        # Files before it: f3 on, as they were tracked (their calibration cannot be judged).
        if "f3_calibrated" in z.files:
            table["f3_calibrated"] = _read_flag(z, "f3_calibrated", path)
            table["f3_note"] = str(z["f3_note"]) if "f3_note" in z.files else ""
        # Files before it were tracked with the plain Gaussian f3.
        table["robust"] = False
        if "f3_robust" in z.files:
            table["robust"] = _read_flag(z, "f3_robust", path)
        if "scale_match_db" in z.files and z["scale_match_db"].size:
            if z["scale_match_db"].shape != z["scale_by_match"].shape:
                raise ValueError(f"{path}:0: field scale_by_match: shape differs from scale_match_db")
            table.update(scale_match_db=z["scale_match_db"], scale_by_match=z["scale_by_match"])
        return FingerprintMap(bssids=z["bssids"], p_xy_m=z["p_xy_m"], rssi_dbm=z["rssi_dbm"], method=method,
                              cov_scale=scale, outlier_frac=eps, **table)
