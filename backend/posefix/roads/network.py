"""The road network of an OSM extract around a run: drivable ways as straight segments in a
local metric frame, with a uniform grid index for candidate search.

Frame: the equirectangular east/north plane of :func:`posefix.mapmatch.osm.local_georef`
(scale error < 0.1 % over a few km, far below a road's width). Each way of the drive profile
becomes its consecutive node pairs ``a -> b``; the grid (cell = ``CELL_M``) lists every
segment under each cell its bounding box covers, so the segments within
``RADIUS_M = RING x CELL_M`` of a point are among those of the (2 RING + 1)^2 cells around it.
The segments are also kept as flat coordinate arrays (``ax``, ``ay``, ``dx``, ``dy``,
``inv_len2``): gathering 1-D arrays is what a candidate search spends its time on.

Cache: reading the extract is most of a call's cost, and the same area is matched again and
again (every revision, every operator): :func:`road_network` keeps the last
``CACHE_SIZE`` networks, keyed by the extract's SHA-256 and the box snapped outwards (the
drivable-area cache's rules, :mod:`posefix.mapmatch.suggest`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from posefix.mapmatch.floorplan import GeoRef
from posefix.mapmatch.osm import local_georef, read_osm_ways
from posefix.mapmatch.suggest import NoWaysError, file_sha256, snap_bbox

__all__ = ["RoadNetwork", "road_network", "CELL_M", "RADIUS_M"]

CELL_M = 25.0  # grid cell
RING = 2  # cells searched around a point's own: every segment within RADIUS_M is among them
RADIUS_M = RING * CELL_M  # the largest candidate search radius
CACHE_SIZE = 8

_cache: OrderedDict = OrderedDict()
_lock = threading.Lock()


@dataclass(frozen=True)
class RoadNetwork:
    """Segments ``a_xy``/``b_xy`` (m, 2) metres in ``georef``'s frame, ``half_width_m`` (m,)
    of their way, and the grid index: ``cell_keys`` (sorted) with ``cell_start`` offsets into
    ``cell_segments``."""

    georef: GeoRef
    a_xy: np.ndarray
    b_xy: np.ndarray
    half_width_m: np.ndarray
    origin_xy: np.ndarray
    n_cols: int
    cell_keys: np.ndarray
    cell_start: np.ndarray
    cell_segments: np.ndarray
    ax: np.ndarray
    ay: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    inv_len2: np.ndarray

    @property
    def n_segments(self) -> int:
        return int(self.a_xy.shape[0])

    def cell_of(self, p_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ij = np.floor((np.asarray(p_xy) - self.origin_xy) / CELL_M).astype(np.int64)
        return ij[..., 0], ij[..., 1]

    def segments_near(self, p_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point row, segment) pairs: every segment listed in the cells within ``RING`` of each point's."""
        ci, cj = self.cell_of(p_xy)
        ring = np.arange(-RING, RING + 1)
        di, dj = np.meshgrid(ring, ring, indexing="ij")
        keys = ((cj[:, None] + dj.ravel()) * self.n_cols + (ci[:, None] + di.ravel())).ravel()
        rows = np.repeat(np.arange(len(ci)), ring.size**2)
        pos = np.searchsorted(self.cell_keys, keys)
        pos_c = np.minimum(pos, len(self.cell_keys) - 1)
        hit = self.cell_keys[pos_c] == keys
        starts, ends = self.cell_start[pos_c[hit]], self.cell_start[pos_c[hit] + 1]
        counts = ends - starts
        point = np.repeat(rows[hit], counts)
        # positions starts[i] .. ends[i]-1 for each hit, flattened without a Python loop
        offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        return point, self.cell_segments[np.repeat(starts, counts) + offsets]


def build_network(ways, box: tuple[float, float, float, float]) -> RoadNetwork:
    geo = local_georef(box[0], box[1])
    a, b, hw = [], [], []
    for way in ways:
        xy = geo.to_xy(way.lonlat_deg)
        keep = np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-3
        a.append(xy[:-1][keep])
        b.append(xy[1:][keep])
        hw.append(np.full(int(keep.sum()), way.width_m / 2.0))
    a_xy, b_xy, half = np.concatenate(a), np.concatenate(b), np.concatenate(hw)
    lo = np.minimum(a_xy, b_xy).min(axis=0) - (RING + 1) * CELL_M
    hi = np.maximum(a_xy, b_xy).max(axis=0) + (RING + 1) * CELL_M
    n_cols = int(np.ceil((hi[0] - lo[0]) / CELL_M)) + 1
    i0, j0 = np.floor((np.minimum(a_xy, b_xy) - lo) / CELL_M).astype(np.int64).T
    i1, j1 = np.floor((np.maximum(a_xy, b_xy) - lo) / CELL_M).astype(np.int64).T
    seg_ids, keys = [], []
    for s in range(len(a_xy)):  # once per network (cached); segments are short, few cells each
        ii, jj = np.meshgrid(np.arange(i0[s], i1[s] + 1), np.arange(j0[s], j1[s] + 1), indexing="ij")
        keys.append((jj * n_cols + ii).ravel())
        seg_ids.append(np.full(ii.size, s))
    keys_a, segs_a = np.concatenate(keys), np.concatenate(seg_ids)
    order = np.argsort(keys_a, kind="stable")
    keys_a, segs_a = keys_a[order], segs_a[order]
    cell_keys, first = np.unique(keys_a, return_index=True)
    d = b_xy - a_xy
    return RoadNetwork(georef=geo, a_xy=a_xy, b_xy=b_xy, half_width_m=half, origin_xy=lo, n_cols=n_cols,
                       cell_keys=cell_keys, cell_start=np.append(first, len(keys_a)), cell_segments=segs_a,
                       ax=a_xy[:, 0].copy(), ay=a_xy[:, 1].copy(), dx=d[:, 0].copy(), dy=d[:, 1].copy(),
                       inv_len2=1.0 / np.einsum("ij,ij->i", d, d))


def road_network(osm_path: str | Path, bbox: tuple[float, float, float, float]) -> RoadNetwork:
    """The drivable network of ``bbox`` (snapped outwards), cached (module docstring).

    Raises :class:`NoWaysError` naming the file when no drivable way is in the box.
    """
    box = snap_bbox(bbox)
    key = (file_sha256(osm_path), box)
    with _lock:
        hit = _cache.get(key)
        if hit is not None:
            _cache.move_to_end(key)
            return hit
    ways = read_osm_ways(osm_path, box, profile="drive")
    if not ways:
        raise NoWaysError(f"{osm_path}:0: field highway: no drive ways near the run")
    net = build_network(ways, box)
    with _lock:
        _cache[key] = net
        while len(_cache) > CACHE_SIZE:
            _cache.popitem(last=False)
    return net
