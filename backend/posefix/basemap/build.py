"""Cut the basemap features into Mapbox Vector Tiles and write them as one PMTiles file.

Each tile holds the features whose bounds touch the tile grown by ``BUFFER_PX`` on every
side (so strokes and fills do not stop short at tile seams), clipped to that grown box,
simplified to half a tile pixel, and scaled to the tile's ``EXTENT`` integer grid with y
pointing down. Tiles are gzip-compressed, as the PMTiles header then declares and the
tile server forwards as ``Content-Encoding: gzip``.
"""

from __future__ import annotations

import gzip
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mapbox_vector_tile
import numpy as np
import shapely
from pmtiles.tile import Compression, TileType, zxy_to_tileid
from pmtiles.writer import Writer
from tqdm import tqdm

from posefix.basemap.features import LAYERS, BasemapFeature, read_basemap_features
from posefix.basemap.tiling import mercator_to_lonlat_deg, tile_bounds_m, tile_size_m, tiles_covering

EXTENT = 4096  # integer grid of one vector tile (the MVT default)
BUFFER_PX = 64  # tile-grid units kept beyond each edge
SCREEN_TILE_PX = 512  # MapLibre draws a vector tile over 512 screen pixels
OSM_ATTRIBUTION = "© OpenStreetMap contributors"
BASEMAP_SCHEMA = "posefix-basemap-1"  # metadata marker: the style in posefix.basemap.style fits it

_LINE_TYPES = {"LineString", "MultiLineString"}
_POLYGON_TYPES = {"Polygon", "MultiPolygon"}
_LAYER_FIELDS = {
    "roads": {"class": "String", "name": "String", "brunnel": "String"},
    "rail": {"class": "String", "brunnel": "String"},
    "buildings": {"class": "String"},
    "water": {"class": "String", "name": "String"},
    "parks": {"class": "String", "name": "String"},
}


@dataclass(frozen=True)
class BasemapSummary:
    """What :func:`build_basemap` wrote."""

    path: Path
    tiles: int
    bytes: int
    min_zoom: int
    max_zoom: int
    bounds_lonlat: tuple[float, float, float, float]


def feature_bounds_lonlat(features: Sequence[BasemapFeature]) -> tuple[float, float, float, float]:
    """(min_lon, min_lat, max_lon, max_lat) enclosing every feature."""
    boxes_m = shapely.bounds([feature.geometry_m for feature in features])
    lon_deg, lat_deg = mercator_to_lonlat_deg(
        np.array([boxes_m[:, 0].min(), boxes_m[:, 2].max()]),
        np.array([boxes_m[:, 1].min(), boxes_m[:, 3].max()]),
    )
    return float(lon_deg[0]), float(lat_deg[0]), float(lon_deg[1]), float(lat_deg[1])


def to_tile_grid(geometry_m: shapely.Geometry, bounds_m: tuple[float, float, float, float]) -> shapely.Geometry:
    """Scale a geometry in Web Mercator metres to a tile's 0..EXTENT grid, y down."""
    min_x, _, _, max_y = bounds_m
    scale = EXTENT / (bounds_m[2] - min_x)

    def scale_to_grid(coords_m: np.ndarray) -> np.ndarray:
        return np.column_stack([(coords_m[:, 0] - min_x) * scale, (max_y - coords_m[:, 1]) * scale])

    return shapely.transform(geometry_m, scale_to_grid)


def clip_feature(feature: BasemapFeature, z: int, x: int, y: int) -> shapely.Geometry | None:
    """The feature's part inside tile (z, x, y) plus buffer, in tile-grid units, or None."""
    bounds_m = tile_bounds_m(z, x, y)
    pixel_m = tile_size_m(z) / EXTENT
    buffer_m = BUFFER_PX * pixel_m
    clipped_m = shapely.clip_by_rect(
        feature.geometry_m,
        bounds_m[0] - buffer_m, bounds_m[1] - buffer_m, bounds_m[2] + buffer_m, bounds_m[3] + buffer_m,
    )
    if clipped_m.is_empty:
        return None
    # Half a grid unit: finer detail would be rounded away by the integer grid anyway.
    clipped_m = shapely.simplify(clipped_m, 0.5 * pixel_m, preserve_topology=True)
    wanted = _POLYGON_TYPES if feature.layer in ("buildings", "water", "parks") else _LINE_TYPES
    parts = [part for part in shapely.get_parts(clipped_m) if part.geom_type in wanted and not part.is_empty]
    if not parts:
        return None
    screen_px_m = tile_size_m(z) / SCREEN_TILE_PX
    if feature.layer == "buildings" and sum(part.area for part in parts) < (2.0 * screen_px_m) ** 2:
        return None  # smaller than 2x2 screen pixels: noise at this zoom
    if len(parts) == 1:
        merged_m = parts[0]
    elif wanted is _POLYGON_TYPES:
        merged_m = shapely.union_all(parts)
    else:
        merged_m = shapely.multilinestrings(parts)
    return to_tile_grid(merged_m, bounds_m)


