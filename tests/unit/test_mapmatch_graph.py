"""Graph construction on small hand-drawn maps: walls block edges, unreachable cells go."""

import numpy as np
import pytest

from posefix.mapmatch.floorplan import fill_polygons, raster_from_polygons
from posefix.mapmatch.graph import build_graph, transition_offsets


def rect(x0, y0, x1, y1):
    return [np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)]


def vid(g, col, row):
    hit = np.nonzero((g.ij[:, 0] == col) & (g.ij[:, 1] == row))[0]
    return int(hit[0]) if hit.size else -1


def neighbours(g, v):
    return set(g.indices[g.indptr[v]:g.indptr[v + 1]].tolist())


def test_wall_blocks_edges_and_gap_lets_through():
    # 6 m x 4 m room, wall at x = 3 from y = 0 to 3: the top row (y 3..4) is the door.
    wall = np.array([[[3.0, 0.0], [3.0, 3.0]]])
    r = raster_from_polygons(6.0, 4.0, [rect(0, 0, 6, 4)], walls=wall, res_m=0.05)
    g = build_graph(r, cell_m=1.0, reach_m=1.0, min_component_m2=1.0)
    assert g.n_vertices == 24
    left, right = vid(g, 2, 0), vid(g, 3, 0)
    assert right not in neighbours(g, left)
    assert vid(g, 3, 1) not in neighbours(g, vid(g, 2, 2))  # diagonal across the wall
    assert vid(g, 3, 3) in neighbours(g, vid(g, 2, 3))  # through the door
    # Step transitions obey the same wall: no move from (2,0) by +1 column.
    k = [i for i, o in enumerate(g.offsets) if tuple(o) == (1, 0)][0]
    assert g.succ[left, k] == -1
    assert g.succ[vid(g, 2, 3), k] == vid(g, 3, 3)
    assert g.pred[vid(g, 3, 3), k] == vid(g, 2, 3)


def test_blocked_polygon_removes_cells_and_unreachable_component_is_dropped():
    # Main room 5 x 3 with a pillar; a closed 1 x 1 closet far away (not connected).
    walk = [rect(0, 0, 5, 3), rect(8, 0, 9, 1)]
    pillar = [rect(2, 1, 3, 2)]
    r = raster_from_polygons(10.0, 3.0, walk, blocked_polys=pillar, res_m=0.05)
    g = build_graph(r, cell_m=1.0, reach_m=1.5, min_component_m2=2.0)
    assert vid(g, 2, 1) == -1  # the pillar
    assert vid(g, 8, 0) == -1  # the closet: walkable but unreachable
    assert g.n_vertices == 14
    # Every remaining vertex reaches every other one through edges.
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components
    a = csr_matrix((np.ones(g.indices.size), g.indices, g.indptr), shape=(g.n_vertices,) * 2)
    assert connected_components(a, directed=False)[0] == 1


def test_fill_polygon_even_odd_hole():
    outer = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], dtype=float)
    hole = np.array([[1, 1], [3, 1], [3, 3], [1, 3]], dtype=float)
    m = fill_polygons((4, 4), 1.0, 0.0, 0.0, [outer, hole])
    assert m.sum() == 12 and not m[1:3, 1:3].any()


def test_transition_offsets_reach():
    o = transition_offsets(0.8, 1.7)
    assert tuple(o[0]) == (0, 0)
    assert o.shape[0] == 13  # self, 8 neighbours, 4 two-cell straight moves
    assert np.all(np.hypot(o[:, 0], o[:, 1]) * 0.8 <= 1.7 + 1e-9)


def test_build_graph_refuses_empty_map():
    r = raster_from_polygons(3.0, 3.0, [rect(0, 0, 0.5, 0.5)], res_m=0.1)
    with pytest.raises(ValueError, match="no walkable component"):
        build_graph(r, cell_m=1.0, reach_m=1.0, min_component_m2=1.0)


def test_floor_plan_image_with_scale_and_origin(tmp_path):
    from PIL import Image

    # 40 x 20 px at 0.1 m/px: white room with a black wall down the middle, gap at the top.
    a = np.full((20, 40, 3), 255, dtype=np.uint8)
    a[5:, 19:21] = 0  # image rows go down: the wall spans the bottom 1.5 m, the gap is on top
    Image.fromarray(a).save(tmp_path / "plan.png")
    from posefix.mapmatch.floorplan import raster_from_image

    r = raster_from_image(tmp_path / "plan.png", m_per_px=0.1, origin_xy_m=(10.0, 5.0))
    assert r.width_m == pytest.approx(4.0) and r.height_m == pytest.approx(2.0)
    assert not r.is_walkable(np.array([[12.0, 5.5]]))[0]  # the wall, 0.5 m above the bottom
    assert r.is_walkable(np.array([[12.0, 6.8]]))[0]  # the gap near the top
    g = build_graph(r, cell_m=0.5, reach_m=0.5, min_component_m2=0.5)
    assert vid(g, 4, 0) not in neighbours(g, vid(g, 3, 0))
    assert g.n_vertices > 0 and g.p_xy_m[:, 0].min() > 10.0
