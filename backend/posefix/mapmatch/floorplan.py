"""Floor plans to a walkable raster in the floor frame (metres, x east, y north).

Every map source (competition floor directory, GeoJSON polygons or walls, a floor-plan
image with scale and origin, OpenStreetMap ways in :mod:`posefix.mapmatch.osm`) becomes
one :class:`WalkableRaster`: a boolean grid at a fine resolution (default 0.1 m) that
:mod:`posefix.mapmatch.graph` samples for cells and for line-of-sight between cell centres.

Geo-reference of the Indoor Location Competition floors. ``floor_info.json`` gives the
floor extent ``width × height`` in metres, origin at the bottom-left of ``floor_image.png``;
``geojson_map.json`` is in lon/lat. We fit the axis-aligned affine that maps the bounding
box of the ``floor`` feature (the outline of the whole floor) onto ``[0, W] × [0, H]``::

    x_m = (lon - lon_min) · W / (lon_max - lon_min),   y_m = (lat - lat_min) · H / (lat_max - lat_min)

On site1/F1 the two scales are 96 119 m/° (east) and 111 319 m/° (north), whose ratio is
cos(30.29°) to 0.02 %: the plan is north-up and undistorted, so the box fit is the
geo-reference (checked against the floor image's outline and all 180 surveyed waypoints,
which all fall in the corridors). Walkable = inside the floor outline and outside every
shop polygon (the shops have no door information; ``shops_walkable=True`` lets them in).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "FloorFormatError",
    "WalkableRaster",
    "GeoRef",
    "fill_polygons",
    "draw_segments",
    "raster_from_polygons",
    "load_ilc_floor",
    "raster_from_image",
]


class FloorFormatError(ValueError):
    """A floor-plan input that cannot be used; ``str()`` names file, line (0 if n/a) and field."""

    def __init__(self, file: str, line: int, field: str, message: str):
        self.file, self.line, self.field = file, line, field
        super().__init__(f"{file}:{line}: field {field}: {message}")


@dataclass(frozen=True)
class GeoRef:
    """Axis-aligned affine floor metres <-> lon/lat: ``lon = lon0 + x·dlon_per_m`` etc."""

    lon0_deg: float
    lat0_deg: float
    dlon_deg_per_m: float
    dlat_deg_per_m: float

    def to_lonlat(self, p_xy_m: np.ndarray) -> np.ndarray:
        """(n, 2) floor metres -> (n, 2) lon, lat degrees."""
        p = np.asarray(p_xy_m, dtype=float)
        return np.column_stack([self.lon0_deg + p[:, 0] * self.dlon_deg_per_m,
                                self.lat0_deg + p[:, 1] * self.dlat_deg_per_m])

    def to_xy(self, lonlat_deg: np.ndarray) -> np.ndarray:
        """(n, 2) lon, lat degrees -> (n, 2) floor metres."""
        q = np.asarray(lonlat_deg, dtype=float)
        return np.column_stack([(q[:, 0] - self.lon0_deg) / self.dlon_deg_per_m,
                                (q[:, 1] - self.lat0_deg) / self.dlat_deg_per_m])

    def as_array(self) -> np.ndarray:
        return np.array([self.lon0_deg, self.lat0_deg, self.dlon_deg_per_m, self.dlat_deg_per_m])


@dataclass(frozen=True)
class WalkableRaster:
    """Boolean walkable grid: ``walkable[r, c]`` covers x ∈ [x0 + c·res, x0 + (c+1)·res),
    y ∈ [y0 + r·res, ...) — row 0 is the *south* edge (floor frame, y up)."""

    walkable: np.ndarray
    res_m: float
    x0_m: float = 0.0
    y0_m: float = 0.0
    georef: GeoRef | None = None

    @property
    def width_m(self) -> float:
        return self.walkable.shape[1] * self.res_m

    @property
    def height_m(self) -> float:
        return self.walkable.shape[0] * self.res_m

    def is_walkable(self, p_xy_m: np.ndarray) -> np.ndarray:
        """Walkable flags for points (..., 2); outside the raster is not walkable."""
        p = np.asarray(p_xy_m, dtype=float)
        c = np.floor((p[..., 0] - self.x0_m) / self.res_m).astype(np.int64)
        r = np.floor((p[..., 1] - self.y0_m) / self.res_m).astype(np.int64)
        h, w = self.walkable.shape
        inside = (c >= 0) & (c < w) & (r >= 0) & (r < h)
        out = np.zeros(p.shape[:-1], dtype=bool)
        out[inside] = self.walkable[r[inside], c[inside]]
        return out


def fill_polygons(shape: tuple[int, int], res_m: float, x0_m: float, y0_m: float,
                  rings_xy_m: list[np.ndarray]) -> np.ndarray:
    """Even-odd scanline fill of the rings (each (n, 2) metres) of ONE polygon.

    A pixel is inside when its centre is; holes are rings too (even-odd rule). Per row,
    the x of every edge crossing the row centre toggles parity from the first pixel
    centre to its right; a cumulative sum mod 2 fills between crossings.
    """
    h_full, w_full = shape
    out = np.zeros(shape, dtype=bool)
    pts = [np.asarray(r, dtype=float) for r in rings_xy_m if len(r) >= 3]
    if not pts:
        return out
    allp = np.concatenate(pts)
    # Work inside the polygon's bounding box only (a floor has hundreds of small shops).
    c_lo = max(int(np.floor((allp[:, 0].min() - x0_m) / res_m)) - 1, 0)
    c_hi = min(int(np.ceil((allp[:, 0].max() - x0_m) / res_m)) + 1, w_full)
    r_lo = max(int(np.floor((allp[:, 1].min() - y0_m) / res_m)) - 1, 0)
    r_hi = min(int(np.ceil((allp[:, 1].max() - y0_m) / res_m)) + 1, h_full)
    if c_hi <= c_lo or r_hi <= r_lo:
        return out
    x0_m, y0_m = x0_m + c_lo * res_m, y0_m + r_lo * res_m
    h, w = r_hi - r_lo, c_hi - c_lo
    toggles = np.zeros((h, w + 1), dtype=np.int32)
    for ring in pts:
        ring = np.asarray(ring, dtype=float)
        if ring.shape[0] < 3:
            continue
        a = ring
        b = np.roll(ring, -1, axis=0)
        ya, yb = (a[:, 1] - y0_m) / res_m - 0.5, (b[:, 1] - y0_m) / res_m - 0.5
        xa, xb = (a[:, 0] - x0_m) / res_m - 0.5, (b[:, 0] - x0_m) / res_m - 0.5
        lo = np.ceil(np.minimum(ya, yb)).astype(np.int64)
        hi = np.ceil(np.maximum(ya, yb)).astype(np.int64) - 1  # half-open: [min, max)
        lo, hi = np.maximum(lo, 0), np.minimum(hi, h - 1)
        sel = np.nonzero(hi >= lo)[0]
        if sel.size == 0:
            continue
        counts = hi[sel] - lo[sel] + 1
        edge = np.repeat(sel, counts)
        rows = lo[edge] + (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts))
        x = xa[edge] + (rows - ya[edge]) * (xb[edge] - xa[edge]) / (yb[edge] - ya[edge])
        cols = np.clip(np.ceil(x).astype(np.int64), 0, w)
        np.add.at(toggles, (rows, cols), 1)
    out[r_lo:r_hi, c_lo:c_hi] = (np.cumsum(toggles, axis=1)[:, :w] % 2).astype(bool)
    return out


def draw_segments(mask: np.ndarray, res_m: float, x0_m: float, y0_m: float,
                  segments_xy_m: np.ndarray, value: bool = False) -> np.ndarray:
    """Return a copy of ``mask`` with thin walls (m, 2, 2) metres drawn as ``value``.

    Samples every 0.25 px along each segment and also sets the 4-neighbours' shared
    corners, so a diagonal wall leaves no gap a line could slip through.
    """
    out = mask.copy()
    h, w = out.shape
    for seg in np.asarray(segments_xy_m, dtype=float).reshape(-1, 2, 2):
        n = int(np.ceil(np.linalg.norm(seg[1] - seg[0]) / (0.25 * res_m))) + 2
        s = np.linspace(0.0, 1.0, n)[:, None]
        p = seg[0] + s * (seg[1] - seg[0])
        c = np.floor((p[:, 0] - x0_m) / res_m).astype(np.int64)
        r = np.floor((p[:, 1] - y0_m) / res_m).astype(np.int64)
        for dr, dc in ((0, 0), (1, 0), (0, 1)):
            rr, cc = r + dr, c + dc
            ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
            out[rr[ok], cc[ok]] = value
    return out


def raster_from_polygons(width_m: float, height_m: float, walkable_polys: list[list[np.ndarray]],
                         blocked_polys: list[list[np.ndarray]] = (), walls: np.ndarray | None = None,
                         res_m: float = 0.1, georef: GeoRef | None = None) -> WalkableRaster:
    """Walkable = union(walkable polygons) - union(blocked polygons) - walls (all metres).

    Each polygon is a list of rings (n, 2). ``walls`` (m, 2, 2) are thin wall segments.
    """
    if not (width_m > 0 and height_m > 0):
        raise ValueError(f"floor extent must be positive, got {width_m} x {height_m} m")
    shape = (int(np.ceil(height_m / res_m)), int(np.ceil(width_m / res_m)))
    mask = np.zeros(shape, dtype=bool)
    for rings in walkable_polys:
        mask |= fill_polygons(shape, res_m, 0.0, 0.0, rings)
    for rings in blocked_polys:
        mask &= ~fill_polygons(shape, res_m, 0.0, 0.0, rings)
    if walls is not None and len(walls):
        mask = draw_segments(mask, res_m, 0.0, 0.0, walls, value=False)
    return WalkableRaster(walkable=mask, res_m=res_m, georef=georef)


def _polygon_rings(geom: dict) -> list[list[np.ndarray]]:
    """GeoJSON Polygon/MultiPolygon -> list of polygons, each a list of rings (n, 2)."""
    t = geom.get("type")
    if t == "Polygon":
        return [[np.asarray(r, dtype=float)[:, :2] for r in geom["coordinates"]]]
    if t == "MultiPolygon":
        return [[np.asarray(r, dtype=float)[:, :2] for r in poly] for poly in geom["coordinates"]]
    return []


def load_ilc_floor(floor_dir: str | Path, res_m: float = 0.1, shops_walkable: bool = False) -> WalkableRaster:
    """Indoor Location Competition floor directory -> walkable raster with geo-reference.

    Reads ``floor_info.json`` (extent, m) and ``geojson_map.json`` (lon/lat polygons; the
    feature whose ``properties.type == "floor"`` is the outline, every other polygon a
    shop). See the module docstring for the geo-reference.
    """
    d = Path(floor_dir)
    info_p, geo_p = d / "floor_info.json", d / "geojson_map.json"
    for p in (info_p, geo_p):
        if not p.is_file():
            raise FloorFormatError(str(p), 0, "file", "missing (expected a competition floor directory)")
    try:
        info = json.loads(info_p.read_text())
        width_m = float(info["map_info"]["width"])
        height_m = float(info["map_info"]["height"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise FloorFormatError(str(info_p), 0, "map_info.width/height", f"unreadable: {exc}") from exc
    try:
        gj = json.loads(geo_p.read_text())
        feats = gj["features"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise FloorFormatError(str(geo_p), 0, "features", f"unreadable: {exc}") from exc
    floor_idx = [i for i, f in enumerate(feats) if (f.get("properties") or {}).get("type") == "floor"]
    if not floor_idx:
        raise FloorFormatError(str(geo_p), 0, "features[].properties.type", "no feature of type 'floor'")
    outline = _polygon_rings(feats[floor_idx[0]]["geometry"])
    pts = np.concatenate([r for poly in outline for r in poly])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if np.any(hi - lo <= 0):
        raise FloorFormatError(str(geo_p), 0, "floor geometry", "degenerate outline bounding box")
    georef = GeoRef(lon0_deg=float(lo[0]), lat0_deg=float(lo[1]),
                    dlon_deg_per_m=float((hi[0] - lo[0]) / width_m),
                    dlat_deg_per_m=float((hi[1] - lo[1]) / height_m))

    def to_m(polys: list[list[np.ndarray]]) -> list[list[np.ndarray]]:
        return [[georef.to_xy(r) for r in poly] for poly in polys]

    shops = [] if shops_walkable else [
        poly for i, f in enumerate(feats) if i not in floor_idx
        for poly in to_m(_polygon_rings(f.get("geometry") or {}))
    ]
    return raster_from_polygons(width_m, height_m, to_m(outline), shops, res_m=res_m, georef=georef)


def raster_from_image(path: str | Path, m_per_px: float, origin_xy_m: tuple[float, float] = (0.0, 0.0),
                      walkable_rgb: tuple[int, int, int] = (255, 255, 255), tol: int = 40) -> WalkableRaster:
    """Floor-plan image -> walkable raster: pixels within ``tol`` (per channel) of
    ``walkable_rgb`` are walkable; fully transparent pixels count as white. ``origin_xy_m``
    is the floor-frame position of the image's bottom-left corner; ``m_per_px`` its scale."""
    from PIL import Image  # pillow is a pinned dependency; imported here as only this reads images

    try:
        im = np.asarray(Image.open(path).convert("RGBA")).astype(np.int32)
    except OSError as exc:
        raise FloorFormatError(str(path), 0, "image", f"unreadable: {exc}") from exc
    if not m_per_px > 0:
        raise FloorFormatError(str(path), 0, "m_per_px", f"must be > 0, got {m_per_px}")
    rgb = np.where(im[..., 3:4] == 0, 255, im[..., :3])
    ok = np.all(np.abs(rgb - np.asarray(walkable_rgb)) <= tol, axis=-1)
    # Image rows go down; the raster's row 0 is the south edge.
    return WalkableRaster(walkable=ok[::-1].copy(), res_m=float(m_per_px),
                          x0_m=float(origin_xy_m[0]), y0_m=float(origin_xy_m[1]))
