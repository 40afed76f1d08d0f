"""The MapLibre style (version 8) the editor loads, built from the registered tile sources.

Every source becomes a MapLibre source; its layers carry ``metadata`` naming the source
and its kind, so the editor's basemap switcher shows one source at a time by toggling
``visibility`` on the layers whose ``metadata["posefix:source"]`` matches. The style's own
``metadata["posefix:sources"]`` lists the sources in switcher order with their layer ids,
and ``metadata["posefix:default"]`` names the one shown first (a street map when there
is one). No layer draws text or icons, so no glyphs or sprites are needed: it works offline.
"""

from __future__ import annotations

from typing import Any

from posefix.basemap import BACKGROUND_COLOR, BASEMAP_SCHEMA, basemap_layers, generic_vector_layers
from posefix.tiles.models import TileKind, TileSource
from posefix.tiles.service import tile_url_template

# The first source of the first kind present is shown when the editor opens.
_DEFAULT_KIND_ORDER = (TileKind.street, TileKind.satellite, TileKind.topo, TileKind.other)


def default_source(sources: list[TileSource]) -> TileSource | None:
    for kind in _DEFAULT_KIND_ORDER:
        for source in sources:
            if source.kind == kind:
                return source
    return None


def source_spec(source: TileSource, base_url: str) -> dict[str, Any]:
    """The MapLibre source object of one tile source."""
    spec: dict[str, Any] = {
        "type": "vector" if source.format == "pbf" else "raster",
        "tiles": [tile_url_template(source, base_url)],
        "minzoom": source.min_zoom,
        "maxzoom": source.max_zoom,
        "attribution": source.attribution,
    }
    if spec["type"] == "raster":
        spec["tileSize"] = source.tile_size
    if source.bounds:
        spec["bounds"] = source.bounds
    return spec


def source_layers(source: TileSource, visible: bool) -> list[dict[str, Any]]:
    """The layers drawing one source, tagged with the source's name and kind."""
    if source.format != "pbf":
        layers = [{
            "id": f"{source.name}-raster", "type": "raster", "source": source.name,
            "layout": {"visibility": "visible" if visible else "none"},
        }]
    elif source.style_schema == BASEMAP_SCHEMA:
        layers = basemap_layers(source.name, visible)
    else:
        layers = generic_vector_layers(source.name, source.vector_layers or [], visible)
    for layer in layers:
        layer["metadata"] = {"posefix:source": source.name, "posefix:kind": source.kind}
    return layers


def build_style(sources: list[TileSource], base_url: str) -> dict[str, Any]:
    """A complete MapLibre style for ``sources``, tile URLs absolute under ``base_url``."""
    shown = default_source(sources)
    style: dict[str, Any] = {
        "version": 8,
        "name": "posefix",
        "sources": {},
        "layers": [{"id": "background", "type": "background", "paint": {"background-color": BACKGROUND_COLOR}}],
        "metadata": {"posefix:sources": [], "posefix:default": shown.name if shown else None},
    }
    if shown is not None and shown.bounds:
        min_lon, min_lat, max_lon, max_lat = shown.bounds
        style["center"] = [(min_lon + max_lon) / 2.0, (min_lat + max_lat) / 2.0]
        style["zoom"] = max(shown.min_zoom, min(15, shown.max_zoom))
    for source in sources:
        style["sources"][source.name] = source_spec(source, base_url)
        layers = source_layers(source, visible=source is shown)
        style["layers"].extend(layers)
        style["metadata"]["posefix:sources"].append({
            "name": source.name, "title": source.title, "kind": source.kind,
            "attribution": source.attribution, "layers": [layer["id"] for layer in layers],
        })
    return style
