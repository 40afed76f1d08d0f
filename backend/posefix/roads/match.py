"""Match a vehicle run's keyframes to the road network: candidates projected onto road
segments (as FMM and Valhalla do) and a linear-chain CRF decoded by Viterbi.

States at keyframe t: up to ``K`` candidates ``c_tk``, the projections of the position
``p_t`` (the reported one moved by the bias estimated so far, below) onto the nearest road
segments within ``RADIUS_M``, plus one off-road state that stays at ``p_t``. The energy of a path (the negative log of its unnormalised
probability) is

    E = sum_t U_t(k_t) + sum_t B_t(k_t, k_t+1)

    U_t(k)   = |p_t - c_tk|^2 / (2 sigma_d^2) + [moving] delta_tk^2 / (2 sigma_h^2)   (road states)
    U_t(off) = OFF_ROAD_COST = 50                   (a road 10 sigma_d away: only where none is within reach)
    B_t(i,j) = |(c_t+1,j - c_ti) - (p_t+1 - p_t)|^2 / (2 sigma_s^2)

with ``delta`` the angle between the body's heading and the segment (undirected, so
either way along it), applied where the keyframe moved more than ``MOVING_M``. The pairwise
term asks consecutive matches to be displaced as the run was: the run's relative motion is
right locally (an IMU's shape), its absolute position is what is wrong, so a constant GNSS
bias costs nothing and a jump to a parallel street costs its offset.

``sigma_d`` is estimated per run: the robust spread (1.4826 x median) of the distances to
the nearest road, within [``SIGMA_D_MIN_M``, ``SIGMA_D_MAX_M``]; ``sigma_h`` = 20 degrees
(a car's heading follows its lane; junctions and curves between OSM nodes);
``sigma_s`` = 1.5 m (half a lane: a lane change between keyframes).

The bias. A projection only moves a keyframe across its road, so a GNSS bias along a
straight road would stay, and on a straight road that is most of the error. The run's
error is a slowly varying bias ``b_t`` (the shape is right, the position wrong), so after
each decoding the bias is estimated from the matched roads, every road constraining it
across that road only, and the turns constraining the rest. A car also drives in a lane,
not on the centreline: ``o``, the run's lane offset (metres right of travel: positive in
right-hand traffic, negative in left-hand), is estimated with it:

    min_{b,o}  sum_t w_t (n_t . (p_t + b_t - c_t) - s_t o)^2       (road t's line, unit normal n_t)
             + sum_t |b_t+1 - phi_t b_t|^2 / q_t + |b_0|^2 / sigma_b^2 + o^2 / sigma_o^2

    q_t = rate^2 dt_t,  phi_t = exp(-dt_t / tau)          (a random walk slowly returning to 0)
    w_t = 1 / (h_t^2 / 3 + SIGMA_LINE_M^2)                (the carriageway's spread across, half width h_t)
    s_t = n_t . r_t                                       (r_t: unit vector right of the body's heading)

The offset turns with the car and a bias does not, which tells them apart wherever the run
turns or drives a road both ways. After the first pass, Cauchy weights
``w_t / (1 + (r_t / (3 sqrt(1/w_t)))^2)`` on the previous estimate's residuals ``r_t`` (a
wrong edge at a junction pulls little); no road term where the decoding chose the off-road
state. ``rate`` = 0.5 m/sqrt(s) (a fix's multipath error wanders by metres over tens of
seconds), ``tau`` = 600 s, ``sigma_b`` per run as ``sigma_d`` (within [``SIGMA_B_MIN_M``,
``SIGMA_B_MAX_M``]), ``sigma_o`` = 1.75 m (half a 3.5 m lane); rate, tau, sigma_o and
``PASSES`` were chosen among a few values on the tuned drives of ``benchmarks.roads``. The system in ``b`` is block
tridiagonal and ``o`` couples every row: a banded Cholesky solve with two right-hand sides
and ``o`` by its Schur complement; on the last pass a Kalman filter and Rauch-Tung-Striebel
smoother give the same ``b`` (given ``o``) and each ``b_t``'s covariance ``P_t``.
``PASSES`` rounds: decode at ``p + b``, estimate ``b`` and ``o``. The suggestion is
``p_t + b_t``: the run's own shape moved by a smooth bias, not snapped to the centreline, so
the lane, a lane change or a corner cut stays as driven. Its ``sigma_m`` is
``sqrt(lambda_max(P_t + s_t^2 var(o) n_t n_t^T) + m_t)``, ``var(o)`` the inverse of the
Schur complement and ``m_t`` the mean squared distance of the decoding's max-marginal
posterior (min-sum forward + backward) from the chosen state.

``off_road`` flags a reported position outside the carriageway of its nearest road (its
distance above that road's half width), the drivable-area version's meaning.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posefix.mapmatch.osm import local_georef
from posefix.mapmatch.suggest import NoWaysError, Suggestions, heading_from_quaternion_wxyz
from posefix.roads.network import RADIUS_M, RoadNetwork, road_network

__all__ = ["FewRoadsNear", "match_on_roads", "match_xy"]

K = 8
SIGMA_D_MIN_M, SIGMA_D_MAX_M = 2.0, 20.0
SIGMA_H_RAD = np.deg2rad(20.0)
SIGMA_S_M = 1.5
OFF_ROAD_COST = 50.0  # 10 sigma_d: only where no road is within the search radius, in practice
MOVING_M = 1.0
PASSES = 3
TAU_S = 600.0
RATE_M_PER_SQRT_S = 0.5
SIGMA_B_MIN_M, SIGMA_B_MAX_M = 1.0, 30.0
SIGMA_LINE_M = 0.5
SIGMA_LANE_M = 1.75
ROBUST_C = 3.0


def candidates(net: RoadNetwork, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per keyframe (n, K): candidate points (n, K, 2), distances, segment headings, segment ids (-1: none)."""
    n = len(p)
    row, seg = net.segments_near(p)
    px, py = p[:, 0].take(row), p[:, 1].take(row)
    ax, ay, dx, dy = net.ax.take(seg), net.ay.take(seg), net.dx.take(seg), net.dy.take(seg)
    t = np.clip(((px - ax) * dx + (py - ay) * dy) * net.inv_len2.take(seg), 0.0, 1.0)
    cx, cy = ax + t * dx, ay + t * dy
    d = np.hypot(px - cx, py - cy)
    keep = np.flatnonzero(d <= RADIUS_M)
    # nearest first per keyframe (one sort key: d <= RADIUS_M < 2^16); a segment met in two
    # cells is the same (row, d, seg), adjacent or one apart (a tie at a shared node between)
    order = keep[np.argsort(row.take(keep) * 65536.0 + d.take(keep), kind="stable")]
    row, seg = row.take(order), seg.take(order)
    dup = np.zeros(len(row), dtype=bool)
    dup[1:] = (row[1:] == row[:-1]) & (seg[1:] == seg[:-1])
    dup[2:] |= (row[2:] == row[:-2]) & (seg[2:] == seg[:-2])
    order, row, seg = order[~dup], row[~dup], seg[~dup]
    first = np.searchsorted(row, row, side="left")
    rank = np.arange(len(row)) - first
    keep = rank < K
    row, rank, order, seg = row[keep], rank[keep], order[keep], seg[keep]
    cand = np.zeros((n, K, 2))
    dist = np.full((n, K), np.inf)
    head = np.zeros((n, K))
    ids = np.full((n, K), -1, dtype=np.int64)
    cand[row, rank, 0] = cx.take(order)
    cand[row, rank, 1] = cy.take(order)
    dist[row, rank] = d.take(order)
    head[row, rank] = np.arctan2(net.dy.take(seg), net.dx.take(seg))
    ids[row, rank] = seg
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


