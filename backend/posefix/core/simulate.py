"""Synthetic drives with ground truth, for tests, benchmarks and the demo.

The model (all units SI, angles radians unless named ``_deg``):

1. **Path.** A planar centreline in the local ENU frame, sampled every ``DS_M`` metres of
   arc length ``s``: either synthetic (curvature ``κ(s)`` = gentle OU wander plus turns of
   30-120° at radii 15-60 m, heading ``θ = ∫κ ds``) or a random drive over the highway
   graph of an OpenStreetMap extract (shortest paths between random nodes, corners rounded
   by a moving average). Height ``z(s)`` = sum of long sinusoids (gentle grades).
2. **Speed.** ``v(s) = min(v_wish(s), sqrt(A_LAT_MAX / |κ(s)|))`` clipped to [5, 20] m/s and
   smoothed; time along the path ``t(s) = ∫ ds / v(s)``, inverted at the sample times.
3. **Truth pose.** Position on the path; yaw = path heading, pitch from the grade
   (``-atan(dz/ds)``, positive pitch = nose down for x fwd, z up), roll = ``ROLL_PER_ALAT``
   × lateral acceleration. Body frame x forward, y left, z up; ``R = Rz(yaw)Ry(pitch)Rx(roll)``.
4. **Raw GNSS** (``gnss_*`` columns, fixes at ``gnss_rate_hz`` held between fixes) = truth +
   the regime's GNSS error. **Reported pose** = truth + a slowly varying error (so its
   local shape is right, as from a GNSS/INS filter) + small slowly varying attitude error.

Regimes (``REGIMES``):

- ``white``: GNSS white noise (2.5 m per horizontal axis, 4 m vertical, 1σ); the pose
  wanders smoothly (an Ornstein-Uhlenbeck process, 3 m, correlation 120 s, low-passed 20 s).
- ``drift``: a post-processed GNSS/INS pose whose bias moves a few cm/s (OU 4 m / 300 s,
  low-passed 30 s); raw GNSS with white noise in the ``gnss_*`` columns.
- ``canyon``: urban-canyon offset jumps of 5-20 m lasting 1-5 minutes in the GNSS, which the
  pose inherits through a 10 s low-pass (INS filters follow a biased fix).
- ``canyon_ins``: the same canyon offsets in the raw GNSS only; the reported pose is a
  GNSS/INS solution that bridged them (smooth 3 m wander as in ``white``), so a location
  term that trusts the GNSS would pull a good run onto a biased track (the case the drift model exists for).
- ``outliers``: 50 m GNSS outliers in bursts of 1-3 s (about 3 % of fixes) on top of white
  noise; the pose wanders as in ``white`` (its filter gated them out).
- ``mixed``: canyon offsets + outliers in the GNSS, pose = inherited canyon offsets + drift.

Edits: at times ``(k + 1/2)·edit_every_s``, the true horizontal position of that sample
plus click noise (``click_noise_m`` 1σ per axis), as 2-D edits (altitude free).

Everything is vectorised; an hour at 100 Hz takes about a second.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from posefix.core.geodesy import EnuOrigin, as_origin, enu_to_geodetic, geodetic_to_enu, quat_local_enu_to_origin_enu
from posefix.core.rotations import quat_conjugate, quat_multiply
from posefix.core.run import PoseRun

__all__ = ["REGIMES", "Simulation", "SimEdit", "simulate", "load_osm_graph", "OsmGraph"]

REGIMES = ("white", "drift", "canyon", "canyon_ins", "outliers", "mixed")
DS_M = 0.5  # arc-length step of the path, metres
V_MIN_MPS, V_MAX_MPS = 5.0, 20.0
A_LAT_MAX_MPS2 = 2.5  # comfortable lateral acceleration that sets corner speeds
ROLL_PER_ALAT = 0.01  # rad of body roll per m/s² of lateral acceleration
DEFAULT_ORIGIN = (60.1699, 24.9384, 20.0)  # Helsinki centre, used when no OSM extract is given
DEFAULT_T0_S = 1_700_000_000.0  # 2023-11-14 UTC, so exported GPX times look like a real drive
DRIVABLE = {
    "motorway", "trunk", "primary", "secondary", "tertiary", "unclassified", "residential",
    "service", "living_street", "motorway_link", "trunk_link", "primary_link",
    "secondary_link", "tertiary_link", "road",
}


@dataclass(frozen=True)
class SimEdit:
    """An operator edit: sample ``index`` at ``t_s`` moved to (lat, lon), 2-D."""

    index: int
    t_s: float
    lat_deg: float
    lon_deg: float


@dataclass(frozen=True)
class Simulation:
    """A simulated drive: ``truth`` and reported ``run`` share times; ``edits`` name samples."""

    truth: PoseRun
    run: PoseRun
    edits: list[SimEdit]
    regime: str
    origin: EnuOrigin
    info: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- noise

def _ou(rng: np.random.Generator, n: int, dt_s: float, sigma: float, tau_s: float, dims: int = 1) -> np.ndarray:
    """Stationary Ornstein-Uhlenbeck samples, shape (n, dims).

    ``x_k = a x_{k-1} + σ sqrt(1 - a²) w_k`` with ``a = exp(-dt/τ)``, started stationary.
    """
    from scipy.signal import lfilter

    a = np.exp(-dt_s / tau_s)
    w = rng.standard_normal((n, dims))
    w[0] = w[0] / np.sqrt(1 - a * a)  # x_0 ~ N(0, σ²)
    return lfilter([sigma * np.sqrt(1 - a * a)], [1.0, -a], w, axis=0)


def _lowpass(x: np.ndarray, dt_s: float, tau_s: float) -> np.ndarray:
    """First-order low-pass along axis 0 (an INS filter following its GNSS input)."""
    from scipy.signal import lfilter

    a = np.exp(-dt_s / tau_s)
    zi = (a * x[0])[None, ...]
    y, _ = lfilter([1 - a], [1.0, -a], x, axis=0, zi=zi)
    return y


def _coarse_to_fine(t_coarse: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(t, t_coarse, x[:, k]) for k in range(x.shape[1])])


# ----------------------------------------------------------------------------- paths

def _synthetic_path(rng: np.random.Generator, length_m: float) -> np.ndarray:
    """Centreline (m, 2) in ENU metres every ``DS_M`` along arc length."""
    m = int(np.ceil(length_m / DS_M)) + 2
    kappa = _ou(rng, m, DS_M, sigma=1.0 / 1500.0, tau_s=300.0)[:, 0]  # gentle bends (per metre)
    pos = 50.0
    while pos < m * DS_M:
        pos += rng.exponential(350.0) + 40.0
        angle = np.radians(rng.uniform(30.0, 120.0)) * rng.choice([-1.0, 1.0])
        radius = rng.uniform(15.0, 60.0)
        i0 = int(pos / DS_M)
        i1 = min(m, i0 + int(abs(angle) * radius / DS_M))
        kappa[i0:i1] += np.sign(angle) / radius
        pos += abs(angle) * radius
    heading = rng.uniform(-np.pi, np.pi) + np.cumsum(kappa) * DS_M
    xy = np.column_stack([np.cos(heading), np.sin(heading)]) * DS_M
    xy = np.vstack([[0.0, 0.0], np.cumsum(xy, axis=0)[:-1]])
    return xy


@dataclass(frozen=True)
class OsmGraph:
    """Drivable street graph: node positions (ENU at ``origin``) and a sparse length matrix."""

    origin: EnuOrigin
    xy_m: np.ndarray  # (v, 2)
    lengths: object  # scipy.sparse.csr_matrix (v, v), metres


def load_osm_graph(path: str) -> OsmGraph:
    """Read drivable ``highway`` ways from an OSM extract (.pbf/.osm) with pyosmium.

    Ways are taken as two-way (a simulation of plausible driving, not routing advice). The
    largest connected component is kept; the ENU origin is its bounding-box centre.
    """
    import osmium
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    ids: dict[int, int] = {}
    lonlat: list[tuple[float, float]] = []
    edges: list[tuple[int, int]] = []
    fp = osmium.FileProcessor(str(path)).with_locations().with_filter(osmium.filter.KeyFilter("highway"))
    for obj in fp:
        if not obj.is_way() or obj.tags.get("highway") not in DRIVABLE:
            continue
        prev = None
        for node in obj.nodes:
            if not node.location.valid():
                prev = None
                continue
            k = ids.get(node.ref)
            if k is None:
                k = ids[node.ref] = len(lonlat)
                lonlat.append((node.lon, node.lat))
            if prev is not None and prev != k:
                edges.append((prev, k))
            prev = k
    if not edges:
        raise ValueError(f"{path}: no drivable highway ways found")
    ll = np.asarray(lonlat)
    origin = EnuOrigin(float(ll[:, 1].min() + ll[:, 1].max()) / 2, float(ll[:, 0].min() + ll[:, 0].max()) / 2, 0.0)
    xy = geodetic_to_enu(ll[:, 1], ll[:, 0], np.zeros(len(ll)), origin)[:, :2]
    e = np.asarray(edges)
    w = np.linalg.norm(xy[e[:, 0]] - xy[e[:, 1]], axis=1)
    v = len(ll)
    mat = coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(v, v)).tocsr()
    _, labels = connected_components(mat, directed=False)
    keep = np.flatnonzero(labels == np.bincount(labels).argmax())
    remap = -np.ones(v, dtype=int)
    remap[keep] = np.arange(keep.size)
    sub = mat[keep][:, keep].tocsr()
    return OsmGraph(origin=origin, xy_m=xy[keep], lengths=sub)


def _cut_hairpins(pts: np.ndarray, max_turn_deg: float = 120.0) -> np.ndarray:
    """Drop vertices where the polyline turns by more than ``max_turn_deg`` (hairpins, dead
    ends, slip-lane triangles), repeatedly, so smoothing cannot fold the path into a cusp."""
    cos_max = np.cos(np.radians(max_turn_deg))
    for _ in range(200):
        d = np.diff(pts, axis=0)
        keep = np.r_[True, np.linalg.norm(d, axis=1) > 0.1]
        pts = pts[keep]
        if pts.shape[0] < 3:
            return pts
        d = np.diff(pts, axis=0)
        u = d / np.linalg.norm(d, axis=1, keepdims=True)
        cos_turn = np.einsum("ij,ij->i", u[:-1], u[1:])
        bad = np.flatnonzero(cos_turn < cos_max) + 1
        if bad.size == 0:
            return pts
        # drop every other offending vertex per pass so neighbours are re-examined
        drop = bad[np.r_[True, np.diff(bad) > 1]]
        pts = np.delete(pts, drop, axis=0)
    return pts


def _osm_path(rng: np.random.Generator, graph: OsmGraph, length_m: float) -> np.ndarray:
    """Centreline (m, 2) of a random drive: shortest paths between random far-apart nodes."""
    from scipy.sparse.csgraph import dijkstra

    v = graph.xy_m.shape[0]
    degree = np.diff(graph.lengths.indptr)
    junctions = degree >= 3  # ending a leg at a junction lets the next leg turn, not U-turn
    node = int(rng.choice(np.flatnonzero(junctions))) if junctions.any() else int(rng.integers(v))
    route = [node]
    total = 0.0
    legs = 0
    while total < length_m:
        lengths = graph.lengths
        if len(route) >= 2:
            # Block the street we arrived on so the next leg does not start with a U-turn
            # (a dead end still forces one: then the block is lifted).
            lengths = lengths.tolil(copy=True)
            lengths[node, route[-2]] = np.inf
            lengths[route[-2], node] = np.inf
            lengths = lengths.tocsr()
        dist, pred = dijkstra(lengths, directed=False, indices=node, return_predecessors=True)
        ok = np.isfinite(dist) & (dist > 300.0)
        if not ok.any():
            dist, pred = dijkstra(graph.lengths, directed=False, indices=node, return_predecessors=True)
            ok = np.isfinite(dist) & (dist > 300.0)
        if (ok & junctions).any():
            ok &= junctions
        reach = np.flatnonzero(ok)
        if reach.size == 0:
            reach = np.flatnonzero(np.isfinite(dist) & (dist > 0))
        if reach.size == 0:
            raise ValueError("the OSM street graph has no route to drive")
        target = int(rng.choice(reach))
        hops = [target]
        while hops[-1] != node:
            hops.append(int(pred[hops[-1]]))
        hops.reverse()
        route.extend(hops[1:])
        total += float(dist[target])
        node = target
        legs += 1
        if legs > 100000:  # pragma: no cover - guards against a degenerate graph
            break
    pts = _cut_hairpins(graph.xy_m[np.asarray(route)])
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s_nodes = np.r_[0.0, np.cumsum(seg)]
    s = np.arange(0.0, s_nodes[-1], DS_M)
    xy = np.column_stack([np.interp(s, s_nodes, pts[:, 0]), np.interp(s, s_nodes, pts[:, 1])])
    # Round corners: a moving average over ~12 m (cars do not turn on a point); dead-end
    # U-turns become tight loops.
    w = int(12.0 / DS_M)
    kern = np.ones(w) / w
    pad = np.pad(xy, ((w, w), (0, 0)), mode="edge")
    smooth = np.column_stack([np.convolve(pad[:, k], kern, mode="same")[w:-w] for k in range(2)])
    # re-sample evenly in arc length after smoothing
    seg = np.linalg.norm(np.diff(smooth, axis=0), axis=1)
    s_sm = np.r_[0.0, np.cumsum(seg)]
    keep = np.r_[True, seg > 1e-9]
    s_sm, smooth = s_sm[keep], smooth[keep]
    s2 = np.arange(0.0, s_sm[-1], DS_M)
    return np.column_stack([np.interp(s2, s_sm, smooth[:, 0]), np.interp(s2, s_sm, smooth[:, 1])])


# ----------------------------------------------------------------------------- truth

def _truth_states(rng: np.random.Generator, xy: np.ndarray, t_rel_s: np.ndarray) -> dict[str, np.ndarray]:
    """Sample the path at times ``t_rel_s`` (from 0): positions, yaw, pitch, roll, speed."""
    m = xy.shape[0]
    s = np.arange(m) * DS_M
    d = np.gradient(xy, DS_M, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    kappa = np.gradient(heading, DS_M)
    from scipy.ndimage import maximum_filter1d, minimum_filter1d, uniform_filter1d

    # Corner speed from the sharpest curvature within ±5 m, so the car has slowed before it.
    kappa_s = uniform_filter1d(kappa, max(1, int(4.0 / DS_M)), mode="nearest")
    kappa_max = maximum_filter1d(np.abs(kappa_s), 2 * int(5.0 / DS_M) + 1, mode="nearest")
    v_wish = 12.5 + 7.5 * np.tanh(_ou(rng, m, DS_M, sigma=1.0, tau_s=600.0)[:, 0])
    v_corner = np.sqrt(A_LAT_MAX_MPS2 / np.maximum(kappa_max, 1e-9))
    v = np.clip(np.minimum(v_wish, v_corner), V_MIN_MPS, V_MAX_MPS)
    # Gentle braking and acceleration: erode over ±60 m then average over ±60 m; the result
    # never exceeds the limit anywhere (each averaged value is a minimum over a window
    # containing the point).
    wv = 2 * int(60.0 / DS_M) + 1
    v = uniform_filter1d(minimum_filter1d(v, wv, mode="nearest"), wv, mode="nearest")
    t_of_s = np.r_[0.0, np.cumsum(DS_M / (0.5 * (v[1:] + v[:-1])))]
    if t_of_s[-1] < t_rel_s[-1]:
        raise ValueError("path too short for the requested duration")  # pragma: no cover
    s_t = np.interp(t_rel_s, t_of_s, s)
    z_amp = rng.uniform(1.0, 6.0, 3)
    z_len = rng.uniform(300.0, 3000.0, 3)
    z_ph = rng.uniform(0, 2 * np.pi, 3)
    z = lambda ss: (z_amp[None, :] * np.sin(2 * np.pi * ss[:, None] / z_len[None, :] + z_ph)).sum(axis=1)  # noqa: E731
    dz = lambda ss: (z_amp * 2 * np.pi / z_len * np.cos(2 * np.pi * ss[:, None] / z_len + z_ph)).sum(axis=1)  # noqa: E731
    speed = np.interp(s_t, s, v)
    k_t = np.interp(s_t, s, kappa_s)
    return {
        "e": np.interp(s_t, s, xy[:, 0]),
        "n": np.interp(s_t, s, xy[:, 1]),
        "u": z(s_t),
        "yaw": np.interp(s_t, s, heading),
        "pitch": -np.arctan(dz(s_t)),
        "roll": ROLL_PER_ALAT * speed * speed * k_t,
        "speed": speed,
        "s": s_t,
    }


def _rpy_to_quat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """q = qz(yaw) ⊗ qy(pitch) ⊗ qx(roll), shape (n, 4) (w, x, y, z)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.column_stack([
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ])


