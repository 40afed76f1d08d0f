"""Phone sensors to steps: walk-file parsing, step detection, step length, heading.

Walk files are the Indoor Location Competition 2.0 path files: ``#`` header lines, then
tab-separated ``unix_ms TYPE values...`` lines. ``TYPE_WAYPOINT`` lines are ground truth;
:func:`read_walk` keeps them apart (``Walk.waypoints``) and nothing in the tracker reads them.

Step length (Weinberg-style linear frequency model, as in the MapCraft patent)::

    l = h * (alpha * f + beta) + gamma        [m]

with ``h`` the walker's height (m), ``f`` the step frequency (Hz, 1 / time since the
previous step), ``alpha`` (s), ``beta`` (1) and ``gamma`` (m) constants learned by hard EM
(:mod:`posefix.mapmatch.learn`). Defaults give 0.70 m at 1.8 Hz for a 1.70 m walker.

Heading: the Android rotation vector is the rotation device -> world with world
x = east, y = magnetic north, z = up. For a phone held flat and pointing forward, the
walking direction is the device y axis; its angle counter-clockwise from east is
``heading_rad = atan2(R[1, 1], R[0, 1])``. The floor frame is x east, y north, so the
only difference is a constant ``heading_bias_rad`` (declination, building steel, the
floor plan's rotation), which is learned.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import find_peaks

__all__ = [
    "WalkFormatError",
    "Walk",
    "StepModel",
    "Steps",
    "read_walk",
    "quat_xyzw_from_rotation_vector",
    "heading_from_rotation_vector",
    "heading_from_gyro_mag",
    "initial_heading_bias_gyro_mag",
    "detect_steps",
    "steps_from_walk",
    "wifi_scans",
]

GRAVITY_MPS2 = 9.80665
WIFI_MAX_AGE_MS = 3000.0  # one Android scan cycle (2-4 s): older entries are cached from earlier scans


class WalkFormatError(ValueError):
    """A walk file line that cannot be read; ``str()`` names file, line and field."""

    def __init__(self, file: str, line: int, field: str, message: str):
        self.file, self.line, self.field = file, line, field
        super().__init__(f"{file}:{line}: field {field}: {message}")


@dataclass(frozen=True)
class Walk:
    """One parsed walk. Times are unix milliseconds, as in the file.

    Sensor arrays are ``(n, 1 + m)``: column 0 the time (ms), then the m values.
    ``wifi`` rows are ``(t_ms, bssid, rssi_dbm, last_seen_ms)``: ``t_ms`` the line's time (when
    the scan was delivered; one scan's lines share it), ``last_seen_ms`` the access point's own
    last-seen time (``t_ms`` when the file has none). :func:`wifi_scans` groups them into scans.
    ``waypoints`` is ``(w, 3)`` = ``t_ms, x_m, y_m``: ground truth, never used for tracking.
    """

    path: str
    acc: np.ndarray
    gyro: np.ndarray
    mag: np.ndarray
    rotvec: np.ndarray
    wifi: list[tuple[int, str, float, int]]
    waypoints: np.ndarray
    header: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class StepModel:
    """Step-length model ``l = h (alpha f + beta) + gamma`` plus heading bias.

    ``height_m``: walker height h (m); ``alpha_s`` (s), ``beta`` (-), ``gamma_m`` (m);
    ``heading_bias_rad``: added to the sensor heading to get the floor-frame heading.
    ``min_len_m``/``max_len_m`` clip the model to physical step lengths.
    """

    height_m: float = 1.70
    alpha_s: float = 0.10
    beta: float = 0.232
    gamma_m: float = 0.0
    heading_bias_rad: float = 0.0
    min_len_m: float = 0.3
    max_len_m: float = 1.2

    def length_m(self, freq_hz: np.ndarray) -> np.ndarray:
        """Step lengths (m) for step frequencies ``freq_hz`` (n,)."""
        f = np.asarray(freq_hz, dtype=float)
        l = self.height_m * (self.alpha_s * f + self.beta) + self.gamma_m
        return np.clip(l, self.min_len_m, self.max_len_m)


@dataclass(frozen=True)
class Steps:
    """Detected steps of one walk: ``t_ms`` (n,) int64, ``freq_hz`` (n,),
    ``heading_rad`` (n,) sensor heading CCW from east *before* the bias."""

    t_ms: np.ndarray
    freq_hz: np.ndarray
    heading_rad: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ms.shape[0])

    def vectors_m(self, model: StepModel) -> np.ndarray:
        """Step displacement vectors (n, 2) in the floor frame (m)."""
        l = model.length_m(self.freq_hz)
        th = self.heading_rad + model.heading_bias_rad
        return np.stack([l * np.cos(th), l * np.sin(th)], axis=1)


_SENSORS = {
    "TYPE_ACCELEROMETER": ("acc", 3),
    "TYPE_GYROSCOPE": ("gyro", 3),
    "TYPE_MAGNETIC_FIELD": ("mag", 3),
    "TYPE_ROTATION_VECTOR": ("rotvec", 3),
}


def read_walk(path: str | Path) -> Walk:
    """Parse a competition path file. Raises :class:`WalkFormatError` on bad lines."""
    path = str(path)
    rows: dict[str, list[list[float]]] = {k: [] for k, _ in _SENSORS.values()}
    wifi: list[tuple[int, str, float, int]] = []
    waypoints: list[list[float]] = []
    header: dict[str, str] = {}
    try:
        fh = open(path, encoding="utf-8", errors="replace")
    except OSError as exc:
        raise WalkFormatError(path, 0, "file", f"cannot open: {exc.strerror}") from exc
    with fh:
        for lineno, line in enumerate(fh, start=1):
            line = line.rstrip("\r\n")
            if not line:
                continue
            if line.startswith("#"):
                for part in line[1:].split("\t"):
                    if ":" in part:
                        k, _, v = part.partition(":")
                        header.setdefault(k.strip(), v.strip())
                continue
            parts = line.split("\t")
            if len(parts) < 2:
                raise WalkFormatError(path, lineno, "type", "expected 'unix_ms<TAB>TYPE ...'")
            kind = parts[1]
            try:
                t_ms = int(parts[0])
            except ValueError:
                raise WalkFormatError(path, lineno, "unix_ms", f"not an integer: {parts[0]!r}")
            if kind in _SENSORS:
                name, m = _SENSORS[kind]
                try:
                    vals = [float(v) for v in parts[2 : 2 + m]]
                except ValueError:
                    raise WalkFormatError(path, lineno, kind, "values must be numbers")
                if len(vals) != m:
                    raise WalkFormatError(path, lineno, kind, f"expected {m} values")
                rows[name].append([t_ms, *vals])
            elif kind == "TYPE_WIFI":
                if len(parts) < 5:
                    raise WalkFormatError(path, lineno, "TYPE_WIFI", "expected ssid, bssid, rssi")
                try:
                    rssi = float(parts[4])
                except ValueError:
                    raise WalkFormatError(path, lineno, "rssi", f"not a number: {parts[4]!r}")
                seen_ms = t_ms
                if len(parts) >= 7 and parts[6].strip():
                    try:
                        seen_ms = int(parts[6])
                    except ValueError:
                        raise WalkFormatError(path, lineno, "last_seen_timestamp", f"not an integer: {parts[6]!r}")
                wifi.append((t_ms, parts[3], rssi, seen_ms))
            elif kind == "TYPE_WAYPOINT":
                try:
                    waypoints.append([t_ms, float(parts[2]), float(parts[3])])
                except (ValueError, IndexError):
                    raise WalkFormatError(path, lineno, "TYPE_WAYPOINT", "expected x y in metres")
    arrays = {k: np.asarray(v, dtype=float).reshape(-1, 4) for k, v in rows.items()}
    for name in ("acc", "rotvec"):
        if arrays[name].shape[0] < 10:
            raise WalkFormatError(path, 0, name, "too few samples to detect steps")
    return Walk(
        path=path,
        acc=arrays["acc"],
        gyro=arrays["gyro"],
        mag=arrays["mag"],
        rotvec=arrays["rotvec"],
        wifi=wifi,
        waypoints=np.asarray(waypoints, dtype=float).reshape(-1, 3),
        header=header,
    )


def quat_xyzw_from_rotation_vector(rv: np.ndarray) -> np.ndarray:
    """Android rotation vector (n, 3) = ``sin(θ/2)·axis`` -> unit quaternions (n, 4) x,y,z,w."""
    rv = np.asarray(rv, dtype=float)
    w = np.sqrt(np.clip(1.0 - np.sum(rv**2, axis=1), 0.0, None))
    q = np.column_stack([rv, w])
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def heading_from_rotation_vector(rv: np.ndarray) -> np.ndarray:
    """Heading (n,) rad CCW from east of the device y axis, from rotation vectors (n, 3).

    The device y axis in the world is column 1 of R(q): ``(2(xy - zw), 1 - 2(x² + z²))``
    for its east and north components.
    """
    x, y, z, w = quat_xyzw_from_rotation_vector(rv).T
    east = 2.0 * (x * y - z * w)
    north = 1.0 - 2.0 * (x * x + z * z)
    return np.arctan2(north, east)


def _interp_rows(t_query: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Linear interpolation of each value column of ``rows`` (n, 1+m) at ``t_query``."""
    return np.column_stack([np.interp(t_query, rows[:, 0], rows[:, j]) for j in range(1, rows.shape[1])])


