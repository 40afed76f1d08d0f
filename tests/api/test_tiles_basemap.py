"""The offline basemap builder: projection, feature reading, tile cutting, the PMTiles file."""

from __future__ import annotations

import gzip
import time
from pathlib import Path

import mapbox_vector_tile
import numpy as np
import pytest
import shapely
from pmtiles.reader import MmapSource, Reader, all_tiles
from pmtiles.tile import Compression, TileType

from posefix.basemap import BASEMAP_SCHEMA, build_basemap, basemap_layers
from posefix.basemap.build import EXTENT, clip_feature
from posefix.basemap.features import BasemapFeature, read_basemap_features
from posefix.basemap.tiling import (
    flip_y, lonlat_to_mercator_m, mercator_to_lonlat_deg, tile_bounds_m, tiles_covering,
)

REPO = Path(__file__).resolve().parents[2]
HELSINKI_OSM = REPO / "data" / "osm" / "helsinki.osm.pbf"


class TestTiling:
    def test_projection_round_trips(self) -> None:
        rng = np.random.default_rng(7)
        lon = rng.uniform(-180, 180, 1000)
        lat = rng.uniform(-85, 85, 1000)
        back_lon, back_lat = mercator_to_lonlat_deg(*lonlat_to_mercator_m(lon, lat))
        assert np.allclose(back_lon, lon, atol=1e-9) and np.allclose(back_lat, lat, atol=1e-9)

    def test_known_tile(self) -> None:
        # The zoom 1 tile (1, 0) is the north-east quarter of the world.
        min_x, min_y, max_x, max_y = tile_bounds_m(1, 1, 0)
        assert (min_x, min_y) == (0.0, 0.0) and max_x == pytest.approx(20037508.34, abs=0.01) == max_y
        assert tiles_covering(1, (10.0, 10.0, 20.0, 20.0)) == [(1, 0)]
        assert tiles_covering(0, (-180.0, -85.0, 180.0, 85.0)) == [(0, 0)]
        # Helsinki railway station at zoom 16 (checked against any slippy-map calculator).
        assert tiles_covering(16, (24.9414, 60.1710, 24.9414, 60.1710)) == [(37308, 18969)]

    def test_flip_y_is_an_involution(self) -> None:
        assert flip_y(3, 0) == 7 and flip_y(3, flip_y(3, 5)) == 5


class TestFeatures:
    def test_helsinki_has_every_layer(self) -> None:
        features = read_basemap_features(HELSINKI_OSM)
        layers = {feature.layer for feature in features}
        assert layers == {"roads", "rail", "buildings", "water", "parks"}
        roads = [f for f in features if f.layer == "roads"]
        assert {"primary", "secondary", "minor", "path"} <= {f.properties["class"] for f in roads}
        # Everything lies in central Helsinki: 24.93-24.96 E, 60.16-60.18 N.
        lon, lat = mercator_to_lonlat_deg(*np.array(shapely.bounds(shapely.union_all([f.geometry_m for f in features]))).reshape(2, 2).T)
        assert 24.93 < lon[0] < lon[1] < 24.96 and 60.16 < lat[0] < lat[1] < 60.18

    def test_missing_or_bad_file_is_named(self, tmp_path: Path) -> None:
        with pytest.raises(FileNotFoundError, match="nowhere.osm.pbf"):
            read_basemap_features(tmp_path / "nowhere.osm.pbf")
        bad = tmp_path / "bad.osm.pbf"
        bad.write_bytes(b"\x00\x01garbage" * 50)
        with pytest.raises(ValueError, match="bad.osm.pbf"):
            read_basemap_features(bad)


