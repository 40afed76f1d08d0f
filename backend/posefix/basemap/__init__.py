"""The offline basemap: OpenStreetMap extract -> vector tiles (PMTiles) -> MapLibre style.

Numerics and file work only: no web or database code, so the demo set-up, the CLI and
tests can build a basemap without a server.
"""

from posefix.basemap.build import BASEMAP_SCHEMA, OSM_ATTRIBUTION, BasemapSummary, build_basemap
from posefix.basemap.style import BACKGROUND_COLOR, basemap_layers, generic_vector_layers

__all__ = [
    "BACKGROUND_COLOR",
    "BASEMAP_SCHEMA",
    "OSM_ATTRIBUTION",
    "BasemapSummary",
    "basemap_layers",
    "build_basemap",
    "generic_vector_layers",
]
