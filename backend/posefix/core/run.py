"""The pose run: the in-memory form of every trajectory posefix reads, corrects and writes.

A run is ``n`` samples in time order. Each sample has a geodetic position (WGS84 degrees,
metres above the ellipsoid) and an orientation: the unit quaternion (Hamilton, w first)
rotating vectors from the body frame (x forward, y left, z up) to the local East-North-Up
frame at that sample. Optional raw GNSS columns travel beside the (possibly fused) pose.

``PoseRun`` is frozen and its arrays are never modified in place; methods return new runs.
Validation lives in ``validate_run`` so readers can report the exact failing row.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

__all__ = ["PoseRun", "RunValidationError", "validate_run", "GNSS_FIELDS"]

GNSS_FIELDS = ("gnss_lat_deg", "gnss_lon_deg", "gnss_alt_m")


class RunValidationError(ValueError):
    """A run's arrays break an invariant.

    ``row`` is the 0-based sample index (or None when the whole run is at fault) and
    ``field`` the offending column; readers turn these into file/line/field errors.
    """

    def __init__(self, field: str, row: int | None, message: str):
        self.field = field
        self.row = row
        self.message = message
        where = f" at sample {row}" if row is not None else ""
        super().__init__(f"{field}{where}: {message}")


@dataclass(frozen=True, eq=False)
class PoseRun:
    """A trajectory of ``n`` timed poses.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
        Sample times in seconds, strictly increasing (any epoch).
    lat_deg, lon_deg : ndarray, shape (n,)
        WGS84 geodetic latitude and longitude in degrees.
    alt_m : ndarray, shape (n,)
        Height above the WGS84 ellipsoid in metres.
    q_body_to_enu_wxyz : ndarray, shape (n, 4)
        Unit quaternions (w, x, y, z) rotating body (x fwd, y left, z up) vectors into the
        local ENU frame at each sample.
    gnss_lat_deg, gnss_lon_deg, gnss_alt_m : ndarray, shape (n,), or None
        Raw GNSS fix beside the reported pose (all three or none). NaN marks a sample
        without a fix.
    images : list of str, or None
        Per sample image names, several separated by ``;``, ``""`` for none.
    extra : dict of str -> ndarray, shape (n,)
        Any other per-sample column, kept as read (numeric or string arrays).
    orientation_derived : bool
        True when the orientation was not in the input but derived from the track heading
        (roll and pitch zero).
    source : str
        Where the run came from (a path or a description), for messages.
    """

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    q_body_to_enu_wxyz: np.ndarray
    gnss_lat_deg: np.ndarray | None = None
    gnss_lon_deg: np.ndarray | None = None
    gnss_alt_m: np.ndarray | None = None
    images: list[str] | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    orientation_derived: bool = False
    source: str = ""

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t_s.shape[0])

    def __len__(self) -> int:
        return self.n

    @property
    def has_gnss(self) -> bool:
        """True when raw GNSS columns are present."""
        return self.gnss_lat_deg is not None

    def take(self, indices: Any) -> PoseRun:
        """Return the run restricted to ``indices`` (int array or boolean mask), in that order."""
        idx = np.asarray(indices)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        idx = idx.astype(np.intp, copy=False)

        def sub(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[idx]

        return replace(
            self,
            t_s=self.t_s[idx],
            lat_deg=self.lat_deg[idx],
            lon_deg=self.lon_deg[idx],
            alt_m=self.alt_m[idx],
            q_body_to_enu_wxyz=self.q_body_to_enu_wxyz[idx],
            gnss_lat_deg=sub(self.gnss_lat_deg),
            gnss_lon_deg=sub(self.gnss_lon_deg),
            gnss_alt_m=sub(self.gnss_alt_m),
            images=None if self.images is None else [self.images[i] for i in idx.tolist()],
            extra={k: v[idx] for k, v in self.extra.items()},
        )

    def with_poses(
        self,
        lat_deg: np.ndarray,
        lon_deg: np.ndarray,
        alt_m: np.ndarray,
        q_body_to_enu_wxyz: np.ndarray | None = None,
    ) -> PoseRun:
        """Return a copy with new positions (and orientations); every other column kept."""
        n = self.n
        lat = _as_float_1d(lat_deg, "lat_deg", n)
        lon = _as_float_1d(lon_deg, "lon_deg", n)
        alt = _as_float_1d(alt_m, "alt_m", n)
        q = self.q_body_to_enu_wxyz if q_body_to_enu_wxyz is None else np.asarray(q_body_to_enu_wxyz, float)
        if q.shape != (n, 4):
            raise RunValidationError("q_body_to_enu_wxyz", None, f"shape {q.shape}, expected ({n}, 4)")
        return replace(self, lat_deg=lat, lon_deg=lon, alt_m=alt, q_body_to_enu_wxyz=q)

    def validated(self) -> PoseRun:
        """Return ``self`` after ``validate_run``; raises ``RunValidationError``."""
        validate_run(self)
        return self


def _as_float_1d(a: Any, name: str, n: int) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.shape != (n,):
        raise RunValidationError(name, None, f"shape {arr.shape}, expected ({n},)")
    return arr


def _first_bad(mask: np.ndarray) -> int | None:
    bad = np.flatnonzero(mask)
    return int(bad[0]) if bad.size else None


def validate_run(run: PoseRun, quaternion_tolerance: float = 1e-3) -> np.ndarray:
    """Check the invariants of a run; raise ``RunValidationError`` naming the first bad row.
    Returns the quaternions' norms (n,), so a reader normalising them needs no second pass.

    Checks: non-empty; shapes agree; finite positions and times; latitude in [-90, 90],
    longitude in [-180, 180]; times strictly increasing; quaternions finite and of unit norm
    (within ``quaternion_tolerance``; a zero quaternion is always refused); GNSS columns all
    three or none, in range where finite; per-row images and extra columns of length n.
    """
    n = run.n
    if n == 0:
        raise RunValidationError("t", None, "the run is empty (no samples)")
    for name in ("t_s", "lat_deg", "lon_deg", "alt_m"):
        a = getattr(run, name)
        if a.shape != (n,):
            raise RunValidationError(name, None, f"shape {a.shape}, expected ({n},)")
        row = _first_bad(~np.isfinite(a))
        if row is not None:
            raise RunValidationError(name, row, f"value {float(a[row])!r} is not a finite number")
    row = _first_bad(np.abs(run.lat_deg) > 90.0)
    if row is not None:
        raise RunValidationError("lat_deg", row, f"latitude {float(run.lat_deg[row])} is outside [-90, 90]")
    row = _first_bad(np.abs(run.lon_deg) > 180.0)
    if row is not None:
        raise RunValidationError("lon_deg", row, f"longitude {float(run.lon_deg[row])} is outside [-180, 180]")
    row = _first_bad(np.diff(run.t_s) <= 0.0)
    if row is not None:
        raise RunValidationError(
            "t_s", row + 1,
            f"timestamps not strictly increasing: {float(run.t_s[row + 1])!r} follows {float(run.t_s[row])!r}",
        )
    q = run.q_body_to_enu_wxyz
    if q.shape != (n, 4):
        raise RunValidationError("q_body_to_enu_wxyz", None, f"shape {q.shape}, expected ({n}, 4)")
    row = _first_bad(~np.all(np.isfinite(q), axis=1))
    if row is not None:
        raise RunValidationError("q_body_to_enu_wxyz", row, f"quaternion {q[row].tolist()} is not finite")
    norm = np.linalg.norm(q, axis=1)
    row = _first_bad(norm < 1e-12)
    if row is not None:
        raise RunValidationError("q_body_to_enu_wxyz", row, "zero quaternion (no rotation defined)")
    row = _first_bad(np.abs(norm - 1.0) > quaternion_tolerance)
    if row is not None:
        raise RunValidationError("q_body_to_enu_wxyz", row, f"quaternion norm {norm[row]:.6g} is not 1")
    present = [getattr(run, f) is not None for f in GNSS_FIELDS]
    if any(present) and not all(present):
        raise RunValidationError("gnss", None, "gnss_lat, gnss_lon and gnss_alt must come together")
    if all(present):
        for name in GNSS_FIELDS:
            a = getattr(run, name)
            if a.shape != (n,):
                raise RunValidationError(name, None, f"shape {a.shape}, expected ({n},)")
            row = _first_bad(np.isinf(a))
            if row is not None:
                raise RunValidationError(name, row, f"value {float(a[row])!r} is not finite")
        row = _first_bad(np.abs(run.gnss_lat_deg) > 90.0)
        if row is not None:
            raise RunValidationError("gnss_lat_deg", row, f"latitude {float(run.gnss_lat_deg[row])} is outside [-90, 90]")
        row = _first_bad(np.abs(run.gnss_lon_deg) > 180.0)
        if row is not None:
            raise RunValidationError("gnss_lon_deg", row, f"longitude {float(run.gnss_lon_deg[row])} is outside [-180, 180]")
    if run.images is not None and len(run.images) != n:
        raise RunValidationError("images", None, f"{len(run.images)} entries, expected {n}")
    for name, a in run.extra.items():
        if len(a) != n:
            raise RunValidationError(name, None, f"{len(a)} entries, expected {n}")
    return norm