class TestCutting:
    def test_a_line_across_a_tile_is_clipped_to_the_buffered_tile_and_scaled(self) -> None:
        min_x, min_y, max_x, max_y = tile_bounds_m(14, 9326, 4741)
        mid_y = (min_y + max_y) / 2
        size = max_x - min_x
        line = shapely.LineString([(min_x - size, mid_y), (max_x + size, mid_y)])
        geometry = clip_feature(BasemapFeature("roads", line, {"class": "minor"}), 14, 9326, 4741)
        xs = np.asarray(geometry.coords)[:, 0]
        ys = np.asarray(geometry.coords)[:, 1]
        assert xs.min() == pytest.approx(-64) and xs.max() == pytest.approx(EXTENT + 64)
        assert np.allclose(ys, EXTENT / 2)

    def test_small_buildings_wait_for_closer_zooms(self) -> None:
        min_x, min_y, max_x, max_y = tile_bounds_m(14, 9326, 4741)
        cx, cy = (min_x + max_x) / 2 + 1.0, (min_y + max_y) / 2 + 1.0
        # 4 m x 4 m: under 2x2 screen pixels at zoom 14 (4.8 m/px), several pixels at zoom 16.
        hut = BasemapFeature("buildings", shapely.box(cx, cy, cx + 4.0, cy + 4.0), {"class": "building"})
        assert clip_feature(hut, 14, 9326, 4741) is None
        assert clip_feature(hut, 16, 9326 * 4 + 2, 4741 * 4 + 1) is not None


class TestBuild:
    def test_helsinki_basemap_is_small_fast_and_complete(self, tmp_path: Path) -> None:
        out = tmp_path / "basemap" / "helsinki.pmtiles"
        started = time.perf_counter()
        summary = build_basemap(HELSINKI_OSM, out, min_zoom=12, max_zoom=16)
        assert time.perf_counter() - started < 30  # "well under a minute" on a shared 2-core box
        assert summary.path == out and out.stat().st_size == summary.bytes < 2_000_000
        assert not [p for p in out.parent.iterdir() if p.name.startswith(".basemap-")]
        with open(out, "rb") as handle:
            reader = Reader(MmapSource(handle))
            header, metadata = reader.header(), reader.metadata()
            tiles = dict(all_tiles(reader.get_bytes))
        assert header["tile_type"] == TileType.MVT and header["tile_compression"] == Compression.GZIP
        assert (header["min_zoom"], header["max_zoom"]) == (12, 16)
        assert metadata["attribution"] == "© OpenStreetMap contributors"
        assert metadata["posefix:schema"] == BASEMAP_SCHEMA
        assert {z for z, _, _ in tiles} == {12, 13, 14, 15, 16} and len(tiles) == summary.tiles
        # Every tile decodes, and at zoom 16 every one of them has streets.
        for (z, _, _), data in tiles.items():
            layers = mapbox_vector_tile.decode(gzip.decompress(data))
            assert layers
            if z == 16:
                assert layers["roads"]["features"]

    def test_bad_zoom_range_and_empty_extract_leave_nothing(self, tmp_path: Path) -> None:
        out = tmp_path / "x.pmtiles"
        with pytest.raises(ValueError, match="zoom range"):
            build_basemap(HELSINKI_OSM, out, min_zoom=10, max_zoom=9)
        empty = tmp_path / "empty.osm"
        empty.write_text("<?xml version='1.0'?><osm version='0.6'></osm>")
        with pytest.raises(ValueError, match="no roads"):
            build_basemap(empty, out)
        assert list(tmp_path.iterdir()) == [empty]


class TestStyleLayers:
    def test_layers_cover_the_schema_and_hide_together(self) -> None:
        layers = basemap_layers("hel", visible=False)
        assert {layer["source-layer"] for layer in layers} == {"roads", "rail", "buildings", "water", "parks"}
        assert {layer["layout"]["visibility"] for layer in layers} == {"none"}
        assert len({layer["id"] for layer in layers}) == len(layers)
        # Road casings sit below every road fill so junctions merge.
        ids = [layer["id"] for layer in layers]
        last_casing = max(i for i, name in enumerate(ids) if name.endswith("-casing"))
        first_fill = min(i for i, name in enumerate(ids) if name.startswith("hel-road-") and not name.endswith("-casing"))
        assert last_casing < first_fill


class TestBasemapCommand:
    def test_posefix_basemap_build(self, tmp_path: Path) -> None:
        from click.testing import CliRunner

        from posefix.cli import build_app

        app = build_app()
        runner = CliRunner()
        out = tmp_path / "city.pmtiles"
        result = runner.invoke(app, ["basemap", "build", str(HELSINKI_OSM), str(out), "--max-zoom", "14"])
        assert result.exit_code == 0, result.output
        assert "zooms 12-14" in result.output and out.is_file()
        missing = runner.invoke(app, ["basemap", "build", str(tmp_path / "none.osm.pbf"), str(tmp_path / "x.pmtiles")])
        assert missing.exit_code == 2 and "none.osm.pbf" in missing.output
        assert not (tmp_path / "x.pmtiles").exists()
