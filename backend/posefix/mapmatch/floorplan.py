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
from dataclasses import dataclass, field
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
    "read_ilc_floor",
    "find_outline",
    "FloorReport",
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
    """GeoJSON Polygon/MultiPolygon -> list of polygons, each a list of rings (n, 2).
    Raises ValueError/TypeError/IndexError on malformed coordinates (the caller reports them)."""
    t = geom.get("type")
    if t == "Polygon":
        polys = [geom["coordinates"]]
    elif t == "MultiPolygon":
        polys = geom["coordinates"]
    else:
        return []
    out = [[np.asarray(r, dtype=float)[:, :2] for r in poly] for poly in polys]
    for poly in out:
        for r in poly:
            if r.ndim != 2 or r.shape[0] < 3 or not np.all(np.isfinite(r)):
                raise ValueError("a ring needs 3 or more finite [lon, lat] points")
    return out


def _ring_area(r: np.ndarray) -> float:
    x, y = r[:, 0], r[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


@dataclass
class FloorReport:
    """What a floor reader used and what it skipped (one line each), for the user to read."""

    outline: str = ""
    used: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        return [f"outline: {self.outline}"] + [f"used: {u}" for u in self.used] + [f"skipped: {s}" for s in self.skipped]


@dataclass(frozen=True)
class _Feature:
    index: int
    keys: frozenset
    polys: list  # list of polygons, each a list of rings (n, 2) lon/lat
    area: float  # outer rings' area, deg²
    box: tuple[float, float, float, float]  # lon_min, lat_min, lon_max, lat_max


def _read_features(feats: list, file: str, report: FloorReport) -> list[_Feature]:
    """Polygon features of a GeoJSON FeatureCollection; everything else is reported as skipped."""
    out, kinds = [], {}
    for i, f in enumerate(feats):
        geom = f.get("geometry") if isinstance(f, dict) else None
        kind = geom.get("type") if isinstance(geom, dict) else None
        if kind not in ("Polygon", "MultiPolygon"):
            kinds[str(kind)] = kinds.get(str(kind), 0) + 1
            continue
        try:
            polys = _polygon_rings(geom)
        except (ValueError, TypeError, IndexError, KeyError) as exc:
            report.skipped.append(f"{file}: features[{i}].geometry: unusable ({exc})")
            continue
        pts = np.concatenate([r for poly in polys for r in poly])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        props = f.get("properties") if isinstance(f.get("properties"), dict) else {}
        out.append(_Feature(i, frozenset(props), polys, sum(_ring_area(p[0]) for p in polys),
                            (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))))
    for kind, n in sorted(kinds.items()):
        report.skipped.append(f"{file}: {n} feature(s) with geometry {kind} (only polygons describe areas)")
    return out


def _covers(outer: _Feature, others: list[_Feature], slack: float = 1e-6) -> float:
    """Share of ``others`` whose bounding-box centre lies in ``outer``'s bounding box."""
    if not others:
        return 1.0
    x0, y0, x1, y1 = outer.box
    c = np.array([[(o.box[0] + o.box[2]) / 2, (o.box[1] + o.box[3]) / 2] for o in others])
    return float(np.mean((c[:, 0] >= x0 - slack) & (c[:, 0] <= x1 + slack) & (c[:, 1] >= y0 - slack) & (c[:, 1] <= y1 + slack)))


def find_outline(feats: list, polys: list[_Feature]) -> tuple[_Feature | None, str]:
    """The floor's outline among the polygon features, and why it was chosen.

    In order: a feature marked ``type``/``category`` ``floor``; the one feature whose
    property names differ from the shops' (the competition's site2 layout: the outline has
    ``floor``, ``store_id``, ``poi_no``..., the shops ``id``, ``name``, ``display``...); the
    largest polygon. A candidate must be the largest or near it (≥ half the largest area)
    and hold ≥ 90 % of the other features in its bounding box: an outline contains the floor.
    """
    def props(p: _Feature) -> dict:
        pr = feats[p.index].get("properties")
        return pr if isinstance(pr, dict) else {}

    def plausible(p: _Feature) -> bool:
        rest = [o for o in polys if o is not p]
        return p.area >= 0.5 * max(o.area for o in polys) and _covers(p, rest) >= 0.9

    if not polys:
        return None, "no polygon feature"
    marked = [p for p in polys if "floor" in (str(props(p).get("type", "")).lower(), str(props(p).get("category", "")).lower())]
    for p in marked:
        if plausible(p):
            return p, f"features[{p.index}] (properties type/category 'floor')"
    sigs: dict[frozenset, list[_Feature]] = {}
    for p in polys:
        sigs.setdefault(p.keys, []).append(p)
    if len(polys) >= 3:
        common = max(sigs.values(), key=len)
        odd = [p for p in polys if len(sigs[p.keys]) == 1 and len(common) >= 0.5 * len(polys)]
        odd = [p for p in odd if plausible(p)]
        if len(odd) == 1:
            p = odd[0]
            return p, f"features[{p.index}] (the one feature whose properties differ from the shops': {sorted(p.keys)})"
    big = max(polys, key=lambda p: p.area)
    if len(polys) >= 3 and plausible(big):
        return big, f"features[{big.index}] (the largest polygon, holding the others)"
    return None, "no polygon encloses the others (no outline feature)"


