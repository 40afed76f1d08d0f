"""Read the map features the offline basemap draws from an OpenStreetMap extract.

Five layers (the posefix basemap schema, styled by :mod:`posefix.basemap.style`):

=========  ========  ============================================================
layer      geometry  ``class`` property
=========  ========  ============================================================
roads      line      motorway trunk primary secondary tertiary minor service
                     pedestrian path steps (``_link`` roads take their parent)
rail       line      rail tram subway light_rail
buildings  polygon   building
water      polygon   water
parks      polygon   park grass wood pitch cemetery
=========  ========  ============================================================

Roads also carry ``name`` and ``brunnel`` (``bridge``, ``tunnel`` or ``""``).

Geometries are returned in Web Mercator metres so the tiler only clips and scales.
Extracts are cut from the planet, so a way may lose nodes at the edge: lines keep
each run of consecutive located nodes, and areas whose rings do not close are dropped
(osmium's area assembler refuses them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import osmium
import shapely
from shapely.geometry import LineString, MultiLineString

from posefix.basemap.tiling import lonlat_to_mercator_m

LAYERS = ("water", "parks", "buildings", "rail", "roads")

_ROAD_CLASSES = {
    "motorway": "motorway",
    "trunk": "trunk",
    "primary": "primary",
    "secondary": "secondary",
    "tertiary": "tertiary",
    "residential": "minor",
    "unclassified": "minor",
    "living_street": "minor",
    "road": "minor",
    "service": "service",
    "pedestrian": "pedestrian",
    "footway": "path",
    "cycleway": "path",
    "path": "path",
    "bridleway": "path",
    "track": "path",
    "trail": "path",
    "corridor": "path",
    "steps": "steps",
}
# The zoom from which each road class is worth drawing: a city overview needs the main
# streets only, footways clutter below street level.
_ROAD_MIN_ZOOM = {
    "motorway": 0, "trunk": 0, "primary": 0, "secondary": 0, "tertiary": 12,
    "minor": 13, "service": 14, "pedestrian": 14, "path": 15, "steps": 15,
}
_RAIL_CLASSES = {"rail", "tram", "subway", "light_rail"}
_PARK_CLASSES = {
    ("leisure", "park"): "park",
    ("leisure", "garden"): "park",
    ("leisure", "playground"): "park",
    ("leisure", "recreation_ground"): "park",
    ("leisure", "pitch"): "pitch",
    ("landuse", "grass"): "grass",
    ("landuse", "meadow"): "grass",
    ("landuse", "village_green"): "grass",
    ("landuse", "recreation_ground"): "park",
    ("landuse", "cemetery"): "cemetery",
    ("landuse", "forest"): "wood",
    ("natural", "wood"): "wood",
    ("natural", "scrub"): "wood",
    ("natural", "heath"): "grass",
    ("natural", "wetland"): "grass",
}
_WATER_TAGS = {
    ("natural", "water"), ("landuse", "basin"), ("landuse", "reservoir"),
    ("waterway", "riverbank"), ("waterway", "dock"), ("landuse", "pond"),
}


@dataclass(frozen=True)
class BasemapFeature:
    """One feature of one layer; ``geometry_m`` in Web Mercator metres."""

    layer: str
    geometry_m: shapely.Geometry
    properties: dict[str, str] = field(default_factory=dict)
    min_zoom: int = 0


def classify_road(tags: osmium.osm.TagList) -> str | None:
    """The basemap road class of a way's tags, or None when it is no road we draw."""
    highway = tags.get("highway")
    if highway is None or tags.get("area") == "yes":
        return None
    return _ROAD_CLASSES.get(highway.removesuffix("_link"))


def classify_area(tags: osmium.osm.TagList) -> tuple[str, str] | None:
    """(layer, class) of an area's tags, or None when the basemap does not draw it."""
    if tags.get("building", "no") != "no":
        return "buildings", "building"
    for key, value in _WATER_TAGS:
        if tags.get(key) == value:
            return "water", "water"
    for (key, value), park_class in _PARK_CLASSES.items():
        if tags.get(key) == value:
            return "parks", park_class
    return None


def project_geometry(geometry_lonlat: shapely.Geometry) -> shapely.Geometry:
    """A geometry in lon/lat degrees carried into Web Mercator metres."""

    def project(coords_lonlat: np.ndarray) -> np.ndarray:
        x_m, y_m = lonlat_to_mercator_m(coords_lonlat[:, 0], coords_lonlat[:, 1])
        return np.column_stack([x_m, y_m])

    return shapely.transform(geometry_lonlat, project)


def located_runs(way: osmium.osm.Way) -> list[list[tuple[float, float]]]:
    """Runs of consecutive nodes with known locations, as (lon, lat) lists of 2+ points.

    A gap means the way left the extract; joining across it would draw a false chord.
    """
    runs: list[list[tuple[float, float]]] = [[]]
    for node in way.nodes:
        if node.location.valid():
            runs[-1].append((node.lon, node.lat))
        elif runs[-1]:
            runs.append([])
    return [run for run in runs if len(run) >= 2]


class _FeatureCollector(osmium.SimpleHandler):
    def __init__(self) -> None:
        super().__init__()
        self.features: list[BasemapFeature] = []
        self._wkb = osmium.geom.WKBFactory()

    def way(self, way: osmium.osm.Way) -> None:
        road_class = classify_road(way.tags)
        railway = way.tags.get("railway")
        if road_class is not None:
            properties = {
                "class": road_class,
                "name": way.tags.get("name", ""),
                "brunnel": _brunnel(way.tags),
            }
            self._add_line(way, "roads", properties, _ROAD_MIN_ZOOM[road_class])
        elif railway in _RAIL_CLASSES:
            properties = {"class": railway, "brunnel": _brunnel(way.tags)}
            self._add_line(way, "rail", properties, 13)

    def area(self, area: osmium.osm.Area) -> None:
        layer_class = classify_area(area.tags)
        if layer_class is None:
            return
        layer, area_class = layer_class
        try:
            geometry = shapely.from_wkb(self._wkb.create_multipolygon(area), on_invalid="ignore")
        except RuntimeError:  # rings that do not close inside the extract
            return
        if geometry is None or geometry.is_empty:
            return
        geometry_m = shapely.make_valid(project_geometry(geometry))
        min_zoom = 14 if layer == "buildings" else 0
        properties = {"class": area_class}
        if area.tags.get("name"):
            properties["name"] = area.tags["name"]
        self.features.append(BasemapFeature(layer, geometry_m, properties, min_zoom))

    def _add_line(self, way: osmium.osm.Way, layer: str, properties: dict[str, str], min_zoom: int) -> None:
        runs = located_runs(way)
        if not runs:
            return
        geometry = LineString(runs[0]) if len(runs) == 1 else MultiLineString(runs)
        self.features.append(BasemapFeature(layer, project_geometry(geometry), properties, min_zoom))


def _brunnel(tags: osmium.osm.TagList) -> str:
    if tags.get("bridge", "no") != "no":
        return "bridge"
    if tags.get("tunnel", "no") != "no":
        return "tunnel"
    return ""


def read_basemap_features(osm_path: Path) -> list[BasemapFeature]:
    """Every basemap feature of an OSM file (.osm.pbf, .osm, .osm.bz2)."""
    if not Path(osm_path).is_file():
        raise FileNotFoundError(f"{osm_path}: no such OpenStreetMap file")
    collector = _FeatureCollector()
    try:
        collector.apply_file(str(osm_path), locations=True)
    except RuntimeError as exc:
        raise ValueError(f"{osm_path}: not a readable OpenStreetMap file ({exc})") from exc
    return collector.features
