"""MapLibre style layers for vector tiles of the posefix basemap schema.

No layer uses text or icons, so the style needs no glyphs or sprites and renders offline.
Road widths grow exponentially with zoom (base 1.5), the way web maps keep streets
legible from the city overview (zoom 13) to street level (zoom 18).
"""

from __future__ import annotations

from typing import Any

BACKGROUND_COLOR = "#f2efe9"

# (class, fill colour, casing colour, width at zoom 13 in px, width at zoom 18 in px)
_ROAD_STYLES = (
    ("motorway", "#e892a2", "#c24e6e", 2.5, 22.0),
    ("trunk", "#f9b29c", "#c84e2f", 2.5, 20.0),
    ("primary", "#fcd6a4", "#a06b00", 2.0, 18.0),
    ("secondary", "#f7fabf", "#707d05", 1.8, 16.0),
    ("tertiary", "#ffffff", "#8f8f8f", 1.4, 14.0),
    ("minor", "#ffffff", "#b0aaa2", 1.0, 12.0),
    ("pedestrian", "#eeeeee", "#b0aaa2", 0.8, 9.0),
    ("service", "#ffffff", "#b0aaa2", 0.5, 6.0),
)
_PATH_CLASSES = ("path", "steps")
_PARK_COLORS = {"park": "#c8facc", "grass": "#cdebb0", "wood": "#add19e", "pitch": "#aae0cb", "cemetery": "#aacbaf"}


def _zoom_width(at_13_px: float, at_18_px: float) -> list[Any]:
    return ["interpolate", ["exponential", 1.5], ["zoom"], 13, at_13_px, 18, at_18_px]


def _layer(layer_id: str, layer_type: str, source_id: str, source_layer: str, **parts: Any) -> dict[str, Any]:
    layer = {"id": layer_id, "type": layer_type, "source": source_id, "source-layer": source_layer}
    layer.update(parts)
    return layer


def basemap_layers(source_id: str, visible: bool = True) -> list[dict[str, Any]]:
    """Layers drawing a posefix-schema vector source, bottom to top; ids are prefixed by the source."""
    visibility = "visible" if visible else "none"
    layout = {"visibility": visibility}
    line_layout = {"visibility": visibility, "line-cap": "round", "line-join": "round"}
    prefix = f"{source_id}-"
    park_color: list[Any] = ["match", ["get", "class"]]
    for park_class, color in _PARK_COLORS.items():
        park_color += [park_class, color]
    park_color.append(_PARK_COLORS["park"])

    layers = [
        _layer(prefix + "parks", "fill", source_id, "parks", layout=layout, paint={"fill-color": park_color}),
        _layer(prefix + "water", "fill", source_id, "water", layout=layout, paint={"fill-color": "#aad3df"}),
        _layer(
            prefix + "buildings", "fill", source_id, "buildings", minzoom=14, layout=layout,
            paint={"fill-color": "#d9d0c9", "fill-outline-color": "#bfb3a8",
                   "fill-opacity": ["interpolate", ["linear"], ["zoom"], 14, 0.4, 16, 1.0]},
        ),
        _layer(
            prefix + "paths", "line", source_id, "roads", minzoom=15,
            filter=["in", ["get", "class"], ["literal", list(_PATH_CLASSES)]],
            layout=line_layout,
            paint={"line-color": "#e9967a", "line-width": _zoom_width(0.5, 1.8), "line-dasharray": [2, 1.5],
                   "line-opacity": 0.6},
        ),
    ]
    # Casings first, all of them under every fill, so crossings merge into junctions.
    for road_class, _, casing, at_13_px, at_18_px in reversed(_ROAD_STYLES):
        layers.append(_layer(
            f"{prefix}road-{road_class}-casing", "line", source_id, "roads",
            filter=["==", ["get", "class"], road_class], layout=line_layout,
            paint={"line-color": casing, "line-width": _zoom_width(at_13_px + 1.0, at_18_px + 3.0),
                   "line-opacity": ["case", ["==", ["get", "brunnel"], "tunnel"], 0.4, 1.0]},
        ))
    for road_class, fill, _, at_13_px, at_18_px in reversed(_ROAD_STYLES):
        layers.append(_layer(
            f"{prefix}road-{road_class}", "line", source_id, "roads",
            filter=["==", ["get", "class"], road_class], layout=line_layout,
            paint={"line-color": fill, "line-width": _zoom_width(at_13_px, at_18_px)},
        ))
    layers.append(_layer(
        prefix + "rail", "line", source_id, "rail", minzoom=13,
        filter=["!=", ["get", "brunnel"], "tunnel"], layout=layout,
        paint={"line-color": ["match", ["get", "class"], "tram", "#6e6e9e", "#707070"],
               "line-width": _zoom_width(0.6, 2.5),
               "line-dasharray": [3, 2]},
    ))
    return layers


def generic_vector_layers(source_id: str, vector_layers: list[dict[str, Any]], visible: bool = True) -> list[dict[str, Any]]:
    """Plain layers for a vector source of unknown schema: fills, lines and points per source layer.

    Taken from the TileJSON ``vector_layers`` list so any registered vector source shows
    something sensible until someone writes a style for it.
    """
    layout = {"visibility": "visible" if visible else "none"}
    layers: list[dict[str, Any]] = []
    for entry in vector_layers:
        name = str(entry.get("id", ""))
        if not name:
            continue
        layers.append(_layer(f"{source_id}-{name}-fill", "fill", source_id, name, layout=layout,
                             filter=["==", ["geometry-type"], "Polygon"],
                             paint={"fill-color": "#d9d0c9", "fill-opacity": 0.6}))
        layers.append(_layer(f"{source_id}-{name}-line", "line", source_id, name, layout=layout,
                             filter=["==", ["geometry-type"], "LineString"],
                             paint={"line-color": "#8a8a8a", "line-width": _zoom_width(0.5, 4.0)}))
        layers.append(_layer(f"{source_id}-{name}-point", "circle", source_id, name, layout=layout,
                             filter=["==", ["geometry-type"], "Point"],
                             paint={"circle-color": "#6a6a6a", "circle-radius": 2}))
    return layers
