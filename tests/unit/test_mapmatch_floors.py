"""Floor reader on the two real competition layouts in data/, and its fall-backs and refusals."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from posefix.mapmatch.floorplan import FloorFormatError, read_ilc_floor
from posefix.mapmatch.sensors import read_walk

DATA = Path(__file__).resolve().parents[2] / "data"
SITE1, SITE2 = DATA / "indoor-site1-F1", DATA / "indoor-site2-F2"


def waypoints(floor: Path) -> np.ndarray:
    return np.concatenate([read_walk(p).waypoints[:, 1:3] for p in sorted((floor / "walks").glob("*.txt"))])


def copy_floor(src: Path, dst: Path, features=None) -> Path:
    """A copy of the floor's three files, with the GeoJSON's features replaced by ``features(old)``."""
    dst.mkdir()
    for name in ("floor_info.json", "floor_image.png", "geojson_map.json"):
        shutil.copy(src / name, dst / name)
    if features is not None:
        gj = json.loads((src / "geojson_map.json").read_text())
        gj["features"] = features(gj["features"])
        (dst / "geojson_map.json").write_text(json.dumps(gj))
    return dst


@pytest.mark.parametrize("floor, why", [(SITE1, "type/category 'floor'"), (SITE2, "properties differ from the shops'")])
def test_both_layouts_read_and_every_waypoint_is_walkable(floor, why):
    raster, report = read_ilc_floor(floor, res_m=0.2)
    assert why in report.outline and report.outline.startswith("geojson_map.json features[0]")
    assert any("shop polygon(s) blocked" in u for u in report.used)
    wp = waypoints(floor)
    assert wp.shape[0] >= 15
    assert raster.is_walkable(wp).all()
    # The geo-reference is the outline's box on the floor's extent: metres per degree as on the globe
    # (north ~111 km/°, east cos(latitude) of it), so the plan is not stretched.
    g = raster.georef
    lat = g.lat0_deg + 100 * g.dlat_deg_per_m
    assert 1 / g.dlat_deg_per_m == pytest.approx(111_000, rel=0.01)
    assert 1 / g.dlon_deg_per_m == pytest.approx(111_320 * np.cos(np.radians(lat)), rel=0.01)


def test_without_an_outline_the_image_is_read_and_the_report_says_so(tmp_path):
    # site2 with its outline removed and a point feature added: no polygon encloses the others.
    d = copy_floor(SITE2, tmp_path / "f", lambda f: f[1:] + [{"type": "Feature", "properties": {},
                                                             "geometry": {"type": "Point", "coordinates": [120.1, 30.3]}}])
    raster, report = read_ilc_floor(d, res_m=0.2)
    assert report.outline.startswith("floor_image.png")
    assert any("geometry Point" in s for s in report.skipped)
    assert any("no polygon encloses the others" in s for s in report.skipped)
    # The image's corridors hold the surveyed walks: every waypoint within 1.5 m of one (the
    # image is 0.3 m a pixel and its shop outlines are drawn a pixel or two thick).
    wp = waypoints(SITE2)
    near = np.zeros(len(wp), bool)
    for dx in (-1.5, 0.0, 1.5):
        for dy in (-1.5, 0.0, 1.5):
            near |= raster.is_walkable(wp + [dx, dy])
    assert near.all()
    full, _ = read_ilc_floor(SITE2, res_m=0.2)
    assert 0.7 < raster.walkable.sum() / full.walkable.sum() < 1.2
    assert raster.georef is not None  # from the bounding box of the shops that are left


def test_unusable_geojson_is_skipped_for_the_image(tmp_path):
    d = copy_floor(SITE1, tmp_path / "f")
    (d / "geojson_map.json").write_text("{not json")
    raster, report = read_ilc_floor(d, res_m=0.2)
    assert report.outline.startswith("floor_image.png") and raster.walkable.any()
    assert any("geojson_map.json:1: field features: not JSON" in s for s in report.skipped)
    assert raster.georef is None and any("geo-reference" in s for s in report.skipped)


def test_refused_only_when_nothing_usable_is_left(tmp_path):
    d = copy_floor(SITE2, tmp_path / "f", lambda f: f[1:])
    (d / "floor_image.png").unlink()
    with pytest.raises(FloorFormatError, match=r"geojson_map.json:0: field features: no polygon encloses the others.*no floor_image.png"):
        read_ilc_floor(d, res_m=0.2)
    (d / "floor_info.json").write_text('{"map_info": {"width": 10}}')
    with pytest.raises(FloorFormatError, match=r"floor_info.json:0: field map_info.width/height"):
        read_ilc_floor(d)


def test_cli_build_reports_the_outline_for_the_second_site(tmp_path):
    from click.testing import CliRunner

    from posefix.cli import build_app

    out = CliRunner().invoke(build_app(), ["mapmatch", "build", "--floor", str(SITE2), "--output", str(tmp_path / "m.npz"),
                                   "--raster-m", "0.2"])
    assert out.exit_code == 0, out.output
    assert "outline: geojson_map.json features[0] (the one feature whose properties differ" in out.output
    assert "304 shop polygon(s) blocked" in out.output and (tmp_path / "m.npz").stat().st_size > 10_000
