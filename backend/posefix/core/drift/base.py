"""The drift models' shared bottom: the estimate they produce and the arithmetic they share.

Notation (every model): keyframe i at time t_i, reported position p~_i, location
measurement g_i (NaN where there is no fix), u_i = g_i - p~_i; an edit k at keyframe e_k
moves the run to c_k, so its offset is d_k = g~(t_k) - c_k, with g~ the fix made robust
against outliers and white noise: p~ plus the median of u over the neighbouring keyframes
(the reported pose keeps its local shape, so u varies slowly over them).

White sigma of u from the MAD of consecutive differences: for white u with sigma s,
u_i+1 - u_i has sigma s sqrt 2, so ``s = 1.4826 MAD(du) / sqrt 2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MEDIAN_EFFICIENCY = 1.2533  # sigma of a sample median / (sigma / sqrt(n)) for Gaussian data


@dataclass(frozen=True)
class DriftEstimate:
    """What the edits say about the location measurements' bias.

    offset_enu_m : (3,) robust mean (median) of the edit offsets g - c, metres (NaN vertical
        when no 3-D edit).
    spread_m : robust horizontal spread (MAD-based sigma) of the edit offsets, metres.
    walk_m2_per_s : wander rate q = 2 sigma_b^2 / tau of the bias, m^2/s per axis.
    sigma_b_m, tau_s : stationary sigma (per axis) and correlation time of the bias model.
    detected : True when the edits show a bias the location term must not be trusted for.
    bias_enu_m : (k,3) bias at each keyframe (g - truth), metres.
    bias_sigma_m : (k,) horizontal one-sigma uncertainty of that bias, metres.
    weight : (k,) factor on the location term's information (1 = untouched, -> 0 = ignored).
    edit_offsets_enu_m : (m,3) the per-edit offsets d_k, in time order.
    edit_t_s : (m,) their times.
    """

    offset_enu_m: np.ndarray
    spread_m: float
    walk_m2_per_s: float
    detected: bool
    bias_enu_m: np.ndarray
    bias_sigma_m: np.ndarray
    weight: np.ndarray
    edit_offsets_enu_m: np.ndarray
    edit_t_s: np.ndarray
    sigma_b_m: float = 0.0
    tau_s: float = 0.0
    n_steps: int = 0
    loc_sigma_h_m: np.ndarray | None = None
    calibration: object | None = None  # engine.calibrate.Calibration: the model the run's edits chose


    def to_json(self) -> dict:
        return {
            "offset_enu_m": [None if not np.isfinite(v) else float(v) for v in self.offset_enu_m],
            "spread_m": float(self.spread_m),
            "walk_m2_per_s": float(self.walk_m2_per_s),
            "sigma_b_m": float(self.sigma_b_m),
            "tau_s": float(self.tau_s),
            "n_steps": int(self.n_steps),
            "gnss_levels": self.loc_sigma_h_m is not None,
            "detected": bool(self.detected),
            "n_edits": int(len(self.edit_t_s)),
            "max_bias_m": float(np.max(np.hypot(*self.bias_enu_m[:, :2].T))) if len(self.bias_enu_m) else 0.0,
            "calibration": None if self.calibration is None else self.calibration.to_json(),
        }


def no_drift(n_keyframes: int) -> DriftEstimate:
    """The estimate when drift handling is off or there are no edits."""
    return DriftEstimate(
        offset_enu_m=np.full(3, np.nan),
        spread_m=0.0,
        walk_m2_per_s=0.0,
        detected=False,
        bias_enu_m=np.zeros((n_keyframes, 3)),
        bias_sigma_m=np.zeros(n_keyframes),
        weight=np.ones(n_keyframes),
        edit_offsets_enu_m=np.zeros((0, 3)),
        edit_t_s=np.zeros(0),
    )


@dataclass(frozen=True)
class DriftParams:
    """The bias model's parameters held from a previous solve, so one more edit (a live drag)
    changes the bias only around it instead of re-estimating the whole run's model.

    sigma2_m2, tau_s: the Gauss-Markov bias's stationary variance (per axis) and correlation
    time; detected: whether that solve found a bias; previous: its estimate, whose GNSS
    levels a live drag keeps beyond the drag (``levels.levels_near_new_edits``).
    """

    sigma2_m2: float
    tau_s: float
    detected: bool
    previous: DriftEstimate | None = None

    @classmethod
    def of(cls, est: DriftEstimate) -> "DriftParams":
        return cls(float(est.sigma_b_m) ** 2, float(est.tau_s), bool(est.detected), est)


def edit_offsets(
    kf_t_s: np.ndarray,
    p_rep_m: np.ndarray,
    g_m: np.ndarray,
    edit_kf: np.ndarray,
    edit_c_m: np.ndarray,
    window: int = 5,
) -> np.ndarray:
    """Offsets d_k = g~(t_k) - c_k (m,3) with g~ = p~ + median of (g - p~) over +-window keyframes.

    NaN rows of g (no fix) are ignored; a window without any fix gives d = p~ - c.
    Vectorised over the edits: each window is gathered into an (m, 2 window + 1, 3) block,
    missing fixes sorted to its end as +inf, and the median read at the middle of the valid part.
    """
    u = g_m - p_rep_m
    k = len(kf_t_s)
    edit_kf = np.asarray(edit_kf, dtype=np.int64)
    if len(edit_kf) == 0:
        return np.zeros((0, 3))
    rows = edit_kf[:, None] + np.arange(-window, window + 1)[None, :]
    local = u[np.clip(rows, 0, k - 1)]  # (m, w, 3)
    valid = (rows >= 0) & (rows < k) & np.all(np.isfinite(local), axis=2)
    local = np.where(valid[:, :, None], local, np.inf)
    local.sort(axis=1)
    n = valid.sum(axis=1)
    lo = np.maximum((n - 1) // 2, 0)[:, None, None]
    hi = np.maximum(n // 2, 0)[:, None, None]
    a = np.take_along_axis(local, np.broadcast_to(lo, (len(n), 1, 3)), axis=1)[:, 0]
    b = np.take_along_axis(local, np.broadcast_to(hi, (len(n), 1, 3)), axis=1)[:, 0]
    shift = np.where(n[:, None] > 0, 0.5 * (a + b), 0.0)
    return p_rep_m[edit_kf] + shift - np.asarray(edit_c_m, dtype=float)


def keyframes_in(seconds: float, kf_t_s: np.ndarray, at_least: int = 1) -> int:
    """``seconds`` in keyframes at the run's typical keyframe spacing (at least ``at_least``)."""
    dt = float(np.median(np.diff(kf_t_s))) if len(kf_t_s) > 1 else 1.0
    return max(int(round(seconds / max(dt, 1e-9))), at_least)


