"""Map-matching suggestions for pose runs: match keyframes to the drivable area of OSM.

For a run's keyframes (lon/lat, orientation), we build a drivable-area graph around them
(:mod:`posefix.mapmatch.osm`, ways buffered by width, default 2 m cells), and match with
the same CRF as indoors:

* odometry: the displacement between consecutive keyframes (from the run's relative
  poses) with the heading of the body x axis from ``q_body_to_enu_wxyz``; a keyframe
  interval longer than one cell is split into equal sub-steps of at most one cell so the
  sparse one-cell transitions can follow it;
* position: each keyframe's reported position as a weak Gaussian state feature
  (``sigma_reported_m``, default 15 m), so the match stays near the run where the map
  is ambiguous (parallel streets);
* start: a Gaussian of the same width around the first keyframe.

The result gives each keyframe's matched position (lon, lat), how far it moved, and
``off_road``: the reported position is not on the drivable raster. Operators accept the
matched positions as a distinct, weaker kind of edit ("machine suggestion").

Cache: reading the extract, rasterising the buffered ways and building the graph is most
of a call's time, and the same run is matched again and again (every revision, every
operator). :func:`drivable_area` keeps the last ``DRIVABLE_CACHE_SIZE`` (raster, graph)
pairs in memory, keyed by the extract's SHA-256 (so a replaced file is never served
stale; the hash itself is memoised per path, size and modification time), the box
snapped outwards to ``BBOX_SNAP_DEG`` (so keyframes moved by an edit fall in the same
box), the cell size and the profile.
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from posefix.mapmatch.features import FeatureSigmas
from posefix.mapmatch.floorplan import FloorFormatError
from posefix.mapmatch.graph import build_graph
from posefix.mapmatch.model import Model
from posefix.mapmatch.osm import local_georef, raster_from_ways, read_osm_ways
from posefix.mapmatch.tracker import Tracker

__all__ = ["Suggestions", "suggest_for_run", "heading_from_quaternion_wxyz", "drivable_area", "drivable_cache_info"]

DRIVABLE_CACHE_SIZE = 8  # (raster, graph) pairs; a 10 min urban drive's is ~10 MB
BBOX_SNAP_DEG = 0.005  # ~0.5 km: boxes snapped outwards to this grid share a cache entry

_cache: OrderedDict = OrderedDict()
_hashes: dict[tuple, str] = {}
_lock = threading.Lock()
_stats = {"hits": 0, "misses": 0}


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's content, memoised per (path, size, mtime)."""
    st = os.stat(path)
    key = (str(Path(path).resolve()), st.st_size, st.st_mtime_ns)
    h = _hashes.get(key)
    if h is None:
        d = hashlib.sha256()
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                d.update(chunk)
        h = _hashes[key] = d.hexdigest()
    return h


def snap_bbox(bbox: tuple[float, float, float, float], snap_deg: float = BBOX_SNAP_DEG) -> tuple[float, ...]:
    """(minlon, minlat, maxlon, maxlat) rounded outwards to multiples of ``snap_deg``."""
    lo, la, hi_lo, hi_la = bbox
    return (float(np.floor(lo / snap_deg) * snap_deg), float(np.floor(la / snap_deg) * snap_deg),
            float(np.ceil(hi_lo / snap_deg) * snap_deg), float(np.ceil(hi_la / snap_deg) * snap_deg))


class NoWaysError(ValueError):
    """No way of the profile in the box (a ValueError naming the file, as every bad input)."""


def drivable_area(osm_path: str | Path, bbox: tuple[float, float, float, float], cell_m: float = 2.0,
                  profile: str = "drive"):
    """(raster, graph) of the ``profile`` ways in ``bbox`` (snapped outwards), cached (module docstring).

    Raises :class:`NoWaysError` naming the file when no way of the profile is in the box.
    """
    box = snap_bbox(bbox)
    key = (file_sha256(osm_path), box, float(cell_m), profile)
    with _lock:
        hit = _cache.get(key)
        if hit is not None:
            _cache.move_to_end(key)
            _stats["hits"] += 1
            return hit
    ways = read_osm_ways(osm_path, box, profile=profile)
    if not ways:
        raise NoWaysError(f"{osm_path}:0: field highway: no {profile} ways near the run")
    raster = raster_from_ways(ways, box, res_m=min(0.5, cell_m / 4.0))
    graph = build_graph(raster, cell_m=cell_m, reach_m=1.5 * cell_m, min_component_m2=25.0 * cell_m**2)
    with _lock:
        _stats["misses"] += 1
        _cache[key] = (raster, graph)
        while len(_cache) > DRIVABLE_CACHE_SIZE:
            _cache.popitem(last=False)
    return raster, graph


def drivable_cache_info(clear: bool = False) -> dict[str, int]:
    """``{"hits", "misses", "size"}`` of the drivable-area cache; ``clear`` empties it and the counters."""
    with _lock:
        info = dict(_stats, size=len(_cache))
        if clear:
            _cache.clear()
            _stats.update(hits=0, misses=0)
    return info