def match_xy(net: RoadNetwork, p: np.ndarray, heading: np.ndarray, dt_s: np.ndarray | float = 1.0,
             passes: int = PASSES, rate: float = RATE_M_PER_SQRT_S, tau_s: float = TAU_S, min_near_share: float = 0.0,
             sigma_lane: float | None = None):
    """Match points ``p`` (n, 2) in ``net``'s frame with body headings (n,) rad CCW from east.

    ``dt_s``: time between consecutive keyframes (scalar or (n-1,)). Returns (matched (n, 2),
    off_road (n,), sigma_m (n,), sigma_d, lane offset m right of travel); see the module docstring.
    """
    n = len(p)
    dt = np.broadcast_to(np.asarray(dt_s, dtype=float), (n - 1,))
    near0 = candidates(net, p)
    _, dist0, _, ids0 = near0
    has0 = np.isfinite(dist0[:, 0])
    if has0.mean() < min_near_share:
        raise FewRoadsNear(f"{int(has0.sum())} of {n} keyframes have a road within {RADIUS_M:.0f} m")
    # the bias's spread, per run: the reported positions' spread across their roads
    sigma_b = float(np.clip(1.4826 * np.median(dist0[has0, 0]), SIGMA_B_MIN_M, SIGMA_B_MAX_M)) if has0.any() else SIGMA_B_MAX_M
    sigma_lane = SIGMA_LANE_M if sigma_lane is None else sigma_lane
    bias = np.zeros_like(p)
    offset = 0.0
    for k in range(passes):
        near = near0 if k == 0 else candidates(net, p + bias)
        last = k == passes - 1
        state, matched, on_road, spread, sigma_d = _viterbi_pass(near, p + bias, heading, last)
        cand, dist, head, ids = near
        seg = np.where(on_road, ids[np.arange(n), np.minimum(state, K - 1)], -1)
        bias, cov, offset = _smooth_bias(net, p, bias, offset, matched, seg, heading, dt, sigma_b, tau_s, rate,
                                         robust=k > 0, covariance=last, sigma_o=sigma_lane)
    out = p + bias
    half = net.half_width_m[np.where(has0, ids0[:, 0], 0)]
    off_road = ~has0 | (dist0[:, 0] > half)
    # 1 sigma major axis: the bias's posterior and the Viterbi's doubt between candidates
    tr, det = cov[:, 0] + cov[:, 2], cov[:, 0] * cov[:, 2] - cov[:, 1] ** 2
    major = 0.5 * tr + np.sqrt(np.maximum(0.25 * tr * tr - det, 0.0))
    sigma = np.sqrt(major + spread)
    return out, off_road, sigma, sigma_d, offset