def _tilt_compensated_mag_heading(acc: np.ndarray, mag: np.ndarray) -> np.ndarray:
    """Heading (n,) of the device y axis from gravity ``acc`` (n,3) and ``mag`` (n,3), device frame.

    East = mag × up, north = up × east (both in the device frame); the device y axis
    (0, 1, 0) has components ``east[1]``, ``north[1]``.
    """
    up = acc / np.linalg.norm(acc, axis=1, keepdims=True)
    east = np.cross(mag, up)
    east /= np.linalg.norm(east, axis=1, keepdims=True)
    north = np.cross(up, east)
    return np.arctan2(north[:, 1], east[:, 1])


def heading_from_gyro_mag(walk: Walk, t_ms: np.ndarray, mag_gain: float = 0.02) -> np.ndarray:
    """Heading (len(t_ms),) rad from the gyroscope, pulled slowly towards the magnetometer.

    Complementary filter: ``θ_pred = θ_{k-1} + ω_up·dt``, ``θ_k = θ_pred + mag_gain·wrap(θ_mag - θ_pred)``
    where ``ω_up`` is the rotation rate about gravity (rad/s, CCW seen from above, which
    turns the device y axis CCW) and ``θ_mag`` the tilt-compensated magnetometer heading. The gain 0.02 per sample at 50 Hz
    is a ~1 s time constant: gyro for turns, magnetometer for the long-term reference.
    """
    acc_t = walk.acc[:, 0]
    grid = walk.gyro[:, 0] if walk.gyro.shape[0] > 10 else acc_t
    acc = _interp_rows(grid, walk.acc)
    mag = _interp_rows(grid, walk.mag)
    gyr = _interp_rows(grid, walk.gyro) if walk.gyro.shape[0] > 10 else np.zeros_like(acc)
    up = acc / np.linalg.norm(acc, axis=1, keepdims=True)
    # A positive rotation about the up axis (CCW seen from above) turns the device y axis
    # CCW, which increases the heading measured CCW from east.
    w_up = np.sum(gyr * up, axis=1)
    th_mag = _tilt_compensated_mag_heading(acc, mag)
    th = np.empty_like(th_mag)
    th[0] = th_mag[0]
    dt = np.diff(grid, prepend=grid[0]) / 1000.0
    for k in range(1, th.size):
        pred = th[k - 1] + w_up[k] * dt[k]
        th[k] = pred + mag_gain * _wrap(th_mag[k] - pred)
    un = np.unwrap(th)
    return _wrap(np.interp(t_ms, grid, un))


