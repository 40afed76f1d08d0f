"""Match a vehicle run's keyframes to the road network: candidates projected onto road
segments (as FMM and Valhalla do) and a linear-chain CRF decoded by Viterbi.

States at keyframe t: up to ``K`` candidates ``c_tk``, the projections of the reported
position ``p_t`` onto the nearest road segments within ``CELL_M``, plus one off-road state
that stays at ``p_t``. The energy of a path (the negative log of its unnormalised
probability) is

    E = sum_t U_t(k_t) + sum_t B_t(k_t, k_t+1)

    U_t(k)   = |p_t - c_tk|^2 / (2 sigma_d^2) + [moving] delta_tk^2 / (2 sigma_h^2)   (road states)
    U_t(off) = OFF_ROAD_Z^2 / 2                     (as costly as a road 3 sigma_d away)
    B_t(i,j) = |(c_t+1,j - c_ti) - (p_t+1 - p_t)|^2 / (2 sigma_s^2)

with ``delta`` the angle between the body's heading and the segment (undirected, so
either way along it), applied where the keyframe moved more than ``MOVING_M``. The pairwise
term asks consecutive matches to be displaced as the run was: the run's relative motion is
right locally (an IMU's shape), its absolute position is what is wrong, so a constant GNSS
bias costs nothing and a jump to a parallel street costs its offset.

``sigma_d`` is estimated per run: the robust spread (1.4826 x median) of the distances to
the nearest road, within [``SIGMA_D_MIN_M``, ``SIGMA_D_MAX_M``]; ``sigma_h`` = 20 degrees
(a car's heading follows its lane; junctions and curves between OSM nodes);
``sigma_s`` = 1.5 m (half a lane: a lane change between keyframes). Each keyframe's
``sigma_m`` is the spread of its max-marginal posterior over the states (min-sum forward
+ backward) plus the lateral spread of a carriageway (half width / sqrt 3).

Two passes: the projections only move a keyframe across its road, so a GNSS bias along a
straight road would stay. The first pass's residuals (matched - reported), median-filtered
over ``BIAS_WINDOW`` keyframes, estimate the run's slowly varying bias, whose along-road
part shows at every turn; the second pass matches the reported positions moved by it
(``p_t`` above becomes ``p_t + bias_t``; the off-road state stays at the reported position).

``off_road`` flags a reported position outside the carriageway of its nearest road (its
distance above that road's half width), the drivable-area version's meaning.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posefix.mapmatch.osm import local_georef
from posefix.mapmatch.suggest import NoWaysError, Suggestions, heading_from_quaternion_wxyz
from posefix.roads.network import CELL_M, RoadNetwork, road_network

__all__ = ["match_on_roads", "match_xy"]

K = 8
SIGMA_D_MIN_M, SIGMA_D_MAX_M = 2.0, 20.0
SIGMA_H_RAD = np.deg2rad(20.0)
SIGMA_S_M = 1.5
OFF_ROAD_Z = 3.0
OFF_ROAD_COST = 50.0  # 10 sigma_d: only where no road is within the search radius, in practice
MOVING_M = 1.0
BIAS_PASSES = 1
BIAS_WINDOW = 61  # keyframes (a minute at one a second): slower than a road's turns, faster than GNSS drift


def candidates(net: RoadNetwork, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per keyframe (n, K): candidate points (n, K, 2), distances, segment headings, segment ids (-1: none)."""
    n = len(p)
    row, seg = net.segments_near(p)
    a, ab = net.a_xy[seg], net.b_xy[seg] - net.a_xy[seg]
    t = np.clip(np.einsum("ij,ij->i", p[row] - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    c = a + t[:, None] * ab
    d = np.linalg.norm(p[row] - c, axis=1)
    keep = d <= CELL_M
    row, seg, c, d, ab = row[keep], seg[keep], c[keep], d[keep], ab[keep]
    # nearest first per keyframe; a segment met in two cells is the same (row, d, seg): adjacent
    order = np.lexsort((seg, d, row))
    row, seg, c, d, ab = row[order], seg[order], c[order], d[order], ab[order]
    dup = np.zeros(len(row), dtype=bool)
    dup[1:] = (row[1:] == row[:-1]) & (seg[1:] == seg[:-1])
    row, seg, c, d, ab = row[~dup], seg[~dup], c[~dup], d[~dup], ab[~dup]
    first = np.searchsorted(row, row, side="left")
    rank = np.arange(len(row)) - first
    keep = rank < K
    row, rank = row[keep], rank[keep]
    cand = np.zeros((n, K, 2))
    dist = np.full((n, K), np.inf)
    head = np.zeros((n, K))
    ids = np.full((n, K), -1, dtype=np.int64)
    cand[row, rank] = c[keep]
    dist[row, rank] = d[keep]
    head[row, rank] = np.arctan2(ab[keep, 1], ab[keep, 0])
    ids[row, rank] = seg[keep]
    return cand, dist, head, ids


def viterbi(unary: np.ndarray, pos: np.ndarray, step: np.ndarray, sigma_s: float,
            marginals: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Min-sum decoding; returns the best state per keyframe and the max-marginal energies
    (n, S) (the forward energies only unless ``marginals``)."""
    n, S = unary.shape
    diff = (pos[1:, None, :, :] - pos[:-1, :, None, :]) - step[:, None, None, :]
    pair = np.einsum("tijc,tijc->tij", diff, diff) / (2.0 * sigma_s**2)  # (n-1, S, S)
    fwd = np.empty((n, S))
    back = np.empty((n - 1, S), dtype=np.int64)
    fwd[0] = unary[0]
    cols = np.arange(S)
    for t in range(n - 1):
        tot = fwd[t][:, None] + pair[t]
        back[t] = np.argmin(tot, axis=0)
        fwd[t + 1] = tot[back[t], cols] + unary[t + 1]
    bwd = np.zeros((n, S))
    for t in range(n - 2 if marginals else -1, -1, -1):
        bwd[t] = np.min(pair[t] + (unary[t + 1] + bwd[t + 1])[None, :], axis=1)
    state = np.empty(n, dtype=np.int64)
    state[-1] = int(np.argmin(fwd[-1]))
    for t in range(n - 2, -1, -1):
        state[t] = back[t, state[t + 1]]
    return state, fwd + bwd


def match_xy(net: RoadNetwork, p: np.ndarray, heading: np.ndarray, window: int = BIAS_WINDOW):
    """Match points ``p`` (n, 2) in ``net``'s frame with body headings (n,) rad CCW from east.

    Two passes: the second matches the positions moved by the first's residuals, median-
    filtered over ``window`` keyframes (the run's slowly varying bias; a turn shows the
    along-road part a straight road cannot). Returns (matched (n, 2), off_road (n,),
    sigma_m (n,), sigma_d).
    """
    near = candidates(net, p)
    passes = BIAS_PASSES if window > 1 else 0
    matched, on_road, sigma, sigma_d = _match_once(near, p, heading, net.half_width_m, marginals=passes == 0)
    for _ in range(passes):
        if on_road.sum() < 2:
            break
        from scipy.ndimage import median_filter

        r = (matched - p)[on_road]
        bias = np.empty_like(p)
        for k in range(2):
            smooth = median_filter(r[:, k], size=min(window, len(r)), mode="nearest")
            bias[:, k] = np.interp(np.arange(len(p)), np.flatnonzero(on_road), smooth)
        matched, on_road, sigma, sigma_d = _match_once(candidates(net, p + bias), p, heading, net.half_width_m)
    _, dist, _, ids = near
    has = np.isfinite(dist[:, 0])
    half = net.half_width_m[np.where(has, ids[:, 0], 0)]
    off_road = ~has | (dist[:, 0] > half)
    return matched, off_road, sigma, sigma_d


def _match_once(near, p_reported: np.ndarray, heading: np.ndarray, half_width_m: np.ndarray, marginals: bool = True):
    """One Viterbi pass over the candidates ``near``; the off-road state stays at ``p_reported``."""
    p = p_reported
    cand, dist, head, ids = near
    has = np.isfinite(dist[:, 0])
    nearest = dist[has, 0]
    sigma_d = float(np.clip(1.4826 * np.median(nearest), SIGMA_D_MIN_M, SIGMA_D_MAX_M)) if nearest.size else SIGMA_D_MAX_M
    step = np.diff(p, axis=0)
    moving = np.zeros(len(p), dtype=bool)
    moving[1:] |= np.linalg.norm(step, axis=1) > MOVING_M
    moving[:-1] |= np.linalg.norm(step, axis=1) > MOVING_M
    delta = np.abs(np.angle(np.exp(1j * (heading[:, None] - head))))
    delta = np.minimum(delta, np.pi - delta)  # a road is driven either way
    unary = np.where(np.isfinite(dist), dist**2 / (2 * sigma_d**2), np.inf)
    unary += np.where(moving[:, None], delta**2 / (2 * SIGMA_H_RAD**2), 0.0)
    off = np.where(has, OFF_ROAD_COST, 0.0)  # the off-road state: where no road is near, or beyond reason
    unary = np.concatenate([unary, off[:, None]], axis=1)
    pos = np.concatenate([cand, p_reported[:, None, :]], axis=1)
    pos = np.where(np.isfinite(unary)[..., None], pos, p_reported[:, None, :])  # empty slots: unused, finite
    state, marg = viterbi(unary, pos, step, SIGMA_S_M, marginals)
    rows = np.arange(len(p))
    matched = pos[rows, state]
    w = np.exp(-(marg - marg.min(axis=1, keepdims=True)))
    w /= w.sum(axis=1, keepdims=True)
    spread = np.einsum("ts,ts->t", w, np.sum((pos - matched[:, None, :]) ** 2, axis=2))
    half = half_width_m[np.maximum(ids[rows, np.minimum(state, K - 1)], 0)]
    on_road = state < K
    sigma = np.sqrt(spread + np.where(on_road, half**2 / 3.0, sigma_d**2))
    return matched, on_road, sigma, sigma_d


def match_on_roads(lon_deg: np.ndarray, lat_deg: np.ndarray, q_body_to_enu_wxyz: np.ndarray, osm_path: str | Path,
                   index: np.ndarray | None = None, margin_m: float = 100.0) -> Suggestions:
    """Match keyframes (rows ``index`` of the run, default all) to the OSM road network.

    The result has the drivable-area version's form (:class:`posefix.mapmatch.Suggestions`;
    ``n_vertices`` counts road segments). Raises ``ValueError`` naming the file when it is
    missing or has no drivable way within ``margin_m`` of the run.
    """
    lon = np.asarray(lon_deg, dtype=float)
    lat = np.asarray(lat_deg, dtype=float)
    idx = np.arange(lon.size) if index is None else np.asarray(index, dtype=np.int64)
    if idx.size < 2:
        raise ValueError("need at least two keyframes to match")
    if not Path(osm_path).is_file():
        raise ValueError(f"{osm_path}:0: field file: no such OSM extract")
    ll = np.column_stack([lon[idx], lat[idx]])
    g0 = local_georef(float(ll[:, 0].min()), float(ll[:, 1].min()))
    pad_lon, pad_lat = margin_m * g0.dlon_deg_per_m, margin_m * g0.dlat_deg_per_m
    bbox = (float(ll[:, 0].min() - pad_lon), float(ll[:, 1].min() - pad_lat),
            float(ll[:, 0].max() + pad_lon), float(ll[:, 1].max() + pad_lat))
    try:
        net = road_network(osm_path, bbox)
    except NoWaysError:
        raise ValueError(f"{osm_path}:0: field highway: no drive ways within {margin_m} m of the run") from None
    p = net.georef.to_xy(ll)
    heading = heading_from_quaternion_wxyz(np.asarray(q_body_to_enu_wxyz, dtype=float)[idx])
    matched, off_road, sigma, _ = match_xy(net, p, heading)
    return Suggestions(index=idx, lonlat_deg=net.georef.to_lonlat(matched),
                       moved_m=np.linalg.norm(matched - p, axis=1), off_road=off_road, sigma_m=sigma,
                       n_vertices=net.n_segments)
