"""Road-network matching on the shipped Helsinki extract: a simulated drive along its
streets, the reported positions offset as a GNSS bias would, matched back onto the roads."""

from __future__ import annotations

import numpy as np
import pytest

from posefix.core.simulate import simulate
from posefix.mapmatch.osm import local_georef
from posefix.roads import match_on_roads

from .io_helpers import osm_extract


@pytest.fixture(scope="module")
def drive():
    sim = simulate(duration_s=180.0, rate_hz=1.0, osm_path=str(osm_extract()), seed=5, edit_every_s=0, regime="white")
    return sim.truth


def _error_m(lonlat: np.ndarray, truth) -> np.ndarray:
    geo = local_georef(float(truth.lon_deg[0]), float(truth.lat_deg[0]))
    return np.linalg.norm(geo.to_xy(lonlat) - geo.to_xy(np.column_stack([truth.lon_deg, truth.lat_deg])), axis=1)


def _offset(truth, east_m: float, north_m: float) -> tuple[np.ndarray, np.ndarray]:
    geo = local_georef(float(truth.lon_deg[0]), float(truth.lat_deg[0]))
    p = geo.to_xy(np.column_stack([truth.lon_deg, truth.lat_deg])) + [east_m, north_m]
    ll = geo.to_lonlat(p)
    return ll[:, 0], ll[:, 1]


def test_a_biased_drive_is_matched_back_onto_its_streets(drive) -> None:
    lon, lat = _offset(drive, 4.0, -3.0)
    sug = match_on_roads(lon, lat, drive.q_body_to_enu_wxyz, osm_extract())
    before = _error_m(np.column_stack([lon, lat]), drive)
    after = _error_m(sug.lonlat_deg, drive)
    assert np.median(after) < 0.3 * np.median(before), (np.median(before), np.median(after))
    assert np.allclose(sug.moved_m, _error_m(sug.lonlat_deg, _shifted(drive, lon, lat)), atol=0.02)
    assert np.all(np.isfinite(sug.sigma_m)) and np.all(sug.sigma_m > 0)
    assert sug.n_vertices > 1000  # road segments of the box


def _shifted(drive, lon, lat):
    import dataclasses

    return dataclasses.replace(drive, lon_deg=lon, lat_deg=lat)


def _far_from_roads(drive, min_m: float = 25.0) -> tuple[float, float]:
    """A point near the drive at least ``min_m`` from every drivable way (shapely, not our index)."""
    from shapely.geometry import LineString, Point

    from posefix.mapmatch.osm import read_osm_ways

    geo = local_georef(float(drive.lon_deg.min()) - 0.003, float(drive.lat_deg.min()) - 0.002)
    box = (geo.lon0_deg, geo.lat0_deg, float(drive.lon_deg.max()) + 0.003, float(drive.lat_deg.max()) + 0.002)
    lines = [LineString(geo.to_xy(w.lonlat_deg)) for w in read_osm_ways(osm_extract(), box, profile="drive")]
    hi = geo.to_xy(np.array([[box[2], box[3]]]))[0]
    for x in np.arange(0.0, hi[0], 10.0):
        for y in np.arange(0.0, hi[1], 10.0):
            if min(line.distance(Point(x, y)) for line in lines) > min_m:
                lon, lat = geo.to_lonlat(np.array([[x, y]]))[0]
                return float(lon), float(lat)
    raise AssertionError("no point far from the roads in the box")


def test_off_road_flags_the_reported_position_outside_every_carriageway(drive) -> None:
    on_centreline = match_on_roads(drive.lon_deg, drive.lat_deg, drive.q_body_to_enu_wxyz, osm_extract()).off_road
    assert on_centreline.mean() < 0.05  # the simulated truth drives along the ways' centrelines
    lon, lat = drive.lon_deg.copy(), drive.lat_deg.copy()
    i = len(lon) // 2
    lon[i], lat[i] = _far_from_roads(drive)
    flagged = match_on_roads(lon, lat, drive.q_body_to_enu_wxyz, osm_extract()).off_road
    assert flagged[i]
    assert np.array_equal(np.delete(flagged, i), np.delete(on_centreline, i))


def test_bad_inputs_name_the_file(tmp_path, drive) -> None:
    q = drive.q_body_to_enu_wxyz
    with pytest.raises(ValueError, match="missing.osm.pbf"):
        match_on_roads(drive.lon_deg, drive.lat_deg, q, tmp_path / "missing.osm.pbf")
    with pytest.raises(ValueError, match=r"helsinki\.osm\.pbf.*no drive ways"):
        match_on_roads(drive.lon_deg + 1.0, drive.lat_deg, q, osm_extract())
    with pytest.raises(ValueError, match="two keyframes"):
        match_on_roads(drive.lon_deg[:1], drive.lat_deg[:1], q[:1], osm_extract())
