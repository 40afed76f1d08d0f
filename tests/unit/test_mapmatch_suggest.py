"""OSM drivable-area rasters and map-matching suggestions for a simulated drive on real streets."""

import os
from pathlib import Path

import numpy as np
import pytest

from posefix.mapmatch.osm import OsmWay, local_georef, raster_from_ways, read_osm_ways
from posefix.mapmatch.suggest import drivable_area, drivable_cache_info, heading_from_quaternion_wxyz, suggest_for_run

REPO = Path(__file__).resolve().parents[2]
PBF = REPO / "data" / "osm" / "helsinki.osm.pbf"
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


def test_drivable_area_is_cached_per_extract_content_box_and_cell(tmp_path):
    drivable_cache_info(clear=True)
    box = (24.940, 60.166, 24.946, 60.170)
    r1, g1 = drivable_area(PBF, box, cell_m=4.0)
    # A box moved by a few metres (keyframes moved by an edit) snaps to the same entry.
    r2, g2 = drivable_area(PBF, (box[0] + 1e-5, box[1], box[2], box[3] - 1e-5), cell_m=4.0)
    assert g2 is g1 and r2 is r1
    assert drivable_cache_info() == {"hits": 1, "misses": 1, "size": 1}
    # Another cell size is another graph.
    assert drivable_area(PBF, box, cell_m=5.0)[1] is not g1
    # The same content under another name hits; changed content misses.
    copy = tmp_path / "copy.osm.pbf"
    copy.write_bytes(PBF.read_bytes())
    assert drivable_area(copy, box, cell_m=4.0)[1] is g1
    copy.write_bytes(PBF.read_bytes()[:-1] + b"\0")
    os.utime(copy, ns=(1, 1))  # a different size/mtime key, so the hash is recomputed
    with pytest.raises(ValueError, match="copy.osm.pbf"):
        drivable_area(copy, box, cell_m=4.0)
    assert drivable_cache_info(clear=True)["hits"] == 2