def initial_heading_bias_gyro_mag(walk: Walk, t0_s: float = 30.0, t1_s: float = 90.0) -> float:
    """Offset (rad) between the gyro+magnetometer heading and the rotation-vector heading.

    Circular mean of ``θ_gyro+mag - θ_rotvec`` over the window [t0_s, t1_s] after the start
    (shortened to the walk if it is shorter). Add it to rotation-vector headings to express
    them in the gyro+mag reference, or subtract to go the other way.
    """
    t = walk.rotvec[:, 0]
    rel = (t - t[0]) / 1000.0
    sel = (rel >= min(t0_s, rel[-1] * 0.3)) & (rel <= t1_s)
    if not np.any(sel):
        sel = np.ones_like(rel, dtype=bool)
    th_rv = heading_from_rotation_vector(walk.rotvec[sel, 1:4])
    th_gm = heading_from_gyro_mag(walk, t[sel])
    d = th_gm - th_rv
    return float(np.arctan2(np.mean(np.sin(d)), np.mean(np.cos(d))))


def _wrap(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angles in radians wrapped to [-π, π)."""
    return _wrap(a)


def detect_steps(
    acc: np.ndarray,
    min_interval_s: float = 0.30,
    min_prominence_mps2: float = 2.0,
    cutoff_hz: float = 2.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Steps from the accelerometer (n, 4) = ``t_ms, ax, ay, az`` (m/s²).

    The magnitude minus gravity is low-passed (2nd-order Butterworth at ``cutoff_hz``,
    run forwards and backwards so peaks are not delayed; walking cadence is 1.4-2.4 Hz)
    and each peak that stands ``min_prominence_mps2`` above its surrounding valleys and
    comes at least ``min_interval_s`` after the previous one is a step. A heel strike's
    peak-to-valley swing is 2-5 m/s²; the phone's hand tremor while standing is well
    under 1 m/s². (Chosen on the even-numbered shared walks, checked on the odd ones:
    the dead-reckoning error at waypoints drops from 5.6 to 3.5 m against a 0.6 m/s²
    height threshold on a 0.15 s moving average.) Returns ``t_ms`` (k,) int64 and the
    step frequency ``freq_hz`` (k,), the median of 1 / interval over the step and its two
    neighbours (a single interval is noisy); pauses over 1 s count as 1.8 Hz.
    """
    from scipy.signal import butter, filtfilt

    t = acc[:, 0]
    if t.size < 16:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    dt_s = max(float(np.median(np.diff(t))) / 1000.0, 1e-3)
    a = np.linalg.norm(acc[:, 1:4], axis=1) - GRAVITY_MPS2
    wn = min(cutoff_hz * 2.0 * dt_s, 0.99)
    b_f, a_f = butter(2, wn)
    a_s = filtfilt(b_f, a_f, a)
    idx, _ = find_peaks(a_s, prominence=min_prominence_mps2, distance=max(1, int(min_interval_s / dt_s)))
    t_ms = t[idx].astype(np.int64)
    if t_ms.size < 2:
        return t_ms, np.full(t_ms.size, 1.8)
    gaps_s = np.diff(t_ms) / 1000.0
    f = np.where(gaps_s > 1.0, 1.8, 1.0 / np.maximum(gaps_s, 1e-3))
    f = np.concatenate([[f[0]], f])
    pad = np.concatenate([[f[0]], f, [f[-1]]])
    freq = np.median(np.stack([pad[:-2], pad[1:-1], pad[2:]]), axis=0)
    return t_ms, freq


def steps_from_walk(walk: Walk, heading: str = "rotation_vector") -> Steps:
    """Detect steps and attach their sensor heading (``rotation_vector`` or ``gyro_mag``)."""
    t_ms, freq = detect_steps(walk.acc)
    if heading == "rotation_vector":
        # Unwrap before interpolating so a ±π crossing does not average to zero.
        th = np.unwrap(heading_from_rotation_vector(walk.rotvec[:, 1:4]))
        th_steps = _wrap(np.interp(t_ms, walk.rotvec[:, 0], th))
    elif heading == "gyro_mag":
        th_steps = heading_from_gyro_mag(walk, t_ms)
    else:
        raise ValueError(f"heading must be 'rotation_vector' or 'gyro_mag', got {heading!r}")
    return Steps(t_ms=t_ms, freq_hz=freq, heading_rad=np.asarray(th_steps, dtype=float))


def wifi_scans(walk: Walk, max_age_ms: float | None = WIFI_MAX_AGE_MS,
               scan_time: str = "median") -> list[tuple[int, dict[str, float]]]:
    """WiFi rows grouped into scans: list of ``(t_ms, {bssid: rssi_dbm})`` in time order.

    One scan = the lines delivered together (same line time). Android reports, with each
    scan, access points it heard in *earlier* scans (cached, with their old last-seen
    time): an entry whose last-seen time is more than ``max_age_ms`` older than the newest
    entry of its scan is dropped (None keeps all). The scan's ``t_ms`` is when it was
    measured, not delivered: the ``"median"`` (default) or ``"newest"`` last-seen time of
    the kept entries, or ``"line"`` for the delivery time. (The delivery comes 0.2-0.7 s
    after the newest entry on the competition files, and one scan's fresh entries spread
    over 1-3 s as the radio sweeps the channels: 1-3 m of walking.)
    """
    if scan_time not in ("median", "newest", "line"):
        raise ValueError(f"scan_time must be 'median', 'newest' or 'line', got {scan_time!r}")
    groups: dict[int, list[tuple]] = {}
    for row in walk.wifi:
        groups.setdefault(int(row[0]), []).append(row)
    out = []
    for t_line, rows in groups.items():
        seen = np.array([r[3] if len(r) > 3 else r[0] for r in rows], dtype=float)
        keep = np.ones(seen.size, bool) if max_age_ms is None else seen >= seen.max() - max_age_ms
        scan: dict[str, float] = {}
        for r, k in zip(rows, keep):
            if k:
                scan[r[1]] = float(r[2])
        if scan_time == "line":
            t = t_line
        elif scan_time == "newest":
            t = int(seen[keep].max())
        else:
            t = int(np.median(seen[keep]))
        out.append((t, scan))
    out.sort(key=lambda x: x[0])
    return out
