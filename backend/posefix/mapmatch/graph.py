"""Grid graph of walkable cells, and the sparse step transitions the CRF uses.

The floor is cut into square cells of ``cell_m`` (default 0.8 m). A cell is a vertex when
at least half of a 4×4 grid of sample points inside it is walkable. Two vertices that
share a side or a corner are joined by an edge when the straight segment between their
centres stays on walkable raster pixels (sampled every ``res/2``), so a wall between them
blocks it. Components of the edge graph smaller than ``min_component_m2`` are dropped
(closed rooms, specks between polygons): those cells are not reachable.

Step transitions: a step may move from vertex u to any vertex v = u + o for an integer
offset o with ``|o|·cell_m <= reach_m`` (o = 0 included: a step shorter than a cell can
end in the same cell), again only with line of sight. Because the grid is regular, the
transition feature of a step depends only on the offset, so transitions are stored as
one bit per (vertex, offset): ``trans_mask[u] & (1 << k)``. From these we derive the
``(V, K)`` tables ``succ[u, k] = v`` and ``pred[v, k] = u`` (-1: no transition), which
make Viterbi and forward-backward dense, vectorised gathers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from posefix.mapmatch.floorplan import GeoRef, WalkableRaster

__all__ = ["GridGraph", "build_graph", "transition_offsets"]

_NEIGHBOURS_8 = np.array([(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)])


def transition_offsets(cell_m: float, reach_m: float) -> np.ndarray:
    """Integer offsets (K, 2) = (dcol, drow) with ``|o|·cell_m <= reach_m``; row 0 is (0, 0).

    At least the 8 neighbours are always included so that any graph edge is a transition.
    """
    r = max(1, int(np.floor(reach_m / cell_m)))
    g = np.array([(dx, dy) for dy in range(-r, r + 1) for dx in range(-r, r + 1)])
    keep = (np.hypot(g[:, 0], g[:, 1]) * cell_m <= reach_m + 1e-9) | (np.abs(g).max(axis=1) <= 1)
    g = g[keep]
    order = np.lexsort((np.arctan2(g[:, 1], g[:, 0]), np.hypot(g[:, 0], g[:, 1])))
    return g[order].astype(np.int64)


@dataclass
class GridGraph:
    """Vertices of a regular grid and their allowed step transitions.

    ``ij`` (V, 2) int: (col, row) of each vertex; centre ``p_xy_m = (x0 + (col+½)·cell,
    y0 + (row+½)·cell)``. ``indptr``/``indices``: the 8-neighbour edge graph in CSR.
    ``offsets`` (K, 2) int and ``trans_mask`` (V,) uint32 (bit k: u -> u + offsets[k] allowed).
    """

    cell_m: float
    x0_m: float
    y0_m: float
    shape: tuple[int, int]  # (rows, cols) of the cell grid
    ij: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    offsets: np.ndarray
    trans_mask: np.ndarray
    georef: GeoRef | None = None
    _succ: np.ndarray | None = field(default=None, repr=False)
    _pred: np.ndarray | None = field(default=None, repr=False)
    _pred_t: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_vertices(self) -> int:
        return int(self.ij.shape[0])

    @property
    def p_xy_m(self) -> np.ndarray:
        """Vertex centres (V, 2), metres, floor frame."""
        return np.column_stack([self.x0_m + (self.ij[:, 0] + 0.5) * self.cell_m,
                                self.y0_m + (self.ij[:, 1] + 0.5) * self.cell_m])

    @property
    def offsets_m(self) -> np.ndarray:
        """Transition displacement vectors (K, 2), metres."""
        return self.offsets.astype(float) * self.cell_m

    def index_grid(self) -> np.ndarray:
        """(rows, cols) int32 grid of vertex indices, -1 where there is no vertex."""
        g = np.full(self.shape, -1, dtype=np.int32)
        g[self.ij[:, 1], self.ij[:, 0]] = np.arange(self.n_vertices, dtype=np.int32)
        return g

    @property
    def succ(self) -> np.ndarray:
        """(V, K) int32: vertex reached from u by offset k, or -1."""
        if self._succ is None:
            self._succ, self._pred = self._tables()
        return self._succ

    @property
    def pred(self) -> np.ndarray:
        """(V, K) int32: vertex u with u + offset k = v, or -1."""
        if self._pred is None:
            self._succ, self._pred = self._tables()
        return self._pred

    @property
    def pred_t(self) -> np.ndarray:
        """(K, V) int32 contiguous transpose of :attr:`pred` (one offset per row, for speed)."""
        if self._pred_t is None:
            self._pred_t = np.ascontiguousarray(self.pred.T)
        return self._pred_t

    def _tables(self) -> tuple[np.ndarray, np.ndarray]:
        grid = self.index_grid()
        rows, cols = self.shape
        v_n, k_n = self.n_vertices, self.offsets.shape[0]
        succ = np.full((v_n, k_n), -1, dtype=np.int32)
        pred = np.full((v_n, k_n), -1, dtype=np.int32)
        for k, (dc, dr) in enumerate(self.offsets):
            ok = (self.trans_mask >> np.uint32(k)) & np.uint32(1)
            u = np.nonzero(ok)[0]
            c, r = self.ij[u, 0] + dc, self.ij[u, 1] + dr
            inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
            u, c, r = u[inside], c[inside], r[inside]
            v = grid[r, c]
            good = v >= 0
            succ[u[good], k] = v[good]
            pred[v[good], k] = u[good]
        return succ, pred

    def nearest_vertex(self, p_xy_m: np.ndarray) -> np.ndarray:
        """Index of the vertex nearest to each point (n, 2) (brute force over V; fine for few points)."""
        p = np.atleast_2d(np.asarray(p_xy_m, dtype=float))
        c = self.p_xy_m
        return np.array([int(np.argmin(np.sum((c - q) ** 2, axis=1))) for q in p])

    def nbytes(self) -> int:
        return int(self.ij.nbytes + self.indptr.nbytes + self.indices.nbytes + self.trans_mask.nbytes)


def _line_of_sight(raster: WalkableRaster, a_xy_m: np.ndarray, b_xy_m: np.ndarray) -> np.ndarray:
    """For segments a -> b (n, 2) each: True when every sample along it (every res/2) is walkable."""
    length = float(np.max(np.linalg.norm(b_xy_m - a_xy_m, axis=1), initial=0.0))
    n = max(2, int(np.ceil(length / (0.5 * raster.res_m))) + 1)
    s = np.linspace(0.0, 1.0, n)
    ok = np.ones(a_xy_m.shape[0], dtype=bool)
    for si in s:  # loop over samples keeps memory at O(n_segments)
        ok &= raster.is_walkable(a_xy_m + si * (b_xy_m - a_xy_m))
    return ok


def build_graph(raster: WalkableRaster, cell_m: float = 0.8, reach_m: float = 1.7,
                min_component_m2: float = 20.0) -> GridGraph:
    """Cut ``raster`` into ``cell_m`` cells and build the :class:`GridGraph` (module docstring).

    ``reach_m``: the longest single-step transition (m); ``min_component_m2``: connected
    components with less walkable area are removed as unreachable.
    """
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    if reach_m < cell_m:
        raise ValueError(f"reach_m ({reach_m}) must be at least cell_m ({cell_m})")
    cols = int(np.floor(raster.width_m / cell_m))
    rows = int(np.floor(raster.height_m / cell_m))
    x0, y0 = raster.x0_m, raster.y0_m
    # Walkable fraction of each cell from a 4x4 grid of sample points.
    sub = (np.arange(4) + 0.5) / 4.0
    cc, rr = np.meshgrid(np.arange(cols), np.arange(rows))
    frac = np.zeros((rows, cols))
    for sx in sub:
        for sy in sub:
            p = np.stack([x0 + (cc + sx) * cell_m, y0 + (rr + sy) * cell_m], axis=-1)
            frac += raster.is_walkable(p)
    frac /= sub.size**2
    r_idx, c_idx = np.nonzero(frac >= 0.5)
    ij = np.column_stack([c_idx, r_idx]).astype(np.int64)
    grid = np.full((rows, cols), -1, dtype=np.int64)
    grid[r_idx, c_idx] = np.arange(ij.shape[0])
    centres = np.column_stack([x0 + (ij[:, 0] + 0.5) * cell_m, y0 + (ij[:, 1] + 0.5) * cell_m])

    def pairs(offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c, r = ij[:, 0] + offset[0], ij[:, 1] + offset[1]
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        u = np.nonzero(inside)[0]
        v = grid[r[inside], c[inside]]
        u, v = u[v >= 0], v[v >= 0]
        ok = _line_of_sight(raster, centres[u], centres[v])
        return u[ok], v[ok]

    us, vs = [], []
    for o in _NEIGHBOURS_8:
        u, v = pairs(o)
        us.append(u)
        vs.append(v)
    u_all, v_all = np.concatenate(us), np.concatenate(vs)
    n = ij.shape[0]
    adj = csr_matrix((np.ones(u_all.size, dtype=np.int8), (u_all, v_all)), shape=(n, n))
    n_comp, labels = connected_components(adj, directed=False)
    sizes = np.bincount(labels, minlength=n_comp) * cell_m**2
    keep = sizes[labels] >= min_component_m2
    if not np.any(keep):
        raise ValueError("no walkable component of at least "
                         f"{min_component_m2} m² at {cell_m} m cells: check the map and its scale")
    new_id = np.full(n, -1, dtype=np.int64)
    new_id[keep] = np.arange(int(keep.sum()))
    ij_k = ij[keep]
    adj_k = adj[keep][:, keep].tocsr()
    adj_k.sort_indices()

    offsets = transition_offsets(cell_m, reach_m)
    if offsets.shape[0] > 32:
        raise ValueError(f"reach_m/cell_m = {reach_m / cell_m:.1f} gives {offsets.shape[0]} offsets; at most 32")
    grid_k = np.full((rows, cols), -1, dtype=np.int64)
    grid_k[ij_k[:, 1], ij_k[:, 0]] = np.arange(ij_k.shape[0])
    centres_k = centres[keep]
    mask = np.zeros(ij_k.shape[0], dtype=np.uint32)
    for k, o in enumerate(offsets):
        if not o.any():
            mask |= np.uint32(1)
            continue
        c, r = ij_k[:, 0] + o[0], ij_k[:, 1] + o[1]
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        u = np.nonzero(inside)[0]
        v = grid_k[r[inside], c[inside]]
        u, v = u[v >= 0], v[v >= 0]
        ok = _line_of_sight(raster, centres_k[u], centres_k[v])
        mask[u[ok]] |= np.uint32(1 << k)
    return GridGraph(cell_m=float(cell_m), x0_m=float(x0), y0_m=float(y0), shape=(rows, cols),
                     ij=ij_k.astype(np.int32), indptr=adj_k.indptr.astype(np.int32),
                     indices=adj_k.indices.astype(np.int32), offsets=offsets, trans_mask=mask,
                     georef=raster.georef)