def _quat_origin_to_local(q_origin: np.ndarray, lat: np.ndarray, lon: np.ndarray, origin: EnuOrigin) -> np.ndarray:
    """Re-express body->origin-ENU quaternions as body->local-ENU (exact for long drives)."""
    q_local_to_origin = quat_local_enu_to_origin_enu(lat, lon, origin)
    q = quat_multiply(quat_conjugate(q_local_to_origin), q_origin)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


# ----------------------------------------------------------------------------- errors

def _canyon_offsets(rng: np.random.Generator, t_coarse: np.ndarray) -> np.ndarray:
    """Piecewise offsets (n, 3): 5-20 m for 1-5 min, open sky between, 5 s ramps."""
    off = np.zeros((t_coarse.size, 3))
    t_end = t_coarse[-1]
    t = rng.uniform(0.0, 90.0)
    while t < t_end:
        dur = rng.uniform(60.0, 300.0)
        mag = rng.uniform(5.0, 20.0)
        ang = rng.uniform(-np.pi, np.pi)
        vec = np.array([mag * np.cos(ang), mag * np.sin(ang), rng.normal(0.0, 0.3 * mag)])
        ramp = np.clip(np.minimum(t_coarse - t, t + dur - t_coarse) / 5.0, 0.0, 1.0)
        off += ramp[:, None] * vec
        t += dur + rng.exponential(120.0) + 10.0
    return off