def keyframe_means(t_s: np.ndarray, u: np.ndarray, kf_t_s: np.ndarray) -> np.ndarray:
    """Mean of u (n,d) over the samples nearer each keyframe time than its neighbours' (k,d); NaN where none."""
    edges = 0.5 * (kf_t_s[1:] + kf_t_s[:-1])
    b = np.searchsorted(edges, t_s, side="right")
    ok = np.all(np.isfinite(u), axis=1)
    k, d = len(kf_t_s), u.shape[1]
    s = np.zeros((k, d))
    n = np.bincount(b[ok], minlength=k).astype(float)
    for j in range(d):
        s[:, j] = np.bincount(b[ok], weights=u[ok, j], minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n[:, None] > 0, s / n[:, None], np.nan)


def white_sigma(u: np.ndarray) -> float:
    """Per-axis sigma of the white part of u (k,d): MAD of consecutive differences / sqrt 2."""
    ok = np.all(np.isfinite(u), axis=1)
    du = np.diff(u[ok], axis=0)
    if len(du) < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(du - np.median(du, axis=0))) / np.sqrt(2.0))


def fill_gaps(u: np.ndarray) -> np.ndarray:
    """Rows of u (k,d) without a fix (NaN) filled by linear interpolation along the rows; zeros when none has one."""
    ok = np.all(np.isfinite(u), axis=1)
    if np.all(ok):
        return u
    if not np.any(ok):
        return np.zeros_like(u)
    idx = np.arange(len(u))
    return np.column_stack([np.interp(idx, idx[ok], u[ok, j]) for j in range(u.shape[1])])