def _smooth_bias(net: RoadNetwork, p, bias, offset, matched, seg, heading, dt, sigma_b, tau, rate, robust: bool,
                 covariance: bool, sigma_o: float = SIGMA_LANE_M):
    """The smooth bias b_t (n, 2) and the lane offset o (m, right of travel) minimising the
    module docstring's least squares; with ``covariance`` also each b_t's (n, 3) xx, xy, yy."""
    n = len(p)
    on = seg >= 0
    s = np.maximum(seg, 0)
    ab = net.b_xy[s] - net.a_xy[s]
    nrm = np.column_stack([-ab[:, 1], ab[:, 0]]) / np.linalg.norm(ab, axis=1, keepdims=True)
    side = nrm[:, 0] * np.sin(heading) - nrm[:, 1] * np.cos(heading)  # n . (right of travel): +-1 along, 0 across
    z = np.einsum("ij,ij->i", nrm, matched - p)  # n . (c - p): the bias across the road
    var = net.half_width_m[s] ** 2 / 3.0 + SIGMA_LINE_M**2
    if robust:
        r = np.einsum("ij,ij->i", nrm, p + bias - matched) - side * offset
        var = var * (1.0 + (r / (ROBUST_C * np.sqrt(var))) ** 2)  # Cauchy weights
    w = np.where(on, 1.0 / var, 0.0)
    phi = np.exp(-dt / tau)
    q = rate**2 * dt
    from scipy.linalg import solveh_banded

    # information matrix of b, unknowns interleaved (x0, y0, x1, y1, ...), upper band form;
    # the offset o couples every row (an arrow matrix): eliminated by its Schur complement
    dx = np.zeros(n)
    dx[0] += 1.0 / sigma_b**2
    dx[1:] += 1.0 / q
    dx[:-1] += phi**2 / q
    dy = dx + w * nrm[:, 1] ** 2
    dx = dx + w * nrm[:, 0] ** 2
    band = np.zeros((3, 2 * n))
    band[2, 0::2], band[2, 1::2] = dx, dy
    band[1, 1::2] = w * nrm[:, 0] * nrm[:, 1]
    band[0, 2::2] = band[0, 3::2] = -phi / q
    rhs = np.empty((2 * n, 2))
    rhs[0::2, 0], rhs[1::2, 0] = w * z * nrm[:, 0], w * z * nrm[:, 1]
    rhs[0::2, 1], rhs[1::2, 1] = -w * side * nrm[:, 0], -w * side * nrm[:, 1]  # u: the o column
    x = solveh_banded(band, rhs, lower=False, check_finite=False)
    u = rhs[:, 1]
    schur = np.sum(w * side**2) + 1.0 / sigma_o**2 - u @ x[:, 1]  # o's posterior information
    offset = float((-np.sum(w * side * z) - u @ x[:, 0]) / schur)
    if covariance:  # b given o, with its covariance, and o's own doubt across each road
        b, cov = _rts(z + side * offset, nrm, np.where(on, var, np.inf), phi, q, sigma_b)
        cross = np.where(on, side**2 / schur, 0.0)
        cov = cov + cross[:, None] * np.column_stack([nrm[:, 0] ** 2, nrm[:, 0] * nrm[:, 1], nrm[:, 1] ** 2])
        return b, cov, offset
    return (x[:, 0] - x[:, 1] * offset).reshape(n, 2), None, offset


