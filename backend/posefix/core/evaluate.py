"""Trajectory error of a run against ground truth (evo's APE, for geodetic input).

For each sample ``i`` of RUN inside TRUTH's time span, TRUTH's position is interpolated
linearly in time (in ECEF, so the interpolation is exact along straight chords) and the
error vector is expressed in the local East-North-Up frame at that truth position::

    e_i = R_ECEF->ENU(φ_i, λ_i) (x_run,i - x_truth(t_i))

Horizontal error is ``|e_i[:2]|``, 3-D error ``|e_i|``. Statistics: RMSE, mean, median,
95th percentile and maximum, as evo reports them. Unlike evo's APE there is no alignment
step: geodetic runs share one absolute frame, and an offset is exactly what we measure.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from posefix.core.geodesy import geodetic_to_ecef, rotation_ecef_to_enu
from posefix.core.run import PoseRun

__all__ = ["ErrorStats", "Evaluation", "evaluate", "position_errors_enu_m"]


@dataclass(frozen=True)
class ErrorStats:
    """Summary of error magnitudes, metres."""

    rmse_m: float
    mean_m: float
    median_m: float
    p95_m: float
    max_m: float

    @classmethod
    def of(cls, err_m: np.ndarray) -> ErrorStats:
        e = np.asarray(err_m, dtype=float)
        return cls(
            rmse_m=float(np.sqrt(np.mean(e * e))),
            mean_m=float(np.mean(e)),
            median_m=float(np.median(e)),
            p95_m=float(np.percentile(e, 95)),
            max_m=float(np.max(e)),
        )


@dataclass(frozen=True)
class Evaluation:
    """Errors of a run against truth.

    Attributes
    ----------
    horizontal, three_d : ErrorStats
    n_compared : int
        Samples of RUN inside TRUTH's time span (the ones measured).
    n_outside : int
        Samples of RUN outside TRUTH's time span (not measured).
    """

    horizontal: ErrorStats
    three_d: ErrorStats
    n_compared: int
    n_outside: int

    def to_dict(self) -> dict:
        return {
            "horizontal": asdict(self.horizontal),
            "3d": asdict(self.three_d),
            "n_compared": self.n_compared,
            "n_outside": self.n_outside,
        }


def position_errors_enu_m(truth: PoseRun, run: PoseRun) -> tuple[np.ndarray, np.ndarray]:
    """Error vectors of RUN against TRUTH interpolated at RUN's times.

    Returns
    -------
    e_enu_m : ndarray, shape (m, 3)
        Errors in the local ENU frame at the truth position, metres.
    inside : ndarray, shape (n,), bool
        Which RUN samples lie in TRUTH's time span (the rows of ``e_enu_m``).
    """
    t = run.t_s
    inside = (t >= truth.t_s[0]) & (t <= truth.t_s[-1])
    x_truth = geodetic_to_ecef(truth.lat_deg, truth.lon_deg, truth.alt_m)
    ts = t[inside]
    # Interpolate relative to the first truth point to keep precision in the weights.
    ref = x_truth[0]
    x_t = np.column_stack([np.interp(ts, truth.t_s, x_truth[:, k] - ref[k]) for k in range(3)]) + ref
    x_r = geodetic_to_ecef(run.lat_deg[inside], run.lon_deg[inside], run.alt_m[inside])
    lat_t = np.interp(ts, truth.t_s, truth.lat_deg)
    lon_t = np.degrees(np.unwrap(np.radians(truth.lon_deg)))
    lon_t = np.interp(ts, truth.t_s, lon_t)
    r = rotation_ecef_to_enu(lat_t, lon_t)
    e = np.einsum("nij,nj->ni", r, x_r - x_t)
    return e, inside


def evaluate(truth: PoseRun, run: PoseRun) -> Evaluation:
    """Horizontal and 3-D position error statistics of RUN against TRUTH.

    Raises
    ------
    ValueError
        when no sample of RUN lies within TRUTH's time span.
    """
    e, inside = position_errors_enu_m(truth, run)
    if e.shape[0] == 0:
        raise ValueError(
            f"no sample of the run ({run.t_s[0]:.3f}..{run.t_s[-1]:.3f} s) lies within the truth's "
            f"time span ({truth.t_s[0]:.3f}..{truth.t_s[-1]:.3f} s)"
        )
    horiz = np.hypot(e[:, 0], e[:, 1])
    full = np.linalg.norm(e, axis=1)
    return Evaluation(
        horizontal=ErrorStats.of(horiz),
        three_d=ErrorStats.of(full),
        n_compared=int(e.shape[0]),
        n_outside=int((~inside).sum()),
    )