def _outliers(rng: np.random.Generator, t_fix: np.ndarray) -> np.ndarray:
    """50 m outliers (n, 3) in bursts of 1-3 s covering about 3 % of fixes."""
    out = np.zeros((t_fix.size, 3))
    span = t_fix[-1] - t_fix[0] if t_fix.size > 1 else 1.0
    n_bursts = rng.poisson(0.03 * span / 2.0)
    for _ in range(n_bursts):
        t0 = rng.uniform(t_fix[0], t_fix[-1])
        sel = (t_fix >= t0) & (t_fix < t0 + rng.uniform(1.0, 3.0))
        ang = rng.uniform(-np.pi, np.pi, sel.sum())
        mag = rng.uniform(40.0, 60.0, sel.sum())
        out[sel] = np.column_stack([mag * np.cos(ang), mag * np.sin(ang), rng.normal(0, 10.0, sel.sum())])
    return out


def _errors(rng: np.random.Generator, regime: str, t_rel_s: np.ndarray, gnss_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(pose error (n,3), GNSS error (n,3)) in ENU metres at the sample times."""
    dur = float(t_rel_s[-1]) if t_rel_s.size else 0.0
    dt_c = 1.0
    t_c = np.arange(0.0, dur + 2 * dt_c, dt_c)
    t_fix = np.arange(0.0, dur + 1.0 / gnss_rate_hz, 1.0 / gnss_rate_hz)
    white = rng.standard_normal((t_fix.size, 3)) * np.array([2.5, 2.5, 4.0])
    gnss_fix = white.copy()
    if regime in ("white", "outliers", "canyon_ins"):
        # a smooth wander (OU low-passed over 20 s): metres over minutes, cm over a second
        pose_c = _lowpass(_ou(rng, t_c.size, dt_c, 3.0, 120.0, 3), dt_c, 20.0) * np.array([1.0, 1.0, 0.6])
    elif regime == "drift":
        pose_c = _lowpass(_ou(rng, t_c.size, dt_c, 4.0, 300.0, 3), dt_c, 30.0) * np.array([1.0, 1.0, 0.5])
    elif regime in ("canyon", "mixed"):
        canyon = _canyon_offsets(rng, t_c)
        gnss_fix += _coarse_to_fine(t_c, canyon, t_fix)
        pose_c = _lowpass(canyon, dt_c, 10.0)
        if regime == "canyon":
            pose_c = pose_c + _lowpass(_ou(rng, t_c.size, dt_c, 0.5, 120.0, 3), dt_c, 20.0)
        else:
            pose_c = pose_c + _lowpass(_ou(rng, t_c.size, dt_c, 4.0, 300.0, 3), dt_c, 30.0) * np.array([1.0, 1.0, 0.5])
    else:
        raise ValueError(f"unknown regime {regime!r} (known: {', '.join(REGIMES)})")
    if regime == "canyon_ins":
        gnss_fix += _coarse_to_fine(t_c, _canyon_offsets(rng, t_c), t_fix)
    if regime in ("outliers", "mixed"):
        gnss_fix += _outliers(rng, t_fix)
    # receivers report the last fix until the next one (zero-order hold)
    k = np.clip(np.floor(t_rel_s * gnss_rate_hz + 1e-9).astype(int), 0, t_fix.size - 1)
    return _coarse_to_fine(t_c, pose_c, t_rel_s), gnss_fix[k]


# ----------------------------------------------------------------------------- main

def simulate(
    duration_s: float = 600.0,
    rate_hz: float = 100.0,
    edit_every_s: float = 100.0,
    seed: int = 1,
    regime: str = "mixed",
    osm_path: str | None = None,
    origin: tuple[float, float, float] | EnuOrigin | None = None,
    gnss_columns: bool = True,
    gnss_rate_hz: float = 10.0,
    click_noise_m: float = 0.5,
    t0_s: float = DEFAULT_T0_S,
    progress: Callable[[str], None] | None = None,
) -> Simulation:
    """Simulate a drive (see the module docstring for the model).

    Parameters
    ----------
    duration_s, rate_hz : float
        Length of the drive in seconds and sample rate in Hz (``n = duration·rate + 1``).
    edit_every_s : float
        One edit every this many seconds, at (k + 1/2)·edit_every_s; 0 or less: none.
    seed : int
        Random seed; the same arguments give the same drive.
    regime : str
        One of ``REGIMES``.
    osm_path : str, optional
        OpenStreetMap extract to drive on; the origin is then the extract's centre.
    origin : (lat_deg, lon_deg, alt_m), optional
        Anchor of the synthetic path (default Helsinki centre); ignored with ``osm_path``.
    gnss_columns : bool
        Include the raw GNSS columns in the reported run.
    """
    if regime not in REGIMES:
        raise ValueError(f"unknown regime {regime!r} (known: {', '.join(REGIMES)})")
    if not (duration_s > 0 and rate_hz > 0 and gnss_rate_hz > 0):
        raise ValueError("duration_s, rate_hz and gnss_rate_hz must be positive")
    say = progress or (lambda _msg: None)
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz)) + 1
    t_rel = np.arange(n) / rate_hz
    length = V_MAX_MPS * duration_s * 1.05 + 200.0
    if osm_path is not None:
        say("reading the street graph")
        graph = load_osm_graph(osm_path)
        o = graph.origin
        say("routing")
        xy = _osm_path(rng, graph, length)
    else:
        o = as_origin(origin if origin is not None else DEFAULT_ORIGIN)
        xy = _synthetic_path(rng, length)
    say("sampling the truth")
    st = _truth_states(rng, xy, t_rel)
    p_true = np.column_stack([st["e"], st["n"], st["u"]])
    say("adding sensor errors")
    pose_err, gnss_err = _errors(rng, regime, t_rel, gnss_rate_hz)
    att_c = _ou(rng, int(duration_s) + 3, 1.0, 1.0, 300.0, 3) * np.radians([0.1, 0.1, 0.3])
    att_err = _coarse_to_fine(np.arange(att_c.shape[0], dtype=float), att_c, t_rel)

    lat_t, lon_t, alt_t = enu_to_geodetic(p_true, o)
    q_t = _quat_origin_to_local(_rpy_to_quat(st["roll"], st["pitch"], st["yaw"]), lat_t, lon_t, o)
    p_rep = p_true + pose_err
    lat_r, lon_r, alt_r = enu_to_geodetic(p_rep, o)
    q_r = _quat_origin_to_local(
        _rpy_to_quat(st["roll"] + att_err[:, 0], st["pitch"] + att_err[:, 1], st["yaw"] + att_err[:, 2]),
        lat_r, lon_r, o,
    )
    t_s = t0_s + t_rel
    truth = PoseRun(t_s=t_s, lat_deg=lat_t, lon_deg=lon_t, alt_m=alt_t, q_body_to_enu_wxyz=q_t,
                    extra={"speed_mps": st["speed"]}, source=f"simulated truth ({regime}, seed {seed})")
    gnss = {}
    if gnss_columns:
        g_lat, g_lon, g_alt = enu_to_geodetic(p_true + gnss_err, o)
        gnss = {"gnss_lat_deg": g_lat, "gnss_lon_deg": g_lon, "gnss_alt_m": g_alt}
    run = PoseRun(t_s=t_s, lat_deg=lat_r, lon_deg=lon_r, alt_m=alt_r, q_body_to_enu_wxyz=q_r,
                  source=f"simulated run ({regime}, seed {seed})", **gnss)
    edits: list[SimEdit] = []
    if edit_every_s > 0:
        t_edit = (np.arange(int(np.floor(duration_s / edit_every_s - 0.5)) + 1) + 0.5) * edit_every_s
        t_edit = t_edit[t_edit <= t_rel[-1]]
        idx = np.unique(np.clip(np.round(t_edit * rate_hz).astype(int), 0, n - 1))
        click = rng.standard_normal((idx.size, 2)) * click_noise_m
        p_edit = p_true[idx].copy()
        p_edit[:, :2] += click
        e_lat, e_lon, _ = enu_to_geodetic(p_edit, o)
        edits = [SimEdit(int(i), float(t_s[i]), float(a), float(b)) for i, a, b in zip(idx, e_lat, e_lon)]
    info = {
        "path_length_m": float(st["s"][-1] - st["s"][0]),
        "mean_speed_mps": float(st["speed"].mean()),
        "pose_error_rms_m": float(np.sqrt((pose_err[:, :2] ** 2).sum(axis=1).mean())),
        "gnss_error_rms_m": float(np.sqrt((gnss_err[:, :2] ** 2).sum(axis=1).mean())),
        "osm": osm_path,
    }
    return Simulation(truth=truth, run=run, edits=edits, regime=regime, origin=o, info=info)
