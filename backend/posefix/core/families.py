"""Pose-error families the engine was not designed on, built on a true motion and its GNSS fixes.

``simulate`` draws a reported pose whose error is one of its regimes.  The families here
build the reported pose the way real units do, from a true trajectory (simulated, or a
real reference such as the Nagoya drive) and GNSS fixes (simulated, or real):

* ``ekf``: dead reckoning from odometry and yaw rate, fused with gated single-point GNSS
  in an extended Kalman filter.  State x = [e, n, psi] (psi: yaw, ENU, from east);
  prediction with the measured speed v~ = (1 + s) v + w_v and yaw rate
  omega~ = omega + b_g + w_omega over dt:

      e' = e + v~ dt cos psi,  n' = n + v~ dt sin psi,  psi' = psi + omega~ dt
      P' = F P F^T + G diag(sigma_v^2, sigma_omega^2) G^T dt

  with F, G the Jacobians in the state and the inputs; a fix z = [e, n] + r (sigma_g per
  axis) updates the state when its innovation passes the gate ``nu^T S^-1 nu < GATE``
  (S = H P H^T + R), or after ``REGATE_S`` seconds without an accepted fix (a filter that
  gated out a canyon jump re-acquires).  ``smoothed``: the filter run forwards and
  backwards in time and the two estimates combined by their inverse covariances (two-filter
  smoother), as post-processing does.
* ``ins_lowpass``: a GNSS/INS pose whose error is a low-passed copy of the fix's bias,
  ``e_pose = a * lowpass(b, tau_p)`` (it followed the biased fix).
* ``scale_heading``: dead reckoning alone with a speed scale error and a heading bias.
* ``time_offset``: the pose stamped ``dt_off`` seconds late against the GNSS and the truth.
* an ``outage`` of the fixes (NaN) and a run with ``no GNSS`` are options of the builders.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from posefix.core.geodesy import enu_to_geodetic, geodetic_to_enu
from posefix.core.rotations import quat_multiply

FAMILIES = ("ekf", "ekf_smoothed", "ins_lowpass", "scale_heading", "time_offset", "outage", "no_gnss")
GATE = 9.21  # 99 % point of chi-square(2)
REGATE_S = 30.0  # accept the next fix whatever its innovation after this long without one


def wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def odometry(rng: np.random.Generator, speed_mps: np.ndarray, yaw_rad: np.ndarray, dt_s: np.ndarray,
             scale: float, gyro_bias_rps: float, sigma_v_mps: float = 0.05,
             sigma_w_rps: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """Measured speed (n,) and yaw rate (n-1,) from the true speed and yaw: scale error, gyro bias, noise."""
    v = speed_mps * (1.0 + scale) + rng.standard_normal(len(speed_mps)) * sigma_v_mps
    w = np.diff(np.unwrap(yaw_rad)) / np.maximum(dt_s, 1e-9) + gyro_bias_rps
    w = w + rng.standard_normal(len(w)) * sigma_w_rps
    return v, w


def _ekf_pass(p0: np.ndarray, psi0: float, v: np.ndarray, w: np.ndarray, dt: np.ndarray, fix: np.ndarray,
              is_fix: np.ndarray, sigma_g: float, q_v: float, q_w: float, sign: float):
    """One filter pass in the order given; returns positions (n,2), yaw (n,), covariances (n,3,3)."""
    n = len(v)
    x = np.array([p0[0], p0[1], psi0], dtype=float)
    P = np.diag([25.0, 25.0, 0.01])
    R = np.eye(2) * sigma_g**2
    out_p, out_psi, out_P = np.zeros((n, 2)), np.zeros(n), np.zeros((n, 3, 3))
    since = 0.0
    for i in range(n):
        if i:
            h = dt[i - 1]
            vi, psi = sign * v[i - 1], x[2]
            c, s = np.cos(psi), np.sin(psi)
            x = x + np.array([vi * h * c, vi * h * s, sign * w[i - 1] * h])
            F = np.array([[1.0, 0.0, -vi * h * s], [0.0, 1.0, vi * h * c], [0.0, 0.0, 1.0]])
            G = np.array([[h * c, 0.0], [h * s, 0.0], [0.0, h]])
            P = F @ P @ F.T + G @ np.diag([q_v, q_w]) @ G.T
            since += h
        if is_fix[i]:
            nu = fix[i] - x[:2]
            S = P[:2, :2] + R
            if float(nu @ np.linalg.solve(S, nu)) < GATE or since > REGATE_S:
                K = P[:, :2] @ np.linalg.inv(S)
                x = x + K @ nu
                P = (np.eye(3) - K[:, :2] @ np.eye(2, 3)) @ P
                since = 0.0
        out_p[i], out_psi[i], out_P[i] = x[:2], x[2], P
    return out_p, out_psi, out_P


def ekf_pose(t_s: np.ndarray, p_true_en: np.ndarray, yaw_true: np.ndarray, speed: np.ndarray,
             fix_en: np.ndarray, rng: np.random.Generator, *, scale: float = 0.01, gyro_bias_rps: float = 0.001,
             sigma_g_m: float = 5.0, smoothed: bool = False, fuse: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Reported horizontal positions (n,2) and yaw (n,) of an odometry + yaw-rate EKF fused with
    the fixes ``fix_en`` (n,2, NaN where none; a fix is used where it changes); ``fuse`` False
    dead-reckons only; ``smoothed`` combines a forward and a backward pass."""
    dt = np.diff(t_s)
    v, w = odometry(rng, speed, yaw_true, dt, scale, gyro_bias_rps)
    ok = np.all(np.isfinite(fix_en), axis=1)
    new = ok & np.r_[True, np.any(np.diff(np.where(ok[:, None], fix_en, 0.0), axis=0) != 0, axis=1)]
    is_fix = new if fuse else np.zeros(len(t_s), dtype=bool)
    q_v, q_w = 0.05**2, 0.002**2
    p0 = p_true_en[0] + rng.standard_normal(2) * 1.0
    pf, yf, Pf = _ekf_pass(p0, yaw_true[0], v, w, dt, fix_en, is_fix, sigma_g_m, q_v, q_w, 1.0)
    if not smoothed:
        return pf, yf
    # backward pass: start where the forward filter ended, integrate the same inputs back in time
    pb, yb, Pb = _ekf_pass(pf[-1], yf[-1], v[::-1], w[::-1], dt[::-1], fix_en[::-1], is_fix[::-1], sigma_g_m,
                           q_v, q_w, -1.0)
    pb, yb, Pb = pb[::-1], yb[::-1], Pb[::-1]
    Wf, Wb = np.linalg.inv(Pf[:, :2, :2]), np.linalg.inv(Pb[:, :2, :2])
    p = np.linalg.solve(Wf + Wb, (np.einsum("nij,nj->ni", Wf, pf) + np.einsum("nij,nj->ni", Wb, pb))[..., None])[..., 0]
    af, ab = 1.0 / Pf[:, 2, 2], 1.0 / Pb[:, 2, 2]
    yaw = yf + wrap(yb - yf) * ab / (af + ab)
    return p, yaw