def _rts(z, nrm, var, phi, q, sigma_b):
    """The same estimate by a Kalman filter and Rauch-Tung-Striebel smoother (scalar
    arithmetic: 2 x 2 blocks), which also gives each b_t's marginal covariance (n, 3) xx, xy, yy."""
    n = len(z)
    zl, nxl, nyl, rl = z.tolist(), nrm[:, 0].tolist(), nrm[:, 1].tolist(), var.tolist()
    phl, ql = np.broadcast_to(phi, (n - 1,)).tolist(), np.broadcast_to(q, (n - 1,)).tolist()
    mp, pp, mf, pf = [None] * n, [None] * n, [None] * n, [None] * n
    mx = my = 0.0
    a = c = sigma_b * sigma_b
    b = 0.0
    for t in range(n):
        if t:
            f, qq = phl[t - 1], ql[t - 1]
            mx, my = f * mx, f * my
            a, b, c = f * f * a + qq, f * f * b, f * f * c + qq
        mp[t], pp[t] = (mx, my), (a, b, c)
        rt = rl[t]
        if rt != np.inf:
            hx, hy = nxl[t], nyl[t]
            px, py = a * hx + b * hy, b * hx + c * hy
            s = hx * px + hy * py + rt
            g = (zl[t] - hx * mx - hy * my) / s
            mx, my = mx + px * g, my + py * g
            a, b, c = a - px * px / s, b - px * py / s, c - py * py / s
        mf[t], pf[t] = (mx, my), (a, b, c)
    mean = np.empty((n, 2))
    cov = np.empty((n, 3))
    sx, sy, sa, sb, sc = mx, my, a, b, c
    mean[-1], cov[-1] = (sx, sy), (sa, sb, sc)
    for t in range(n - 2, -1, -1):
        f = phl[t]
        fa, fb, fc = pf[t]
        pa, pb, pc = pp[t + 1]
        det = pa * pc - pb * pb
        ia, ib, ic = pc / det, -pb / det, pa / det
        ga, gb = f * (fa * ia + fb * ib), f * (fa * ib + fb * ic)  # G = phi P_f P_p^-1
        gc, gd = f * (fb * ia + fc * ib), f * (fb * ib + fc * ic)
        ex, ey = sx - mp[t + 1][0], sy - mp[t + 1][1]
        fx, fy = mf[t]
        sx, sy = fx + ga * ex + gb * ey, fy + gc * ex + gd * ey
        da, db, dc = sa - pa, sb - pb, sc - pc
        ua, ub = ga * da + gb * db, ga * db + gb * dc
        va, vb = gc * da + gd * db, gc * db + gd * dc
        sa, sb, sc = fa + ua * ga + ub * gb, fb + ua * gc + ub * gd, fc + va * gc + vb * gd
        mean[t], cov[t] = (sx, sy), (sa, sb, sc)
    return mean, cov


