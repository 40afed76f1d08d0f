"""WiFi fingerprint map (f3) and access-point RSSI peaks (f4), built from surveyed walks.

Survey: every WiFi scan of a walk with waypoints is placed at the straight-line position
between the waypoints around its time (the competition's assumption); scans outside the
first..last waypoint span are not used. The map is the matrix of RSSI (dBm; -100 for an
access point not heard) over those positions.

f3 prediction (weighted k-nearest neighbours in signal space): for a scan r, the distance
to fingerprint i is the RMS RSSI difference over the access points either heard,
``d_i = sqrt(mean_a (r_a - R_ia)²)``; the k nearest with weights ``1 / (d_i + 1 dB)``
give the mean position μ and covariance ``Σ = Σ_i w_i (p_i - μ)(p_i - μ)ᵀ + σ0² I`` with
σ0 = 2 m (a survey point's own uncertainty). Scans sharing fewer than ``min_common``
access points with the map predict nothing.

f4 peaks: an access point's peak location is the survey position of its strongest
reading, kept when that is at least ``peak_dbm`` (-55 dBm: within a few metres of it).
While tracking, a scan where that access point reads ≥ ``peak_dbm`` and more than in the
scans just before and after is a peak; its observation is (peak location, σ = 3 m).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from posefix.mapmatch.sensors import Walk, wifi_scans

__all__ = ["FingerprintMap", "build_fingerprints", "save_fingerprints", "load_fingerprints"]

MISSING_DBM = -100.0


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
    peak_sigma_m: float = 3.0

    def __post_init__(self):
        self._col = {b: i for i, b in enumerate(self.bssids.tolist())}
        best = np.argmax(self.rssi_dbm, axis=0) if self.rssi_dbm.size else np.zeros(0, dtype=int)
        strong = self.rssi_dbm[best, np.arange(self.rssi_dbm.shape[1])] >= self.peak_dbm if self.rssi_dbm.size else np.zeros(0, bool)
        self.peak_xy_m = {self.bssids[a]: self.p_xy_m[best[a]] for a in np.nonzero(strong)[0]}

    def _vector(self, scan: dict[str, float]) -> tuple[np.ndarray, int]:
        v = np.full(self.bssids.shape[0], MISSING_DBM, dtype=np.float32)
        n = 0
        for b, r in scan.items():
            j = self._col.get(b)
            if j is not None:
                v[j] = r
                n += 1
        return v, n

    def predict(self, scan: dict[str, float]) -> tuple[np.ndarray, np.ndarray] | None:
        """Position (μ (2,), Σ (2, 2)) in floor metres for one scan, or None."""
        v, n = self._vector(scan)
        if n < self.min_common or self.p_xy_m.shape[0] == 0:
            return None
        heard = (self.rssi_dbm > MISSING_DBM) | (v > MISSING_DBM)[None, :]
        diff2 = np.where(heard, (self.rssi_dbm - v[None, :]) ** 2, 0.0)
        d = np.sqrt(diff2.sum(axis=1) / np.maximum(heard.sum(axis=1), 1))
        k = min(self.k, d.size)
        nn = np.argpartition(d, k - 1)[:k]
        w = 1.0 / (d[nn] + 1.0)
        w /= w.sum()
        p = self.p_xy_m[nn]
        mu = w @ p
        dp = p - mu
        cov = (dp * w[:, None]).T @ dp + np.eye(2) * self.sigma0_m**2
        return mu, cov

    def predict_walk(self, walk: Walk):
        """[(t_ms, μ, Σ)] for every scan of a walk that predicts a position."""
        out = []
        for t_ms, scan in wifi_scans(walk):
            r = self.predict(scan)
            if r is not None:
                out.append((t_ms, r[0], r[1]))
        return out

    def peaks_in_walk(self, walk: Walk):
        """[(t_ms, peak_xy (2,), sigma_m)] for RSSI peaks of known access points (f4)."""
        scans = wifi_scans(walk)
        out = []
        for j, (t_ms, scan) in enumerate(scans):
            for b, r in scan.items():
                if b not in self.peak_xy_m or r < self.peak_dbm:
                    continue
                before = scans[j - 1][1].get(b, MISSING_DBM) if j > 0 else MISSING_DBM
                after = scans[j + 1][1].get(b, MISSING_DBM) if j + 1 < len(scans) else MISSING_DBM
                if r > before and r >= after:
                    out.append((t_ms, self.peak_xy_m[b], self.peak_sigma_m))
        return out


def build_fingerprints(walks: list[Walk]) -> FingerprintMap:
    """Fingerprint map from walks with waypoints (module docstring)."""
    pos, scans = [], []
    for w in walks:
        wp = w.waypoints
        if wp.shape[0] < 2:
            continue
        for t_ms, scan in wifi_scans(w):
            if wp[0, 0] <= t_ms <= wp[-1, 0]:
                pos.append([np.interp(t_ms, wp[:, 0], wp[:, 1]), np.interp(t_ms, wp[:, 0], wp[:, 2])])
                scans.append(scan)
    if not scans:
        raise ValueError("no WiFi scan between two waypoints in the given walks: nothing to build a map from")
    bssids = np.array(sorted({b for s in scans for b in s}))
    col = {b: i for i, b in enumerate(bssids.tolist())}
    r = np.full((len(scans), bssids.size), MISSING_DBM, dtype=np.float32)
    for i, s in enumerate(scans):
        for b, v in s.items():
            r[i, col[b]] = v
    return FingerprintMap(bssids=bssids, p_xy_m=np.asarray(pos, dtype=float), rssi_dbm=r)


def save_fingerprints(fp: FingerprintMap, path: str | Path) -> int:
    """Write ``.npz`` (members ``format``, ``version``, ``bssids``, ``p_xy_m``, ``rssi_dbm``); returns bytes."""
    with open(path, "wb") as fh:
        np.savez_compressed(fh, format=np.array("posefix-fingerprints"), version=np.array(1, dtype=np.int32),
                            bssids=fp.bssids.astype(str), p_xy_m=fp.p_xy_m, rssi_dbm=fp.rssi_dbm)
    return Path(path).stat().st_size


def load_fingerprints(path: str | Path) -> FingerprintMap:
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}:0: field file: not a fingerprint file: {exc}") from exc
    with z:
        if "format" not in z.files or str(z["format"]) != "posefix-fingerprints":
            raise ValueError(f"{path}:0: field format: not a posefix fingerprint file")
        return FingerprintMap(bssids=z["bssids"], p_xy_m=z["p_xy_m"], rssi_dbm=z["rssi_dbm"])
