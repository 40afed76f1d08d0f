"""GeoJSON (RFC 7946): timed LineStrings and Points; round trips and refused input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from posefix.io import OrientationDerivedWarning, RunFormatError, read_run, write_run

from .io_helpers import small_run


def test_round_trip_keeps_pose_gnss_images(tmp_path):
    run = small_run()
    write_run(run, tmp_path / "r.geojson")
    doc = json.loads((tmp_path / "r.geojson").read_text())
    assert doc["features"][0]["geometry"]["coordinates"][0][:2] == [run.lon_deg[0], run.lat_deg[0]]  # lon first
    back = read_run(tmp_path / "r.geojson")
    assert np.array_equal(back.t_s, run.t_s)
    assert np.array_equal(back.lat_deg, run.lat_deg) and np.array_equal(back.alt_m, run.alt_m)
    assert np.abs(back.q_body_to_enu_wxyz - run.q_body_to_enu_wxyz).max() < 1e-15
    assert np.array_equal(np.isnan(back.gnss_lat_deg), np.isnan(run.gnss_lat_deg))
    assert back.images == run.images
    assert back.extra['note'].tolist() == run.extra['note'].tolist()
    assert np.array_equal(back.extra['speed_mps'], run.extra['speed_mps'])


def test_linestring_with_iso_coord_times_and_points(tmp_path):
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"coordTimes": ["2024-05-01T10:00:00Z", "2024-05-01T10:00:01.5Z"]},
         "geometry": {"type": "LineString", "coordinates": [[24.94, 60.17], [24.9401, 60.17]]}},
        {"type": "Feature", "properties": {"time": "2024-05-01T10:00:03Z"},
         "geometry": {"type": "Point", "coordinates": [24.9402, 60.17, 12.0]}},
    ]}
    p = tmp_path / "t.geojson"
    p.write_text(json.dumps(doc))
    with pytest.warns(OrientationDerivedWarning):
        run = read_run(p)
    assert run.n == 3 and run.t_s[1] - run.t_s[0] == pytest.approx(1.5)
    assert run.alt_m.tolist() == [0.0, 0.0, 12.0]


def _feature_file(tmp_path, times, coords, extra_props=None):
    props = {"times": times, **(extra_props or {})}
    text = json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"times": [0, 1], "q_body_to_enu_wxyz": [[1, 0, 0, 0]] * 2},
         "geometry": {"type": "LineString", "coordinates": [[24.0, 60.0], [24.001, 60.0]]}},
        {"type": "Feature", "properties": props, "geometry": {"type": "LineString", "coordinates": coords}},
    ]}, indent=1)
    p = tmp_path / "bad.geojson"
    p.write_text(text)
    return p, text


def _line_of_second_feature(text: str) -> int:
    lines = text.splitlines()
    starts = [i + 1 for i, ln in enumerate(lines) if ln.strip() == "{" and i > 2]
    # first "{" after "features": [ is feature 0; find the one that opens feature 1
    opened = [i for i in starts if '"type": "Feature"' in lines[i]]
    return opened[1]


@pytest.mark.parametrize("times,coords,field,fragment", [
    ([2, 3], [[24.002, 60.0], ["x", 60.0]], "features[1].geometry.coordinates[1][0] (lon)", "not a number"),
    ([2], [[24.002, 60.0], [24.003, 60.0]], "features[1].properties.times", "one time per coordinate"),
    ([2, "yesterday"], [[24.002, 60.0], [24.003, 60.0]], "features[1].properties.times[1]", "ISO 8601"),
    ([2, 3], [[24.002, 60.0], [24.003, 91.0]], "coordinates (lat)", "outside [-90, 90]"),
    ([2, 1.5], [[24.002, 60.0], [24.003, 60.0]], "times", "not strictly increasing"),
])
def test_bad_geojson_names_line_and_field(tmp_path, times, coords, field, fragment):
    q = {"q_body_to_enu_wxyz": [[1, 0, 0, 0]] * len(coords)}
    p, text = _feature_file(tmp_path, times, coords, q)
    with pytest.raises(RunFormatError) as info:
        read_run(p)
    assert info.value.field == field
    assert fragment in info.value.message
    assert info.value.line == _line_of_second_feature(text)


def test_invalid_json_and_wrong_type(tmp_path):
    p = tmp_path / "x.geojson"
    p.write_text('{"type": "FeatureCollection",\n "features": [,]}')
    with pytest.raises(RunFormatError, match="not valid JSON") as info:
        read_run(p)
    assert info.value.line == 2
    p.write_text('{"type": "Polygon", "coordinates": []}')
    with pytest.raises(RunFormatError, match="expected FeatureCollection"):
        read_run(p)
    p.write_text('{"type": "FeatureCollection", "features": []}')
    with pytest.raises(RunFormatError, match="empty"):
        read_run(p)


@pytest.mark.parametrize("coords,field", [
    ([[24.0, 60.0, 0.0], [24.001, 91.0, 0.0]], "coordinates (lat)"),
    ([[24.0, 60.0, 0.0], [24.001, "60.1", 0.0]], "features[0].geometry.coordinates[1][1] (lat)"),
    ([[24.0, 60.0, 0.0], [24.001, True, 0.0]], "features[0].geometry.coordinates[1][1] (lat)"),
])
def test_single_linestring_errors_keep_their_line(tmp_path, coords, field):
    text = json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
         "properties": {"times": [0, 1], "q_body_to_enu_wxyz": [[1, 0, 0, 0]] * 2}}]}, indent=1)
    p = tmp_path / "one.geojson"
    p.write_text(text)
    with pytest.raises(RunFormatError) as info:
        read_run(p)
    assert info.value.field == field
    assert info.value.line == 4  # the line where the feature's object opens


def test_stdlib_decides_what_orjson_refuses(tmp_path):
    """BOM, NaN literals and huge integers read as the stdlib reads them; bad UTF-8 is named."""
    doc = {"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[24.0, 60.0], [24.001, 60.001]]},
           "properties": {"times": [0, 1], "gnss": [[24.0, 60.0, float("nan")], None]}}
    p = tmp_path / "nan.geojson"
    p.write_bytes(b"\xef\xbb\xbf" + json.dumps(doc).encode())  # json writes NaN, which orjson refuses
    with pytest.warns(OrientationDerivedWarning):
        run = read_run(p)
    assert run.n == 2 and np.isnan(run.gnss_alt_m).all() and run.gnss_lat_deg[0] == 60.0
    doc["properties"]["times"] = [0, 10**30]  # beyond 64 bits: orjson refuses, json reads
    p.write_text(json.dumps(doc))
    with pytest.warns(OrientationDerivedWarning):
        assert read_run(p).t_s[1] == 1e30
    p.write_bytes(b'{"type": "Feature", "geometry": null, "properties": {"name": "\xff"}}')
    with pytest.raises(RunFormatError, match="cannot read file"):
        read_run(p)