@dataclass(frozen=True)
class Suggestions:
    """Per keyframe (k,): ``index`` rows into the run, ``lonlat_deg`` (k, 2) matched,
    ``moved_m`` distance from the reported position, ``off_road`` reported position off the
    drivable area, ``sigma_m`` 1σ major axis of the match at that keyframe (m). ``n_vertices``
    of the graph used (road segments for the road matcher); ``matcher`` "grid" (this module)
    or "roads" (:mod:`posefix.roads`)."""

    index: np.ndarray
    lonlat_deg: np.ndarray
    moved_m: np.ndarray
    off_road: np.ndarray
    sigma_m: np.ndarray
    n_vertices: int
    matcher: str = "grid"


def heading_from_quaternion_wxyz(q: np.ndarray) -> np.ndarray:
    """Heading (n,) rad CCW from east of the body x axis, for body->ENU quaternions (n, 4) w,x,y,z."""
    w, x, y, z = np.asarray(q, dtype=float).T
    east = 1.0 - 2.0 * (y * y + z * z)
    north = 2.0 * (x * y + w * z)
    return np.arctan2(north, east)


def suggest_for_run(lon_deg: np.ndarray, lat_deg: np.ndarray, q_body_to_enu_wxyz: np.ndarray, osm_path: str | Path,
                    index: np.ndarray | None = None, cell_m: float = 2.0, margin_m: float = 100.0,
                    sigma_reported_m: float = 15.0, profile: str = "drive") -> Suggestions:
    """Match keyframes (rows ``index`` of the run, default all) to OSM; see the module docstring.

    ``lon_deg``, ``lat_deg`` (n,) and ``q_body_to_enu_wxyz`` (n, 4) are the run's columns
    (a :class:`posefix.core.run.PoseRun` has them under these names).
    """
    lon = np.asarray(lon_deg, dtype=float)
    lat = np.asarray(lat_deg, dtype=float)
    idx = np.arange(lon.size) if index is None else np.asarray(index, dtype=np.int64)
    if idx.size < 2:
        raise ValueError("need at least two keyframes to match")
    ll = np.column_stack([lon[idx], lat[idx]])
    # Bounding box with a margin, in degrees via the local scale.
    g0 = local_georef(float(ll[:, 0].min()), float(ll[:, 1].min()))
    pad_lon, pad_lat = margin_m * g0.dlon_deg_per_m, margin_m * g0.dlat_deg_per_m
    bbox = (float(ll[:, 0].min() - pad_lon), float(ll[:, 1].min() - pad_lat),
            float(ll[:, 0].max() + pad_lon), float(ll[:, 1].max() + pad_lat))
    if not Path(osm_path).is_file():
        raise FloorFormatError(str(osm_path), 0, "file", "no such OSM extract")
    try:
        raster, graph = drivable_area(osm_path, bbox, cell_m=cell_m, profile=profile)
    except NoWaysError:
        raise ValueError(f"{osm_path}:0: field highway: no {profile} ways within {margin_m} m of the run") from None
    geo = raster.georef
    p_rep = geo.to_xy(ll)

    heading = heading_from_quaternion_wxyz(np.asarray(q_body_to_enu_wxyz, dtype=float)[idx])
    dist = np.linalg.norm(np.diff(p_rep, axis=0), axis=1)
    # Odometry: relative-pose distance along the orientation's heading (mean of both ends).
    h_mid = np.arctan2(np.sin(heading[:-1]) + np.sin(heading[1:]), np.cos(heading[:-1]) + np.cos(heading[1:]))
    model = Model(graph=graph, weights={"f1": 1.0, "f2": 0.0, "f3": 1.0, "f4": 0.0},
                  sigmas=FeatureSigmas(len_m=0.5 * cell_m, heading_rad=np.deg2rad(10.0)))
    tr = Tracker(model, start_xy_m=tuple(p_rep[0]), start_sigma_m=sigma_reported_m, filtered=False,
                 wifi_corr_s=0.0)  # reported positions, not WiFi scans: no WiFi time-correlation discount
    cov = np.eye(2) * sigma_reported_m**2
    kf_step = [0]
    sig = [np.sqrt(float(np.trace(cov)) / 2.0)]
    for k in range(idx.size - 1):
        n_sub = max(1, int(np.ceil(dist[k] / cell_m)))
        step = dist[k] / n_sub * np.array([np.cos(h_mid[k]), np.sin(h_mid[k])])
        for j in range(n_sub):
            wifi_like = (p_rep[k + 1], cov) if j == n_sub - 1 else None
            tp = tr.step(step, t_ms=k, wifi=wifi_like, summarise=j == n_sub - 1)
        kf_step.append(len(tr.t_ms) - 1)
        sig.append(tp.summary.sigma_major_m)
    path = tr.best_path()
    p_match = graph.p_xy_m[path[np.asarray(kf_step)]]
    return Suggestions(
        index=idx,
        lonlat_deg=geo.to_lonlat(p_match),
        moved_m=np.linalg.norm(p_match - p_rep, axis=1),
        off_road=~raster.is_walkable(p_rep),
        sigma_m=np.asarray(sig),
        n_vertices=graph.n_vertices,
    )
