"""Error of a track against a walk's surveyed waypoints.

The competition's convention: waypoints are the truth at their timestamps, and the walker
moves in a straight line at constant speed between consecutive waypoints. We report

* ``err_wp_m``: at each waypoint, the distance between the waypoint and the track
  linearly interpolated at the waypoint's time (the headline figure);
* ``err_steps_m``: at each track row between the first and last waypoint, the distance
  to the straight-line truth interpolated at that row's time.

The first waypoint can be excluded (``skip_first``) when it was given to the tracker as
the known start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["WalkError", "interpolate_xy", "evaluate_track", "summarise", "mahalanobis2_at_waypoints",
           "CHI2_2_COVER_2SIGMA"]

# A calibrated 2-D Gaussian puts 1 - e⁻² = 86.5 % of its draws inside its 2σ ellipse.
CHI2_2_COVER_2SIGMA = 1.0 - float(np.exp(-2.0))


@dataclass(frozen=True)
class WalkError:
    err_wp_m: np.ndarray
    err_steps_m: np.ndarray


def interpolate_xy(t_query_ms: np.ndarray, t_ms: np.ndarray, p_xy_m: np.ndarray) -> np.ndarray:
    """Piecewise-linear positions (n, 2) at ``t_query_ms`` from a track (t_ms (m,), p (m, 2));
    held constant before the first and after the last row."""
    t = np.asarray(t_ms, dtype=float)
    return np.column_stack([np.interp(t_query_ms, t, p_xy_m[:, 0]), np.interp(t_query_ms, t, p_xy_m[:, 1])])


def evaluate_track(waypoints: np.ndarray, t_ms: np.ndarray, p_xy_m: np.ndarray, skip_first: bool = False) -> WalkError:
    """``waypoints`` (w, 3) = t_ms, x_m, y_m; track ``t_ms`` (m,), ``p_xy_m`` (m, 2)."""
    wp = np.asarray(waypoints, dtype=float)
    if wp.shape[0] == 0:
        raise ValueError("the walk has no TYPE_WAYPOINT lines to evaluate against")
    at_wp = interpolate_xy(wp[:, 0], t_ms, p_xy_m)
    e_wp = np.linalg.norm(at_wp - wp[:, 1:3], axis=1)
    if skip_first:
        e_wp = e_wp[1:]
    sel = (t_ms >= wp[0, 0]) & (t_ms <= wp[-1, 0])
    truth = interpolate_xy(np.asarray(t_ms, dtype=float)[sel], wp[:, 0], wp[:, 1:3])
    e_steps = np.linalg.norm(np.asarray(p_xy_m)[sel] - truth, axis=1)
    return WalkError(err_wp_m=e_wp, err_steps_m=e_steps)


def summarise(errors: list[np.ndarray]) -> dict[str, float]:
    """Mean, median and 95th percentile (m) of the pooled errors."""
    e = np.concatenate([np.asarray(x, dtype=float) for x in errors]) if errors else np.zeros(0)
    if e.size == 0:
        return {"n": 0, "mean_m": float("nan"), "median_m": float("nan"), "p95_m": float("nan")}
    return {"n": int(e.size), "mean_m": float(e.mean()), "median_m": float(np.median(e)),
            "p95_m": float(np.percentile(e, 95))}


def mahalanobis2_at_waypoints(waypoints: np.ndarray, res, skip_first: bool = False) -> np.ndarray:
    """Squared Mahalanobis distance (w,) of each waypoint's error under the reported ellipse:
    the track ``res`` (a TrackResult: ``t_ms``, ``p_xy_m``, ``sigma_major_m``, ``sigma_minor_m``,
    ``angle_deg``) interpolated at the waypoint's time (as the error is measured) against the
    covariance of the row nearest in time, rebuilt from its 1σ semi-axes and angle. A
    calibrated 2-D Gaussian gives a χ²₂: median 1.39, 86.5 % within 4 (the 2σ ellipse)."""
    wp = np.asarray(waypoints, dtype=float)
    t = np.asarray(res.t_ms, dtype=float)
    err = interpolate_xy(wp[:, 0], t, res.p_xy_m) - wp[:, 1:3]
    i = np.clip(np.searchsorted(t, wp[:, 0]), 1, t.size - 1)
    i = np.where(np.abs(t[i - 1] - wp[:, 0]) <= np.abs(t[i] - wp[:, 0]), i - 1, i) if t.size > 1 else np.zeros_like(i)
    a = np.radians(res.angle_deg[i])
    u = np.stack([np.cos(a), np.sin(a)], axis=1)  # major axis
    v = np.stack([-np.sin(a), np.cos(a)], axis=1)
    m2 = (np.sum(err * u, axis=1) / res.sigma_major_m[i]) ** 2 + (np.sum(err * v, axis=1) / res.sigma_minor_m[i]) ** 2
    return m2[1:] if skip_first else m2