def _georef_from_box(box: tuple[float, float, float, float], width_m: float, height_m: float) -> GeoRef:
    return GeoRef(lon0_deg=box[0], lat0_deg=box[1], dlon_deg_per_m=(box[2] - box[0]) / width_m,
                  dlat_deg_per_m=(box[3] - box[1]) / height_m)


def _read_json(path: Path, field_name: str):
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FloorFormatError(str(path), getattr(exc, "lineno", 0), field_name, f"not JSON ({exc})") from None


def read_ilc_floor(floor_dir: str | Path, res_m: float = 0.1,
                   shops_walkable: bool = False) -> tuple["WalkableRaster", FloorReport]:
    """Indoor Location Competition floor directory -> (walkable raster with geo-reference, report).

    Reads ``floor_info.json`` (extent, m) and ``geojson_map.json`` (lon/lat polygons). The
    outline is found by what it is (:func:`find_outline`); every other polygon is a shop.
    Without a usable outline the floor image is read instead (opaque near-white pixels are
    corridors), geo-referenced by the bounding box of all polygons when there are any.
    Raises :class:`FloorFormatError` only when nothing usable is left.
    """
    d = Path(floor_dir)
    info_p, geo_p, img_p = d / "floor_info.json", d / "geojson_map.json", d / "floor_image.png"
    if not info_p.is_file():
        raise FloorFormatError(str(info_p), 0, "file", "missing (expected a competition floor directory)")
    info = _read_json(info_p, "map_info")
    try:
        width_m = float(info["map_info"]["width"])
        height_m = float(info["map_info"]["height"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FloorFormatError(str(info_p), 0, "map_info.width/height", f"unreadable: {exc}") from None
    if not (np.isfinite(width_m) and np.isfinite(height_m) and width_m > 0 and height_m > 0):
        raise FloorFormatError(str(info_p), 0, "map_info.width/height", f"must be positive, got {width_m} x {height_m}")
    report = FloorReport()
    report.used.append(f"{info_p.name}: extent {width_m:.1f} x {height_m:.1f} m")
    polys: list[_Feature] = []
    feats: list = []
    if geo_p.is_file():
        try:
            gj = _read_json(geo_p, "features")
            feats = gj.get("features") if isinstance(gj, dict) else None
            if not isinstance(feats, list):
                raise FloorFormatError(str(geo_p), 0, "features", "expected a FeatureCollection")
            polys = _read_features(feats, geo_p.name, report)
        except FloorFormatError as exc:
            report.skipped.append(str(exc))
    else:
        report.skipped.append(f"{geo_p.name}: missing")
    outline, why = find_outline(feats, polys)
    if outline is not None:
        lo0, la0, lo1, la1 = outline.box
        if not (lo1 > lo0 and la1 > la0):
            outline, why = None, f"features[{outline.index}]: degenerate outline bounding box"
    if outline is None:
        if polys:
            report.skipped.append(f"{geo_p.name}: {why}; its {len(polys)} polygon(s) give only the geo-reference")
        return _image_fallback(img_p, geo_p, width_m, height_m, res_m, polys, why, report)
    georef = _georef_from_box(outline.box, width_m, height_m)
    report.outline = f"{geo_p.name} {why}"

    def to_m(p: list[list[np.ndarray]]) -> list[list[np.ndarray]]:
        return [[georef.to_xy(r) for r in poly] for poly in p]

    shops = [p for p in polys if p is not outline]
    inside = [p for p in shops if _covers(outline, [p]) == 1.0]
    if len(inside) < len(shops):
        report.skipped.append(f"{geo_p.name}: {len(shops) - len(inside)} polygon(s) outside the outline")
    blocked = [] if shops_walkable else [poly for p in inside for poly in to_m(p.polys)]
    report.used.append(f"{geo_p.name}: {len(inside)} shop polygon(s) " + ("walkable (no door data)" if shops_walkable else "blocked"))
    raster = raster_from_polygons(width_m, height_m, to_m(outline.polys), blocked, res_m=res_m, georef=georef)
    if not raster.walkable.any():
        raise FloorFormatError(str(geo_p), 0, "features", "no walkable area inside the outline")
    return raster, report


def _image_fallback(img_p: Path, geo_p: Path, width_m: float, height_m: float, res_m: float,
                    polys: list[_Feature], why: str, report: FloorReport) -> tuple["WalkableRaster", FloorReport]:
    """The floor image as the walkable map when the GeoJSON has no outline (see read_ilc_floor)."""
    if not img_p.is_file():
        raise FloorFormatError(str(geo_p), 0, "features", f"{why}, and no {img_p.name} to fall back to")
    img = competition_image_raster(img_p, width_m)
    georef = None
    if polys:
        box = (min(p.box[0] for p in polys), min(p.box[1] for p in polys),
               max(p.box[2] for p in polys), max(p.box[3] for p in polys))
        if box[2] > box[0] and box[3] > box[1]:
            georef = _georef_from_box(box, width_m, height_m)
    report.outline = f"{img_p.name} (corridors: the clear or white pixels inside the building; {why})"
    report.used.append(f"{img_p.name}: {img.walkable.shape[1]} x {img.walkable.shape[0]} px at {img.res_m:.3f} m/px")
    if georef is None:
        report.skipped.append("geo-reference: no polygon to place the floor on the globe (lat/lon left empty)")
    else:
        report.used.append(f"{geo_p.name}: bounding box of all polygons as the geo-reference (approximate)")
    if not img.walkable.any():
        raise FloorFormatError(str(img_p), 0, "image", f"{why}, and the image shows no corridor inside a building")
    # Resample to the requested resolution so the graph builder sees the usual raster.
    shape = (int(np.ceil(height_m / res_m)), int(np.ceil(width_m / res_m)))
    yy, xx = (np.arange(shape[0]) + 0.5) * res_m, (np.arange(shape[1]) + 0.5) * res_m
    pts = np.stack(np.meshgrid(xx, yy), axis=-1)
    return WalkableRaster(walkable=img.is_walkable(pts), res_m=res_m, georef=georef), report


def competition_image_raster(path: Path, width_m: float, closing_m: float = 3.0) -> WalkableRaster:
    """A competition floor image -> walkable raster (its width is ``width_m``).

    The images draw shops and walls opaque and leave corridors clear (site2) or white; the
    outside is clear too. The building is the opaque drawing closed over gaps up to
    ``closing_m`` (entrances, thin corridors between shop rows) with its holes filled; the
    corridors are the clear or near-white pixels inside it.
    """
    from PIL import Image
    from scipy import ndimage

    try:
        with Image.open(path) as im:
            px = np.asarray(im.convert("RGBA")).astype(np.int32)
    except OSError as exc:
        raise FloorFormatError(str(path), 0, "image", f"unreadable: {exc}") from None
    m_per_px = width_m / px.shape[1]
    opaque = px[..., 3] >= 128
    white = opaque & np.all(px[..., :3] >= 243, axis=-1)
    r = max(1, int(round(closing_m / 2 / m_per_px)))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disk = xx**2 + yy**2 <= r * r
    solid = opaque & ~white
    building = ndimage.binary_fill_holes(ndimage.binary_closing(np.pad(solid, r), structure=disk))[r:-r, r:-r]
    walkable = building & ~solid
    # Image rows go down; the raster's row 0 is the south edge.
    return WalkableRaster(walkable=walkable[::-1].copy(), res_m=m_per_px)


def load_ilc_floor(floor_dir: str | Path, res_m: float = 0.1, shops_walkable: bool = False) -> WalkableRaster:
    """:func:`read_ilc_floor` without the report."""
    return read_ilc_floor(floor_dir, res_m=res_m, shops_walkable=shops_walkable)[0]


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
