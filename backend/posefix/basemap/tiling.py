"""Web Mercator (EPSG:3857) projection and XYZ tile arithmetic.

Tiles follow the XYZ scheme used by MapLibre and PMTiles: zoom ``z`` splits the square
world of side ``2 * HALF_WORLD_M`` into ``2**z`` columns ``x`` (west to east) and ``2**z``
rows ``y`` (north to south). MBTiles stores rows in the TMS scheme (south to north), so
``flip_y`` converts between the two.
"""

from __future__ import annotations

import math

import numpy as np

EARTH_RADIUS_M = 6378137.0  # WGS84 semi-major axis, the sphere Web Mercator uses
HALF_WORLD_M = math.pi * EARTH_RADIUS_M  # 20037508.34 m: the projected half-width
MAX_LAT_DEG = 85.0511287798  # latitude where Web Mercator's square ends


def lonlat_to_mercator_m(lon_deg: np.ndarray, lat_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project WGS84 degrees to Web Mercator metres.

    x = R * lon, y = R * ln(tan(pi/4 + lat/2)); latitude is clamped to the square's edge.
    Shapes: any broadcastable arrays; returns arrays of the broadcast shape.
    """
    lon_rad = np.radians(np.asarray(lon_deg, dtype=float))
    lat_rad = np.radians(np.clip(np.asarray(lat_deg, dtype=float), -MAX_LAT_DEG, MAX_LAT_DEG))
    x_m = EARTH_RADIUS_M * lon_rad
    y_m = EARTH_RADIUS_M * np.log(np.tan(np.pi / 4.0 + lat_rad / 2.0))
    return x_m, y_m


def mercator_to_lonlat_deg(x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`lonlat_to_mercator_m`: lat = 2 atan(exp(y / R)) - pi/2."""
    lon_deg = np.degrees(np.asarray(x_m, dtype=float) / EARTH_RADIUS_M)
    lat_deg = np.degrees(2.0 * np.arctan(np.exp(np.asarray(y_m, dtype=float) / EARTH_RADIUS_M)) - np.pi / 2.0)
    return lon_deg, lat_deg


def tile_size_m(z: int) -> float:
    """Side of one tile at zoom ``z`` in Web Mercator metres."""
    return 2.0 * HALF_WORLD_M / (1 << z)


def tile_bounds_m(z: int, x: int, y: int) -> tuple[float, float, float, float]:
    """(min_x, min_y, max_x, max_y) of XYZ tile (z, x, y) in Web Mercator metres."""
    size_m = tile_size_m(z)
    min_x = -HALF_WORLD_M + x * size_m
    max_y = HALF_WORLD_M - y * size_m
    return min_x, max_y - size_m, min_x + size_m, max_y


def tiles_covering(z: int, bounds_lonlat: tuple[float, float, float, float]) -> list[tuple[int, int]]:
    """(x, y) of every XYZ tile at zoom ``z`` touching (min_lon, min_lat, max_lon, max_lat)."""
    min_lon, min_lat, max_lon, max_lat = bounds_lonlat
    x_m, y_m = lonlat_to_mercator_m(np.array([min_lon, max_lon]), np.array([min_lat, max_lat]))
    size_m = tile_size_m(z)
    last = (1 << z) - 1
    x0 = min(last, max(0, int((x_m[0] + HALF_WORLD_M) // size_m)))
    x1 = min(last, max(0, int((x_m[1] + HALF_WORLD_M) // size_m)))
    # Rows count from the north edge: the max latitude gives the smallest row.
    y0 = min(last, max(0, int((HALF_WORLD_M - y_m[1]) // size_m)))
    y1 = min(last, max(0, int((HALF_WORLD_M - y_m[0]) // size_m)))
    return [(x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1)]


def flip_y(z: int, y: int) -> int:
    """Convert a row between the XYZ (north-first) and TMS (south-first) schemes."""
    return (1 << z) - 1 - y


def is_valid_tile(z: int, x: int, y: int, max_zoom: int = 30) -> bool:
    """True when (z, x, y) names a tile that exists in the XYZ pyramid."""
    return 0 <= z <= max_zoom and 0 <= x < (1 << z) and 0 <= y < (1 << z)
