"""WGS84 geodetic <-> ECEF <-> local East-North-Up, exact and vectorised.

Forward (geodetic -> ECEF), with prime vertical radius ``N = a / sqrt(1 - e² sin²φ)``::

    X = (N + h) cos φ cos λ,   Y = (N + h) cos φ sin λ,   Z = (N (1 - e²) + h) sin φ

Inverse (ECEF -> geodetic): the closed form of H. Vermeille, "Direct transformation from
geocentric coordinates to geodetic coordinates", J. Geodesy 76 (2002) 451-454, exact (no
iteration) everywhere outside a small region around the Earth's centre.

Local ENU anchored at an origin ``o`` (geodetic φ0, λ0, h0): ``p_enu = R(φ0, λ0) (X - X0)``
with rows of ``R`` the east, north and up unit vectors at the origin. Because it goes
through ECEF it stays exact for runs of any length (no flat-earth approximation); the
frame is simply the tangent frame at the origin.

The tangent plane is not level away from its origin: a point kept at plane height ``u``
while moved ``d`` across the plane rises by about ``d² / (2R)`` above the ellipsoid.
``en_height_to_geodetic`` therefore gives the point with plane east/north ``(e, n)`` at a
stated ellipsoidal height ``h*`` instead of a stated plane height: it slides the point along
the plane's up axis, ``u <- u + (h* - h(e, n, u))``. Along that axis ``dh/du = cos β`` with
``β ≈ d / R`` the angle between the plane's up and the local vertical, so each step leaves
``(1 - cos β) ≈ β²/2`` of the height error (7.8 m at 10 km becomes 10 µm, then 1e-11 m).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np

__all__ = [
    "WGS84_A_M",
    "WGS84_F",
    "WGS84_E2",
    "EnuOrigin",
    "as_origin",
    "geodetic_to_ecef",
    "ecef_to_geodetic",
    "rotation_ecef_to_enu",
    "ecef_to_enu",
    "enu_to_ecef",
    "geodetic_to_enu",
    "enu_to_geodetic",
    "en_height_to_geodetic",
    "rotation_local_enu_to_origin_enu",
    "quat_ecef_to_enu",
    "quat_local_enu_to_origin_enu",
]

WGS84_A_M = 6378137.0  # semi-major axis, metres
WGS84_F = 1.0 / 298.257223563  # flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared


@dataclass(frozen=True)
class EnuOrigin:
    """The anchor of a local ENU frame: geodetic latitude/longitude (deg) and height (m)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("lat_deg", "lon_deg", "alt_m"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise ValueError(f"origin {name} must be a finite number, got {v!r}")
            object.__setattr__(self, name, v)
        if abs(self.lat_deg) > 90.0:
            raise ValueError(f"origin latitude {self.lat_deg} is outside [-90, 90]")
        if abs(self.lon_deg) > 180.0:
            raise ValueError(f"origin longitude {self.lon_deg} is outside [-180, 180]")

    @property
    def ecef_m(self) -> np.ndarray:
        """Origin in ECEF, shape (3,), metres."""
        return geodetic_to_ecef(self.lat_deg, self.lon_deg, self.alt_m)

    @property
    def r_ecef_to_enu(self) -> np.ndarray:
        """Rotation matrix ECEF -> ENU at the origin, shape (3, 3)."""
        return rotation_ecef_to_enu(self.lat_deg, self.lon_deg)


OriginLike = Union[EnuOrigin, tuple, list, np.ndarray]


def as_origin(origin: OriginLike) -> EnuOrigin:
    """Accept an ``EnuOrigin`` or a ``(lat_deg, lon_deg[, alt_m])`` sequence."""
    if isinstance(origin, EnuOrigin):
        return origin
    vals = [float(v) for v in origin]
    if len(vals) == 2:
        vals.append(0.0)
    if len(vals) != 3:
        raise ValueError(f"origin needs lat, lon[, alt]; got {len(vals)} values")
    return EnuOrigin(*vals)


def geodetic_to_ecef(lat_deg, lon_deg, alt_m) -> np.ndarray:
    """WGS84 geodetic -> ECEF.

    Parameters
    ----------
    lat_deg, lon_deg : array_like, shape (n,) or scalar
        Geodetic latitude and longitude, degrees.
    alt_m : array_like, shape (n,) or scalar
        Height above the ellipsoid, metres.

    Returns
    -------
    ndarray, shape (n, 3) (or (3,) for scalars)
        ECEF X, Y, Z in metres.
    """
    return np.stack(np.broadcast_arrays(*_geodetic_to_ecef_columns(lat_deg, lon_deg, alt_m)), axis=-1)


def _geodetic_to_ecef_columns(lat_deg, lon_deg, alt_m):
    """ECEF x, y, z (each shaped like the inputs), metres; see ``geodetic_to_ecef``."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    h = np.asarray(alt_m, dtype=float)
    sin_lat, cos_lat = np.sin(lat), np.cos(lat)
    n_m = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat * sin_lat)
    r = (n_m + h) * cos_lat
    return r * np.cos(lon), r * np.sin(lon), (n_m * (1.0 - WGS84_E2) + h) * sin_lat


def ecef_to_geodetic(p_ecef_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF -> WGS84 geodetic (Vermeille 2002, closed form).

    Parameters
    ----------
    p_ecef_m : array_like, shape (n, 3) or (3,)

    Returns
    -------
    lat_deg, lon_deg, alt_m : ndarray, shape (n,) (or scalars' 0-d arrays)
    """
    p = np.asarray(p_ecef_m, dtype=float)
    return _ecef_columns_to_geodetic(p[..., 0], p[..., 1], p[..., 2])


def _ecef_columns_to_geodetic(x, y, z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``ecef_to_geodetic`` of ECEF columns x, y, z."""
    a2 = WGS84_A_M * WGS84_A_M
    e2 = WGS84_E2
    e4 = e2 * e2
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    pp = rho2 / a2
    qq = (1.0 - e2) / a2 * z * z
    r = (pp + qq - e4) / 6.0
    # Outside the evolute (|r| > 0 region near the surface) s >= 0; the expressions below
    # are the ones Vermeille gives for that case, which covers every point above ~43 km
    # from the Earth's centre.
    s = e4 * pp * qq / (4.0 * r * r * r)
    t = np.cbrt(1.0 + s + np.sqrt(s * (2.0 + s)))
    u = r * (1.0 + t + 1.0 / t)
    v = np.sqrt(u * u + e4 * qq)
    w = e2 * (u + v - qq) / (2.0 * v)
    k = np.sqrt(u + v + w * w) - w
    d = k * rho / (k + e2)
    dz = np.sqrt(d * d + z * z)
    lat = 2.0 * np.arctan2(z, d + dz)
    alt = (k + e2 - 1.0) / k * dz
    lon = np.arctan2(y, x)
    return np.degrees(lat), np.degrees(lon), alt


def rotation_ecef_to_enu(lat_deg, lon_deg) -> np.ndarray:
    """Rotation matrix from ECEF axes to the ENU axes at (lat, lon).

    Rows are the east, north and up unit vectors expressed in ECEF.

    Returns
    -------
    ndarray, shape (3, 3) for scalars or (n, 3, 3)
    """
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl * so)
    east = np.stack(np.broadcast_arrays(-so, co, zero), axis=-1)
    north = np.stack(np.broadcast_arrays(-sl * co, -sl * so, cl), axis=-1)
    up = np.stack(np.broadcast_arrays(cl * co, cl * so, sl), axis=-1)
    return np.stack([east, north, up], axis=-2)


def _rotate_columns(R: np.ndarray, a, b, c) -> np.ndarray:
    """``[a b c] @ R.T`` for columns a, b, c of shape (n,): (n, 3).

    Written out element by element: a (n,3) @ (3,3) product goes through BLAS, whose
    threads only wait on each other for so thin a matrix (ten times slower on a busy
    machine than these nine multiply-adds).
    """
    out = np.empty(np.shape(a) + (3,))
    for i in range(3):
        out[..., i] = R[i, 0] * a + R[i, 1] * b + R[i, 2] * c
    return out


def ecef_to_enu(p_ecef_m, origin: OriginLike) -> np.ndarray:
    """ECEF points -> ENU in the tangent frame at ``origin``; shape (n, 3), metres."""
    o = as_origin(origin)
    p = np.asarray(p_ecef_m, dtype=float)
    ox, oy, oz = o.ecef_m
    return _rotate_columns(o.r_ecef_to_enu, p[..., 0] - ox, p[..., 1] - oy, p[..., 2] - oz)


def enu_to_ecef(p_enu_m, origin: OriginLike) -> np.ndarray:
    """ENU points in the frame at ``origin`` -> ECEF; shape (n, 3), metres."""
    o = as_origin(origin)
    p = np.asarray(p_enu_m, dtype=float)
    out = _rotate_columns(o.r_ecef_to_enu.T, p[..., 0], p[..., 1], p[..., 2])
    out += o.ecef_m
    return out


def geodetic_to_enu(lat_deg, lon_deg, alt_m, origin: OriginLike) -> np.ndarray:
    """WGS84 geodetic -> local ENU at ``origin``.

    Parameters
    ----------
    lat_deg, lon_deg : array_like, shape (n,)
    alt_m : array_like, shape (n,)
    origin : EnuOrigin or (lat_deg, lon_deg, alt_m)

    Returns
    -------
    p_enu_m : ndarray, shape (n, 3)
        East, north, up in metres.
    """
    o = as_origin(origin)
    x, y, z = _geodetic_to_ecef_columns(lat_deg, lon_deg, alt_m)
    ox, oy, oz = o.ecef_m
    x, y, z = np.broadcast_arrays(x - ox, y - oy, z - oz)
    return _rotate_columns(o.r_ecef_to_enu, x, y, z)


def enu_to_geodetic(p_enu_m, origin: OriginLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local ENU at ``origin`` -> WGS84 geodetic; exact inverse of ``geodetic_to_enu``.

    Parameters
    ----------
    p_enu_m : array_like, shape (n, 3), metres

    Returns
    -------
    lat_deg, lon_deg, alt_m : ndarray, shape (n,)
    """
    o = as_origin(origin)
    p = np.asarray(p_enu_m, dtype=float)
    R = o.r_ecef_to_enu  # ECEF = R^T enu + origin, one column at a time
    e, n, u = p[..., 0], p[..., 1], p[..., 2]
    x, y, z = (R[0, i] * e + R[1, i] * n + R[2, i] * u + o.ecef_m[i] for i in range(3))
    return _ecef_columns_to_geodetic(x, y, z)


def en_height_to_geodetic(en_m, alt_m, origin: OriginLike, up_m=None, tol_m: float = 1e-6,
                          max_iter: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The geodetic point with ENU east/north ``en_m`` and ellipsoidal height ``alt_m``.

    Parameters
    ----------
    en_m : array_like, shape (n, 2), metres
        East and north in the plane anchored at ``origin``.
    alt_m : array_like, shape (n,)
        Wanted height above the ellipsoid, metres.
    up_m : array_like, shape (n,), optional
        A first guess of the plane's up (e.g. a solution's own up); by default the
        ellipsoid's drop below a sphere's tangent plane, ``alt - h0 - (e² + n²) / (2a)``.

    Returns
    -------
    lat_deg, lon_deg, alt_m : ndarray, shape (n,); the height returned is ``alt_m`` itself
    (the point's own height is within ``tol_m`` of it).
    """
    o = as_origin(origin)
    en = np.asarray(en_m, dtype=float).reshape(-1, 2)
    h = np.broadcast_to(np.asarray(alt_m, dtype=float), (len(en),))
    if up_m is None:
        u = h - o.alt_m - (en[:, 0] ** 2 + en[:, 1] ** 2) / (2.0 * WGS84_A_M)
    else:
        u = np.array(np.broadcast_to(np.asarray(up_m, dtype=float), (len(en),)))
    p = np.empty((len(en), 3))
    p[:, :2] = en
    for _ in range(max_iter):
        p[:, 2] = u
        lat, lon, h_now = enu_to_geodetic(p, o)
        miss = h - h_now
        if not np.max(np.abs(miss), initial=0.0, where=np.isfinite(miss)) > tol_m:
            break
        u = u + miss
    return lat, lon, np.array(h)


def rotation_local_enu_to_origin_enu(lat_deg, lon_deg, origin: OriginLike) -> np.ndarray:
    """Rotation from the ENU frame at each (lat, lon) to the ENU frame at ``origin``.

    A pose's orientation is given relative to ENU at its own position; to use it in the
    run's anchored frame, left-multiply by this matrix. Over 100 km the two frames differ
    by about 0.9 degrees, so it matters for long runs.

    Returns
    -------
    ndarray, shape (n, 3, 3)
    """
    o = as_origin(origin)
    r_local = rotation_ecef_to_enu(lat_deg, lon_deg)  # ECEF -> local ENU
    # origin_ENU <- ECEF <- local_ENU
    return o.r_ecef_to_enu @ np.swapaxes(r_local, -1, -2)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (…, 4) arrays (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_ecef_to_enu(lat_deg, lon_deg) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of ``rotation_ecef_to_enu``: shape (n, 4) or (4,).

    ``R_ECEF->ENU = Rx(-(π/2 - φ)) Rz(-(λ + π/2))`` (active rotations): turn the meridian
    of λ so east lies on x, then tip the pole down onto the local up axis.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    ax = -0.5 * (0.5 * np.pi - lat)
    az = -0.5 * (lon + 0.5 * np.pi)
    zero = np.zeros(np.broadcast(ax, az).shape)
    qx = np.stack(np.broadcast_arrays(np.cos(ax), np.sin(ax), zero, zero), axis=-1)
    qz = np.stack(np.broadcast_arrays(np.cos(az), zero, zero, np.sin(az)), axis=-1)
    return _quat_mul(qx, qz)


def quat_local_enu_to_origin_enu(lat_deg, lon_deg, origin: OriginLike) -> np.ndarray:
    """Quaternions (n, 4) of ``rotation_local_enu_to_origin_enu`` (cheaper than matrices)."""
    o = as_origin(origin)
    q_o = quat_ecef_to_enu(o.lat_deg, o.lon_deg)
    q_l = quat_ecef_to_enu(lat_deg, lon_deg)
    q_l_inv = q_l * np.array([1.0, -1.0, -1.0, -1.0])
    return _quat_mul(q_o, q_l_inv)


def horizontal_distance_m(lon1: np.ndarray, lat1: np.ndarray, lon2: np.ndarray, lat2: np.ndarray) -> np.ndarray:
    """Great-circle distance on the mean sphere (for display: corrections of metres)."""
    r = 6371008.8
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dphi = p2 - p1
    dlmb = np.radians(lon2 - lon1)
    a = np.sin(dphi / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dlmb / 2) ** 2
    return 2 * r * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))