def encode_tile(features: Sequence[BasemapFeature], z: int, x: int, y: int) -> bytes | None:
    """The gzip-compressed MVT of tile (z, x, y), or None when no feature reaches it."""
    layers: dict[str, list[dict]] = {name: [] for name in LAYERS}
    for feature in features:
        if feature.min_zoom > z:
            continue
        geometry = clip_feature(feature, z, x, y)
        if geometry is not None:
            layers[feature.layer].append({"geometry": geometry, "properties": feature.properties})
    encoded_layers = [{"name": name, "features": items} for name, items in layers.items() if items]
    if not encoded_layers:
        return None
    mvt = mapbox_vector_tile.encode(
        encoded_layers,
        default_options={
            "extents": EXTENT,
            "y_coord_down": True,
            "on_invalid_geometry": mapbox_vector_tile.encoder.on_invalid_geometry_make_valid,
        },
    )
    return gzip.compress(mvt, mtime=0)


def build_basemap(
    osm_path: Path,
    out_path: Path,
    min_zoom: int = 12,
    max_zoom: int = 16,
    show_progress: bool = False,
) -> BasemapSummary:
    """Build a vector-tile PMTiles basemap of an OSM extract at zooms ``min_zoom..max_zoom``.

    MapLibre over-zooms the ``max_zoom`` tiles for closer views, so 16 serves street level
    (zoom 18) with sub-metre precision. The file appears atomically: a half-written basemap
    is never left at ``out_path``.
    """
    if not 0 <= min_zoom <= max_zoom <= 18:
        raise ValueError(f"zoom range {min_zoom}..{max_zoom}: need 0 <= min_zoom <= max_zoom <= 18")
    features = read_basemap_features(Path(osm_path))
    if not features:
        raise ValueError(f"{osm_path}: no roads, buildings, water or parks to draw")
    bounds_lonlat = feature_bounds_lonlat(features)
    tree = shapely.STRtree([feature.geometry_m for feature in features])
    jobs = [(z, x, y) for z in range(min_zoom, max_zoom + 1) for x, y in tiles_covering(z, bounds_lonlat)]

    tiles: list[tuple[int, bytes]] = []
    for z, x, y in tqdm(jobs, desc="basemap tiles", unit="tile", disable=not show_progress):
        bounds_m = tile_bounds_m(z, x, y)
        buffer_m = BUFFER_PX * tile_size_m(z) / EXTENT
        box_m = shapely.box(bounds_m[0] - buffer_m, bounds_m[1] - buffer_m, bounds_m[2] + buffer_m, bounds_m[3] + buffer_m)
        nearby = [features[i] for i in sorted(tree.query(box_m))]
        data = encode_tile(nearby, z, x, y)
        if data is not None:
            tiles.append((zxy_to_tileid(z, x, y), data))
    if not tiles:
        raise ValueError(f"{osm_path}: the features produced no tiles at zooms {min_zoom}..{max_zoom}")
    tiles.sort(key=lambda item: item[0])

    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    metadata = basemap_metadata(bounds_lonlat, min_zoom, max_zoom)
    header = {
        "tile_type": TileType.MVT,
        "tile_compression": Compression.GZIP,
        "min_lon_e7": int(bounds_lonlat[0] * 1e7),
        "min_lat_e7": int(bounds_lonlat[1] * 1e7),
        "max_lon_e7": int(bounds_lonlat[2] * 1e7),
        "max_lat_e7": int(bounds_lonlat[3] * 1e7),
        "center_zoom": min(max_zoom, 15),
    }
    fd, tmp_name = tempfile.mkstemp(prefix=".basemap-", suffix=".pmtiles", dir=out_path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            writer = Writer(handle)
            for tile_id, data in tiles:
                writer.write_tile(tile_id, data)
            writer.finalize(header, metadata)
        os.chmod(tmp_name, 0o644)  # mkstemp makes it owner-only; the server may run as another user
        os.replace(tmp_name, out_path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return BasemapSummary(out_path, len(tiles), out_path.stat().st_size, min_zoom, max_zoom, bounds_lonlat)


def basemap_metadata(bounds_lonlat: tuple[float, float, float, float], min_zoom: int, max_zoom: int) -> dict:
    """PMTiles/TileJSON metadata: attribution, layer list and the posefix schema marker."""
    return {
        "name": "posefix offline basemap",
        "format": "pbf",
        "type": "baselayer",
        "attribution": OSM_ATTRIBUTION,
        "posefix:schema": BASEMAP_SCHEMA,
        "bounds": ",".join(f"{value:.7f}" for value in bounds_lonlat),
        "vector_layers": [
            {"id": name, "fields": _LAYER_FIELDS[name], "minzoom": min_zoom, "maxzoom": max_zoom}
            for name in LAYERS
        ],
    }
