"""OSM drivable-area rasters and map-matching suggestions for a simulated drive on real streets."""

import os
from pathlib import Path

import numpy as np
import pytest

from posefix.mapmatch.osm import OsmWay, local_georef, raster_from_ways, read_osm_ways
from posefix.mapmatch.suggest import heading_from_quaternion_wxyz, suggest_for_run

REPO = Path(__file__).resolve().parents[2]
PBF = Path(os.environ.get("POSEFIX_SHARED_DATA", REPO.parent / "shared" / "data")) / "osm" / "helsinki.osm.pbf"
BBOX = (24.935, 60.164, 24.953, 60.179)


def test_raster_buffers_ways_by_width():
    geo = local_georef(24.0, 60.0)
    line = geo.to_lonlat(np.array([[10.0, 50.0], [90.0, 50.0]]))
    ne = geo.to_lonlat(np.array([[100.0, 100.0]]))[0]
    r = raster_from_ways([OsmWay(1, "primary", 10.0, line)], (24.0, 60.0, float(ne[0]), float(ne[1])), res_m=0.5)
    assert r.is_walkable(np.array([[50.0, 54.5]]))[0] and not r.is_walkable(np.array([[50.0, 55.6]]))[0]
    assert not r.is_walkable(np.array([[3.5, 50.0]]))[0]  # round cap: 5 m past the end only


def test_heading_from_quaternion():
    th = np.array([0.3, -2.0])
    q = np.column_stack([np.cos(th / 2), 0 * th, 0 * th, np.sin(th / 2)])
    assert np.allclose(heading_from_quaternion_wxyz(q), th)


def test_suggestions_pull_a_drifted_drive_onto_the_street():
    if not PBF.is_file():
        pytest.fail(f"shared data missing at {PBF}: set POSEFIX_SHARED_DATA")
    ways = read_osm_ways(PBF, BBOX)
    assert ways and all(w.highway != "footway" for w in ways)
    way = max((w for w in ways if w.highway in ("primary", "secondary")), key=lambda w: len(w.lonlat_deg))
    geo = local_georef(*way.lonlat_deg[0])
    xy = geo.to_xy(way.lonlat_deg)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    ss = np.arange(0.0, s[-1], 8.0)
    truth = np.column_stack([np.interp(ss, s, xy[:, 0]), np.interp(ss, s, xy[:, 1])])
    d = np.gradient(truth, axis=0)
    th = np.arctan2(d[:, 1], d[:, 0])
    reported = truth + 9.0 * np.column_stack([-np.sin(th), np.cos(th)])  # 9 m to the left
    q = np.column_stack([np.cos(th / 2), 0 * th, 0 * th, np.sin(th / 2)])
    ll = geo.to_lonlat(reported)
    sug = suggest_for_run(ll[:, 0], ll[:, 1], q, PBF)
    matched = geo.to_xy(sug.lonlat_deg)
    err = np.linalg.norm(matched - truth, axis=1)
    assert err.mean() < 4.0 < 9.0
    assert sug.off_road.mean() > 0.5  # 9 m off a 6.5 m street is mostly off the road
    assert np.allclose(sug.moved_m, np.linalg.norm(matched - reported, axis=1), atol=0.01)
