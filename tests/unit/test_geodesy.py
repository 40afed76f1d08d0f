"""Geodesy: WGS84 <-> ECEF <-> local ENU, checked against pyproj to the millimetre."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Transformer

from posefix.core.geodesy import (
    EnuOrigin,
    as_origin,
    ecef_to_enu,
    ecef_to_geodetic,
    enu_to_geodetic,
    geodetic_to_ecef,
    geodetic_to_enu,
    rotation_ecef_to_enu,
    rotation_local_enu_to_origin_enu,
)

MM = 1e-3


@pytest.fixture(scope="module")
def world_points():
    rng = np.random.default_rng(42)
    n = 20000
    lat = np.r_[rng.uniform(-90, 90, n), [90.0, -90.0, 0.0, 0.0, 89.999999]]
    lon = np.r_[rng.uniform(-180, 180, n), [0.0, 123.0, 180.0, -180.0, -45.0]]
    alt = np.r_[rng.uniform(-500, 12000, n), [0.0, 100.0, -50.0, 8848.0, 30.0]]
    return lat, lon, alt


def test_geodetic_to_ecef_matches_pyproj(world_points):
    lat, lon, alt = world_points
    tr = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = tr.transform(lon, lat, alt)
    assert np.abs(geodetic_to_ecef(lat, lon, alt) - np.column_stack([x, y, z])).max() < MM


def test_ecef_to_geodetic_matches_pyproj_and_inverts(world_points):
    lat, lon, alt = world_points
    p = geodetic_to_ecef(lat, lon, alt)
    tr = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon_p, lat_p, alt_p = tr.transform(p[:, 0], p[:, 1], p[:, 2])
    lat2, lon2, alt2 = ecef_to_geodetic(p)
    # 1e-9 degree is 0.1 mm on the ground
    assert np.abs(lat2 - lat_p).max() < 1e-9
    assert np.abs(alt2 - alt_p).max() < MM
    assert np.abs(lat2 - lat).max() < 1e-9
    assert np.abs(alt2 - alt).max() < MM
    away_from_pole = np.abs(lat) < 89.9999
    dlon = (lon2 - lon + 180.0) % 360.0 - 180.0
    assert np.abs(dlon[away_from_pole]).max() < 1e-9


def _pyproj_enu(lat, lon, alt, origin):
    pipe = (
        "+proj=pipeline +step +proj=cart +ellps=WGS84 "
        f"+step +proj=topocentric +ellps=WGS84 +lat_0={origin[0]!r} +lon_0={origin[1]!r} +h_0={origin[2]!r}"
    )
    tr = Transformer.from_pipeline(pipe)
    e, n, u = tr.transform(np.radians(lon), np.radians(lat), alt, radians=True)
    return np.column_stack([e, n, u])


@pytest.mark.parametrize("origin", [(60.17, 24.94, 20.0), (37.72, -122.47, 31.6), (-33.9, 151.2, 0.0), (0.0, 179.9, 5.0)])
def test_enu_matches_pyproj_topocentric_over_150_km(origin):
    rng = np.random.default_rng(1)
    # points up to ~150 km from the origin in every direction, heights up to 2 km
    lat = origin[0] + rng.uniform(-1.35, 1.35, 5000)
    lon = origin[1] + rng.uniform(-1.35, 1.35, 5000)
    lon = (lon + 180.0) % 360.0 - 180.0
    alt = rng.uniform(-100, 2000, 5000)
    ours = geodetic_to_enu(lat, lon, alt, origin)
    ref = _pyproj_enu(lat, lon, alt, origin)
    assert np.hypot(ours[:, 0], ours[:, 1]).max() > 100e3
    assert np.abs(ours - ref).max() < MM


def test_enu_round_trip_is_exact_for_long_runs():
    origin = EnuOrigin(45.0, 7.0, 300.0)
    rng = np.random.default_rng(2)
    p = np.column_stack([rng.uniform(-200e3, 200e3, 10000), rng.uniform(-200e3, 200e3, 10000), rng.uniform(-3e3, 3e3, 10000)])
    lat, lon, alt = enu_to_geodetic(p, origin)
    back = geodetic_to_enu(lat, lon, alt, origin)
    assert np.abs(back - p).max() < 1e-6


def test_origin_maps_to_zero_and_up_is_up():
    o = (10.0, 20.0, 100.0)
    assert np.allclose(geodetic_to_enu(np.array([10.0]), np.array([20.0]), np.array([100.0]), o), 0.0, atol=1e-9)
    up = geodetic_to_enu(np.array([10.0]), np.array([20.0]), np.array([105.0]), o)[0]
    assert np.allclose(up, [0, 0, 5.0], atol=1e-9)
    # one arc-second north is ~30.7 m north and nothing east
    north = geodetic_to_enu(np.array([10.0 + 1 / 3600]), np.array([20.0]), np.array([100.0]), o)[0]
    assert abs(north[0]) < 1e-6 and 30.0 < north[1] < 31.5


def test_rotation_matrices_are_orthonormal_and_consistent():
    rng = np.random.default_rng(3)
    lat, lon = rng.uniform(-89, 89, 100), rng.uniform(-180, 180, 100)
    r = rotation_ecef_to_enu(lat, lon)
    eye = np.einsum("nij,nkj->nik", r, r)
    assert np.allclose(eye, np.eye(3), atol=1e-14)
    assert np.allclose(np.linalg.det(r), 1.0)
    o = EnuOrigin(50.0, 8.0, 0.0)
    r_lo = rotation_local_enu_to_origin_enu(np.array([50.0, 51.0]), np.array([8.0, 9.5]), o)
    assert np.allclose(r_lo[0], np.eye(3), atol=1e-14)
    # a local "up" vector at the far point, mapped to the origin frame, equals the ECEF up
    # direction expressed in the origin frame
    up_far_ecef = rotation_ecef_to_enu(51.0, 9.5)[2]
    assert np.allclose(r_lo[1] @ [0, 0, 1.0], ecef_to_enu(up_far_ecef + o.ecef_m, o), atol=1e-12)
    # ~1.4 degrees apart: the frames differ by about that angle
    angle = np.degrees(np.arccos((np.trace(r_lo[1]) - 1) / 2))
    assert 1.0 < angle < 2.0


def test_as_origin_refuses_bad_values():
    assert as_origin((1.0, 2.0)) == EnuOrigin(1.0, 2.0, 0.0)
    with pytest.raises(ValueError, match="latitude"):
        as_origin((91.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        as_origin((float("nan"), 0.0, 0.0))
    with pytest.raises(ValueError, match="lat, lon"):
        as_origin((1.0,))


def test_quaternion_forms_equal_the_matrices():
    from posefix.core.geodesy import quat_ecef_to_enu, quat_local_enu_to_origin_enu
    from posefix.core.rotations import quat_to_matrix

    rng = np.random.default_rng(4)
    lat, lon = rng.uniform(-90, 90, 500), rng.uniform(-180, 180, 500)
    assert np.abs(quat_to_matrix(quat_ecef_to_enu(lat, lon)) - rotation_ecef_to_enu(lat, lon)).max() < 1e-14
    o = (47.0, -3.0, 10.0)
    assert np.abs(quat_to_matrix(quat_local_enu_to_origin_enu(lat, lon, o)) - rotation_local_enu_to_origin_enu(lat, lon, o)).max() < 1e-14


from hypothesis import given, settings
from hypothesis import strategies as st


@settings(max_examples=200, deadline=None)
@given(
    lat=st.floats(-90, 90), lon=st.floats(-180, 180), alt=st.floats(-1000, 20000),
    olat=st.floats(-89, 89), olon=st.floats(-180, 180), oalt=st.floats(-100, 3000),
)
def test_enu_round_trip_property(lat, lon, alt, olat, olon, oalt):
    o = (olat, olon, oalt)
    p = geodetic_to_enu(np.array([lat]), np.array([lon]), np.array([alt]), o)
    lat2, lon2, alt2 = enu_to_geodetic(p, o)
    # compare as ECEF points: longitude is undefined at the poles
    d = geodetic_to_ecef(lat2, lon2, alt2) - geodetic_to_ecef(lat, lon, alt)
    assert np.abs(d).max() < 1e-4  # 0.1 mm even across the globe (12,000 km from the origin)
