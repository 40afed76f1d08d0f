"""OpenStreetMap extracts to a drivable (or walkable) raster: ways buffered by their width.

Reads ``highway=*`` ways from a ``.osm.pbf`` with pyosmium (imported lazily: only this
reader needs it). Each way is kept when its class is in the profile, and buffered by half
its width: the ``width`` tag in metres when it parses, else ``lanes`` × 3.25 m, else the
class default below (typical carriageway widths; a footway 2.5 m).

Frame: a local east/north plane in metres around ``origin`` (lon, lat), by the
equirectangular map ``x = (lon - lon0)·cos(lat0)·πR/180``, ``y = (lat - lat0)·πR/180``
(R = 6 371 008.8 m), i.e. an axis-aligned :class:`GeoRef`. Over a few kilometres its scale
error is below 0.1 %, far under a road's width; the raster's origin is the box's
south-west corner.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import distance_transform_edt

from posefix.mapmatch.floorplan import FloorFormatError, GeoRef, WalkableRaster

__all__ = ["DRIVE_WIDTH_M", "WALK_WIDTH_M", "OsmWay", "read_osm_ways", "raster_from_ways", "local_georef"]

EARTH_R_M = 6_371_008.8
LANE_M = 3.25

DRIVE_WIDTH_M = {
    "motorway": 14.0, "trunk": 12.0, "primary": 10.0, "secondary": 8.0, "tertiary": 7.0,
    "motorway_link": 6.0, "trunk_link": 6.0, "primary_link": 6.0, "secondary_link": 6.0,
    "tertiary_link": 6.0, "unclassified": 6.0, "residential": 6.0, "living_street": 5.0,
    "service": 4.0, "road": 6.0,
}
WALK_WIDTH_M = {
    "footway": 2.5, "pedestrian": 6.0, "path": 2.0, "steps": 2.0, "cycleway": 2.5, "living_street": 5.0,
    "residential": 6.0, "service": 4.0, "unclassified": 6.0, "tertiary": 7.0, "secondary": 8.0,
    "primary": 10.0, "track": 3.0,
}


@dataclass(frozen=True)
class OsmWay:
    """One highway way: ``lonlat_deg`` (n, 2), its class and buffer width (m)."""

    way_id: int
    highway: str
    width_m: float
    lonlat_deg: np.ndarray


def _width(tags, highway: str, defaults: dict[str, float]) -> float:
    w = tags.get("width")
    if w:
        try:
            v = float(w.replace("m", "").strip())
            if 0.5 <= v <= 60.0:
                return v
        except ValueError:
            pass
    lanes = tags.get("lanes")
    if lanes:
        try:
            return max(1, int(lanes)) * LANE_M
        except ValueError:
            pass
    return defaults[highway]


def read_osm_ways(path: str | Path, bbox_lonlat: tuple[float, float, float, float] | None = None,
                  profile: str = "drive") -> list[OsmWay]:
    """Highway ways of ``profile`` ("drive" or "walk") touching ``bbox`` (minlon, minlat, maxlon, maxlat)."""
    import osmium  # pinned dependency; lazily imported so the numerical core does not need it

    defaults = DRIVE_WIDTH_M if profile == "drive" else WALK_WIDTH_M if profile == "walk" else None
    if defaults is None:
        raise ValueError(f"profile must be 'drive' or 'walk', got {profile!r}")
    p = Path(path)
    if not p.is_file():
        raise FloorFormatError(str(p), 0, "file", "no such OSM extract")
    ways: list[OsmWay] = []
    try:
        fp = osmium.FileProcessor(str(p)).with_locations().with_filter(osmium.filter.KeyFilter("highway"))
        for obj in fp:
            if not obj.is_way():
                continue
            hw = obj.tags.get("highway")
            if hw not in defaults:
                continue
            try:
                pts = np.array([(n.lon, n.lat) for n in obj.nodes], dtype=float)
            except osmium.InvalidLocationError:
                continue
            if pts.shape[0] < 2:
                continue
            if bbox_lonlat is not None:
                lo, la, hi_lo, hi_la = bbox_lonlat
                if (pts[:, 0].max() < lo or pts[:, 0].min() > hi_lo or pts[:, 1].max() < la or pts[:, 1].min() > hi_la):
                    continue
            ways.append(OsmWay(way_id=int(obj.id), highway=hw, width_m=_width(obj.tags, hw, defaults), lonlat_deg=pts))
    except RuntimeError as exc:
        raise FloorFormatError(str(p), 0, "pbf", f"unreadable OSM extract: {exc}") from exc
    return ways


def local_georef(lon0_deg: float, lat0_deg: float) -> GeoRef:
    """Equirectangular metres around (lon0, lat0) (module docstring)."""
    m_per_deg = np.pi * EARTH_R_M / 180.0
    return GeoRef(lon0_deg=lon0_deg, lat0_deg=lat0_deg,
                  dlon_deg_per_m=1.0 / (m_per_deg * np.cos(np.radians(lat0_deg))), dlat_deg_per_m=1.0 / m_per_deg)


def raster_from_ways(ways: list[OsmWay], bbox_lonlat: tuple[float, float, float, float], res_m: float = 0.5) -> WalkableRaster:
    """Drivable raster over ``bbox``: every pixel within half a way's width of its centre line.

    Centre lines are sampled every res/2 into one mask per distinct width; a Euclidean
    distance transform of each mask, thresholded at half that width, is the buffer.
    """
    lo, la, hi_lo, hi_la = bbox_lonlat
    geo = local_georef(lo, la)
    ne = geo.to_xy(np.array([[hi_lo, hi_la]]))[0]
    h, w = int(np.ceil(ne[1] / res_m)), int(np.ceil(ne[0] / res_m))
    if h <= 0 or w <= 0:
        raise ValueError(f"empty bounding box {bbox_lonlat}")
    if h * w > 40_000_000:
        raise ValueError(f"area too large for a {res_m} m raster ({w} x {h} px); use a smaller box or coarser res_m")
    out = np.zeros((h, w), dtype=bool)
    segs: dict[float, list[np.ndarray]] = {}
    for way in ways:
        xy = geo.to_xy(way.lonlat_deg)
        # Widths rounded up to whole metres: fewer distance transforms, never narrower.
        segs.setdefault(float(np.ceil(way.width_m)), []).append(np.stack([xy[:-1], xy[1:]], axis=1))
    by_width: dict[float, np.ndarray] = {}
    for width, parts in segs.items():
        seg = np.concatenate(parts)  # (m, 2, 2)
        a, d = seg[:, 0], seg[:, 1] - seg[:, 0]
        n = np.ceil(np.linalg.norm(d, axis=1) / (0.5 * res_m)).astype(np.int64) + 1
        idx = np.repeat(np.arange(seg.shape[0]), n)
        s = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(np.maximum(n - 1, 1), n)
        p = a[idx] + s[:, None] * d[idx]
        c = np.floor(p[:, 0] / res_m).astype(np.int64)
        r = np.floor(p[:, 1] / res_m).astype(np.int64)
        ok = (c >= 0) & (c < w) & (r >= 0) & (r < h)
        m = np.zeros((h, w), dtype=bool)
        m[r[ok], c[ok]] = True
        by_width[width] = m
    for width, m in by_width.items():
        rows, cols = np.nonzero(m)
        if rows.size == 0:
            continue
        # Only the box around this class's centre lines (plus the buffer) needs the EDT.
        pad = int(np.ceil(width / 2.0 / res_m)) + 1
        r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, h)
        c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, w)
        sub = m[r0:r1, c0:c1]
        out[r0:r1, c0:c1] |= distance_transform_edt(~sub) * res_m <= width / 2.0
    return WalkableRaster(walkable=out, res_m=res_m, georef=geo)