def _viterbi_pass(near, p, heading: np.ndarray, marginals: bool):
    """One Viterbi pass over the candidates ``near`` of ``p``; the off-road state stays at ``p``.
    Returns (state, matched, on_road, spread (the posterior's mean squared distance from
    the match), sigma_d)."""
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
    pos = np.concatenate([cand, p[:, None, :]], axis=1)
    pos = np.where(np.isfinite(unary)[..., None], pos, p[:, None, :])  # empty slots: unused, finite
    state, marg = viterbi(unary, pos, step, SIGMA_S_M, marginals)
    rows = np.arange(len(p))
    matched = pos[rows, state]
    spread = np.zeros(len(p))
    if marginals:
        w = np.exp(-(marg - marg.min(axis=1, keepdims=True)))
        w /= w.sum(axis=1, keepdims=True)
        spread = np.einsum("ts,ts->t", w, np.sum((pos - matched[:, None, :]) ** 2, axis=2))
    return state, matched, state < K, spread, sigma_d


class FewRoadsNear(ValueError):
    """Fewer than the asked share of keyframes has a road within ``RADIUS_M`` (a car park, a
    gap in the extract): the caller falls back to a matcher without a search radius."""


def match_on_roads(lon_deg: np.ndarray, lat_deg: np.ndarray, q_body_to_enu_wxyz: np.ndarray, osm_path: str | Path,
                   index: np.ndarray | None = None, margin_m: float = 100.0, t_s: np.ndarray | None = None,
                   min_near_share: float = 0.0) -> Suggestions:
    """Match keyframes (rows ``index`` of the run, default all) to the OSM road network.

    ``t_s``: the keyframes' times (s; default one a second, the keyframe default). The
    result has the drivable-area version's form (:class:`posefix.mapmatch.Suggestions`;
    ``n_vertices`` counts road segments). Raises ``ValueError`` naming the file when it is
    missing or has no drivable way within ``margin_m`` of the run, and :class:`FewRoadsNear`
    when fewer than ``min_near_share`` of the keyframes have a road within ``RADIUS_M``.
    """
    lon = np.asarray(lon_deg, dtype=float)
    lat = np.asarray(lat_deg, dtype=float)
    idx = np.arange(lon.size) if index is None else np.asarray(index, dtype=np.int64)
    if idx.size < 2:
        raise ValueError("need at least two keyframes to match")
    if not Path(osm_path).is_file():
        raise ValueError(f"{osm_path}:0: field file: no such OSM extract")
    dt_s = 1.0
    if t_s is not None:
        dt_s = np.diff(np.asarray(t_s, dtype=float)[idx])
        bad = np.flatnonzero(~(dt_s > 0))
        if bad.size:
            raise ValueError(f"keyframe {int(bad[0]) + 1}: field t_s: times must increase")
    ll = np.column_stack([lon[idx], lat[idx]])
    for k, name in enumerate(("lon", "lat")):
        bad = np.flatnonzero(~np.isfinite(ll[:, k]))
        if bad.size:
            raise ValueError(f"keyframe {int(bad[0])}: field {name}: not a finite number")
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
    matched, off_road, sigma, _, _ = match_xy(net, p, heading, dt_s=dt_s, min_near_share=min_near_share)
    return Suggestions(index=idx, lonlat_deg=net.georef.to_lonlat(matched),
                       moved_m=np.linalg.norm(matched - p, axis=1), off_road=off_road, sigma_m=sigma,
                       n_vertices=net.n_segments, matcher="roads")