def lowpass(x: np.ndarray, dt_s: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order low-pass of x (n,d) over irregular steps dt (n-1,)."""
    y = np.empty_like(x)
    y[0] = x[0]
    a = np.exp(-np.asarray(dt_s) / tau_s)
    for i in range(1, len(x)):
        y[i] = a[i - 1] * y[i - 1] + (1.0 - a[i - 1]) * x[i]
    return y


def gauss_markov(rng: np.random.Generator, t_s: np.ndarray, sigma: float, tau_s: float, dims: int = 2) -> np.ndarray:
    """A stationary Gauss-Markov process (n,dims) at times t_s."""
    out = np.empty((len(t_s), dims))
    out[0] = rng.standard_normal(dims) * sigma
    a = np.exp(-np.diff(t_s) / tau_s)
    z = rng.standard_normal((len(t_s) - 1, dims))
    for i in range(1, len(t_s)):
        out[i] = a[i - 1] * out[i - 1] + np.sqrt(1.0 - a[i - 1] ** 2) * sigma * z[i - 1]
    return out


def _yaw_quat(dyaw: np.ndarray) -> np.ndarray:
    return np.column_stack([np.cos(dyaw / 2), np.zeros_like(dyaw), np.zeros_like(dyaw), np.sin(dyaw / 2)])


def reported_run(truth, run, p_rep_en: np.ndarray, dyaw: np.ndarray, origin, gnss_en: np.ndarray | None, source: str):
    """A PoseRun on ``truth``'s times: horizontal positions ``p_rep_en`` (n,2), the truth's altitude,
    orientation rotated by the yaw error ``dyaw`` (n,), raw GNSS ``gnss_en`` (n,3; NaN rows: no fix; None: no columns)."""
    p_t = geodetic_to_enu(truth.lat_deg, truth.lon_deg, truth.alt_m, origin)
    p = np.column_stack([p_rep_en, p_t[:, 2]])
    lat, lon, alt = enu_to_geodetic(p, origin)
    q = quat_multiply(_yaw_quat(dyaw), truth.q_body_to_enu_wxyz)
    gnss = {}
    if gnss_en is not None:
        g_lat, g_lon, g_alt = enu_to_geodetic(gnss_en, origin)
        bad = ~np.all(np.isfinite(gnss_en), axis=1)
        gnss = {"gnss_lat_deg": np.where(bad, np.nan, g_lat), "gnss_lon_deg": np.where(bad, np.nan, g_lon),
                "gnss_alt_m": np.where(bad, np.nan, g_alt)}
    return dataclasses.replace(run, lat_deg=lat, lon_deg=lon, alt_m=alt, q_body_to_enu_wxyz=q, source=source,
                               gnss_lat_deg=gnss.get("gnss_lat_deg"), gnss_lon_deg=gnss.get("gnss_lon_deg"),
                               gnss_alt_m=gnss.get("gnss_alt_m"))


def simulate_family(family: str, duration_s: float = 1800.0, rate_hz: float = 10.0, edit_every_s: float = 100.0,
                    seed: int = 1, gnss_rate_hz: float = 1.0, click_noise_m: float = 0.5):
    """A ``simulate`` drive whose reported pose (and GNSS) follow ``family`` (module docstring)."""
    from posefix.core.simulate import simulate

    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r} (known: {', '.join(FAMILIES)})")
    base = "white" if family in ("ins_lowpass", "time_offset", "scale_heading") else "mixed"
    sim = simulate(duration_s=duration_s, rate_hz=rate_hz, edit_every_s=edit_every_s, seed=seed, regime=base,
                   gnss_rate_hz=gnss_rate_hz, click_noise_m=click_noise_m)
    rng = np.random.default_rng(10_000 + seed)
    o = sim.origin
    t = sim.truth.t_s - sim.truth.t_s[0]
    p_t = geodetic_to_enu(sim.truth.lat_deg, sim.truth.lon_deg, sim.truth.alt_m, o)
    g = geodetic_to_enu(sim.run.gnss_lat_deg, sim.run.gnss_lon_deg, sim.run.gnss_alt_m, o)
    dt = np.diff(t)
    yaw = _truth_yaw(p_t, sim.truth.extra.get("speed_mps"))
    speed = sim.truth.extra["speed_mps"]
    dyaw = np.zeros(len(t))
    if family == "ins_lowpass":
        bias = gauss_markov(rng, t, 4.0, 180.0)
        g[:, :2] = p_t[:, :2] + bias + rng.standard_normal((len(t), 2)) * 1.5
        p_rep = p_t[:, :2] + 0.9 * lowpass(bias, dt, 40.0) + gauss_markov(rng, t, 0.3, 300.0)
    elif family == "time_offset":
        off = 0.5 + 0.5 * rng.random()
        p_rep = np.column_stack([np.interp(t - off, t, p_t[:, j]) for j in range(2)]) + gauss_markov(rng, t, 1.0, 300.0)
    elif family == "scale_heading":
        p_rep, yaw_r = ekf_pose(sim.truth.t_s, p_t[:, :2], yaw, speed, g[:, :2], rng, scale=0.02 * rng.choice([-1, 1]),
                                gyro_bias_rps=0.0, fuse=False)
        # a heading bias of about a degree turns the dead-reckoned track about its start
        b = np.radians(1.0) * rng.choice([-1, 1])
        c, s_ = np.cos(b), np.sin(b)
        d = p_rep - p_rep[0]
        p_rep = p_rep[0] + np.column_stack([c * d[:, 0] - s_ * d[:, 1], s_ * d[:, 0] + c * d[:, 1]])
        dyaw = wrap(yaw_r + b - yaw)
    else:
        if family == "outage":
            a = int(len(t) * 0.4)
            g[a:a + int(180.0 * rate_hz)] = np.nan
        p_rep, yaw_r = ekf_pose(sim.truth.t_s, p_t[:, :2], yaw, speed, g[:, :2], rng,
                                scale=0.01 * rng.uniform(-1, 1), gyro_bias_rps=np.radians(0.05) * rng.uniform(-1, 1),
                                smoothed=family == "ekf_smoothed")
        dyaw = wrap(yaw_r - yaw)
    run = reported_run(sim.truth, sim.run, p_rep, dyaw, o, None if family == "no_gnss" else g, f"family {family}, seed {seed}")
    info = dict(sim.info, pose_error_rms_m=_h_rms(p_rep[:, :2] - p_t[:, :2]),
                gnss_error_rms_m=float("nan") if family == "no_gnss" else _h_rms(g[:, :2] - p_t[:, :2]))
    return dataclasses.replace(sim, run=run, regime=family, info=info)


def _h_rms(d_m: np.ndarray) -> float:
    """Horizontal RMS of (n,2) differences over the finite rows."""
    ok = np.all(np.isfinite(d_m), axis=1)
    return float(np.sqrt(np.mean(np.sum(d_m[ok] ** 2, axis=1)))) if ok.any() else float("nan")


def _truth_yaw(p_en: np.ndarray, speed) -> np.ndarray:
    """Yaw (ENU, from east) of the direction of travel."""
    d = np.gradient(p_en[:, :2], axis=0)
    return np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
