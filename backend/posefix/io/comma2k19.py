"""The comma2k19 segment layout (commaai/comma2k19, MIT).

A segment folder holds numpy arrays saved without extension. posefix reads:

- the pose from ``global_pose/``: ``frame_times`` (boot time, s), ``frame_positions`` (ECEF,
  m) and ``frame_orientations``: Hamilton quaternions (w first) whose rotation maps the
  camera/device frame [forward, right, down] into ECEF (checked on the data: the device's
  forward axis follows ``frame_velocities``, its third axis points down). The body frame
  posefix uses is [forward, left, up] = diag(1, -1, -1) device, so
  ``R_body->ENU = R_ECEF->ENU(lat, lon) · R_device->ECEF · diag(1, -1, -1)``.
  This 20 Hz fused INS/GNSS/vision pose is comma's own estimate, not RTK truth. The "body"
  is therefore the camera, not the car: its pitch includes the mount's (~4° down here).
- the raw u-blox fix ``processed_log/GNSS/live_gnss_ublox`` (10 Hz: lat, lon, speed, UTC ms,
  altitude, bearing) as the ``gnss_*`` columns, linearly interpolated in time at the pose
  times (held at the first/last fix outside its span; NaN where the gap to the nearest fix
  exceeds ``MAX_GNSS_GAP_S``). The u-blox altitude is taken as ellipsoidal height (it agrees
  with the pose's ellipsoidal height to ~2 m here, where the geoid is ~32 m below).
- extra columns: ``speed_mps`` (norm of ``frame_velocities``), ``gps_week``, ``gps_tow_s``.

The ~100 Hz IMU logs are not read: the fused pose already integrates them, and the
corrected run is defined at the pose samples.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from posefix.core.geodesy import ecef_to_geodetic, rotation_ecef_to_enu
from posefix.core.run import PoseRun
from posefix.io._build import build_run
from posefix.io._quat import matrix_to_quat, quat_to_matrix
from posefix.io.errors import RunFormatError

__all__ = ["read_comma2k19", "find_comma2k19_segment"]

MAX_GNSS_GAP_S = 1.0  # beyond this from any fix, the sample has no GNSS reading
_DEVICE_TO_BODY = np.diag([1.0, -1.0, -1.0])


def find_comma2k19_segment(path: Path) -> Path | None:
    """The segment folder (holding ``global_pose/``) for ``path`` or its ``segment`` child."""
    for cand in (path, path / "segment"):
        if (cand / "global_pose" / "frame_times").is_file():
            return cand
    return None


def _load(path: Path, shape_tail: tuple[int, ...]) -> np.ndarray:
    try:
        with open(path, "rb") as fh:
            arr = np.load(fh, allow_pickle=False)
    except FileNotFoundError:
        raise RunFormatError(path, None, None, "missing array file") from None
    except (OSError, ValueError) as exc:
        raise RunFormatError(path, None, None, f"not a numpy array file: {exc}") from None
    if arr.ndim != 1 + len(shape_tail) or tuple(arr.shape[1:]) != shape_tail:
        raise RunFormatError(path, None, None, f"array shape {arr.shape}, expected (n, {', '.join(map(str, shape_tail))})".replace(", )", ")"))
    return arr.astype(float, copy=False)


def read_comma2k19(path: str | os.PathLike) -> PoseRun:
    """Read a comma2k19 segment folder into a ``PoseRun`` (see module doc for the choices)."""
    path = Path(path)
    seg = find_comma2k19_segment(path)
    if seg is None:
        raise RunFormatError(path, None, None, "not a comma2k19 segment (needs global_pose/frame_times)")
    gp = seg / "global_pose"
    t_s = _load(gp / "frame_times", ())
    p_ecef = _load(gp / "frame_positions", (3,))
    q_dev_to_ecef = _load(gp / "frame_orientations", (4,))
    n = t_s.shape[0]
    for f, a in (("frame_positions", p_ecef), ("frame_orientations", q_dev_to_ecef)):
        if a.shape[0] != n:
            raise RunFormatError(gp / f, None, None, f"{a.shape[0]} rows but frame_times has {n}")
    bad = np.flatnonzero(~np.isfinite(p_ecef).all(axis=1))
    if bad.size:
        raise RunFormatError(gp / "frame_positions", None, f"row {bad[0]}", "position is not finite")
    bad = np.flatnonzero(~(np.linalg.norm(q_dev_to_ecef, axis=1) > 1e-12))
    if bad.size:
        raise RunFormatError(gp / "frame_orientations", None, f"row {bad[0]}", "zero or non-finite quaternion")
    lat, lon, alt = ecef_to_geodetic(p_ecef)
    r_body_to_enu = rotation_ecef_to_enu(lat, lon) @ quat_to_matrix(q_dev_to_ecef) @ _DEVICE_TO_BODY
    q = matrix_to_quat(r_body_to_enu)
    extra: dict[str, np.ndarray] = {}
    vel = gp / "frame_velocities"
    if vel.is_file():
        v = _load(vel, (3,))
        if v.shape[0] == n:
            extra["speed_mps"] = np.linalg.norm(v, axis=1)
    gps_times = gp / "frame_gps_times"
    if gps_times.is_file():
        g = _load(gps_times, (2,))
        if g.shape[0] == n:
            extra["gps_week"] = g[:, 0]
            extra["gps_tow_s"] = g[:, 1]
    gnss = _read_ublox(seg, t_s)
    return build_run(
        gp, t_s, lat, lon, alt, q, line_of_row=lambda i: None, gnss=gnss, extra=extra,
        field_names={"t_s": "frame_times", "lat_deg": "frame_positions", "lon_deg": "frame_positions",
                     "alt_m": "frame_positions", "q_body_to_enu_wxyz": "frame_orientations"},
    )


def _read_ublox(seg: Path, t_s: np.ndarray):
    folder = seg / "processed_log" / "GNSS" / "live_gnss_ublox"
    if not (folder / "t").is_file():
        return None
    t_g = _load(folder / "t", ())
    val = _load(folder / "value", (6,))
    if val.shape[0] != t_g.shape[0]:
        raise RunFormatError(folder / "value", None, None, f"{val.shape[0]} rows but t has {t_g.shape[0]}")
    ok = np.isfinite(t_g) & np.isfinite(val[:, [0, 1, 4]]).all(axis=1) & (np.abs(val[:, 0]) <= 90) & (np.abs(val[:, 1]) <= 180)
    t_g, val = t_g[ok], val[ok]
    order = np.argsort(t_g, kind="stable")
    t_g, val = t_g[order], val[order]
    if t_g.size == 0:
        return None
    out = [np.interp(t_s, t_g, val[:, k]) for k in (0, 1, 4)]
    # distance in time to the nearest fix
    j = np.clip(np.searchsorted(t_g, t_s), 1, max(t_g.size - 1, 1))
    gap = np.minimum(np.abs(t_s - t_g[j - 1]), np.abs(t_g[np.minimum(j, t_g.size - 1)] - t_s))
    far = gap > MAX_GNSS_GAP_S
    for a in out:
        a[far] = np.nan
    return tuple(out)
