"""Map-matching benchmark on the shared indoor floor: ``python -m benchmarks.mapmatch [--quick]``.

Rows (error at the surveyed waypoints, metres):
  (a) dead reckoning from the known start (same steps, step model and heading bias)
  (b) CRF, known start           (first waypoint given; it is left out of the errors)
  (b') the same run's online positions (each step's best vertex given only the past:
       what a live session shows), against the same targets
  (b+w) (b) with the WiFi of (d) added: a check of the fusion, not a target. The known
       start already places the walk better than any WiFi fix, so a fusion that weighs
       WiFi honestly leaves (b) about unchanged; an excess over (b) is WiFi (f3, f4)
       evidence counted as stronger than it is. Scans are discounted for their correlation
       in time (τ = the model's wifi_corr_s, 20 s; ``--wifi-corr-s 0`` counts every scan as
       independent, the behaviour before the discount)
  (c) CRF, unknown start         (uniform over all reachable vertices; all waypoints)
  (d) CRF + WiFi, unknown start  (fingerprints built from the OTHER walks: leave-one-out)
  WiFi alone: the k-NN position of every scan (between the first and last waypoint) of the
       walk, from the same leave-one-out fingerprints, against the straight-line position
       at the scan's time (errors per scan, not per waypoint)
  floor centroid (reference for (c)/(d)): one constant answer, the mean of all walkable
       vertices, for every waypoint: what "no information at all" scores on this floor
Below the table, for (c): the median 1σ major semi-axis of the smoothed start marginal
p(y_0 | whole walk): how many metres the walk's shape leaves the start undetermined; for
(d): a 90 % interval of its mean with the walks resampled (how much the figure depends on
which walks are in the set); for (d) and WiFi alone: the error split by how far the truth is from the
nearest scan of the other walks (the survey's coverage); for (b), (b+w) and (d): whether the
reported ellipses are honest — the share of waypoints inside their 2σ ellipse (86 % for a
calibrated Gaussian; less = overconfident) and the median squared Mahalanobis distance of
the error (1.39).

Parameters are never fitted on the walk being scored: two folds (even / odd walks), each
tracked with the heading bias and the f1/f2 weights learned on the other fold. ``--quick``
uses every third walk and learns only the heading bias. Positions are the smoothed
posterior means (forward-backward); time per step is CPU time of one process (one core):
"online" the tracker's step, "offline" with the back-track and smoothing. Model size is
the device file (.npz).

Data: the full floor (30 walks) at $POSEFIX_SHARED_DATA/indoor-site1-F1 or ../shared/data/indoor-site1-F1
when present; otherwise the repository's data/indoor-site1-F1 (3 walks: the run works on a fresh
clone, the figures are then only indicative).
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

TARGETS = {"b": (2.0, 4.0), "c": (3.0, None), "d": (3.0, None)}
TARGET_MS_PER_STEP = 2.0
NAIVE_PDR = (4.4, 8.8)  # README: fixed 0.7 m stride, rotation-vector heading, no map


def floor_dir() -> Path:
    """The full floor when it is beside the repository, else the repository's 3-walk copy."""
    repo = Path(__file__).resolve().parents[1]
    env = os.environ.get("POSEFIX_SHARED_DATA")
    full = Path(env) if env else repo.parent / "shared" / "data"
    if (full / "indoor-site1-F1" / "walks").is_dir():
        return full / "indoor-site1-F1"
    print(f"note: no full floor at {full}; using the repository's data/indoor-site1-F1 (3 walks)", file=sys.stderr)
    return repo / "data" / "indoor-site1-F1"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="every third walk; learn only the heading bias")
    ap.add_argument("--figure", metavar="PNG", help="also draw one walk (floor, waypoints, DR, CRF, 2σ ellipses)")
    ap.add_argument("--wifi-corr-s", type=float, metavar="S", default=None,
                    help="correlation time of WiFi errors for the discount of f3/f4 (s; default the "
                         "model's, 20; 0 = every scan independent, the behaviour before the discount)")
    ap.add_argument("--no-browser", action="store_true", help="skip the browser tracker's block (benchmarks.browser_tracker)")
    ap.add_argument("--suggest", action="store_true",
                    help="only time suggestions on the demo's 10 min drive (cache cleared vs repeated)")
    args = ap.parse_args(argv)
    if args.suggest:
        return bench_suggestions()

    from posefix.mapmatch import build_model, read_walk, track_walk, train_model
    from posefix.mapmatch.evaluate import evaluate_track, summarise
    from posefix.mapmatch.fingerprints import build_fingerprints
    from posefix.mapmatch.model import model_bytes

    floor = floor_dir()
    files = sorted(glob.glob(str(floor / "walks" / "*.txt")))
    if not files:
        print(f"error: no walks under {floor}/walks ", file=sys.stderr)
        return 1
    if args.quick:
        files = files[::3]
    walks = [read_walk(f) for f in files]
    t0 = time.perf_counter()
    base = build_model(floor)
    build_s = time.perf_counter() - t0
    size_kib = len(model_bytes(base)) / 1024

    folds = [list(range(0, len(walks), 2)), list(range(1, len(walks), 2))]
    errs = {k: [] for k in ("a", "b", "b_online", "b_wifi", "c", "d", "wifi", "centroid")}
    maha2 = {k: [] for k in ("b", "b_wifi", "d")}  # squared Mahalanobis distance of each waypoint's error
    cover = {"d": [], "wifi": []}  # distance (m) from the truth to the nearest other-walk scan
    start_sigma_c = []
    ms = {k: [] for k in "bcd"}
    reports = []
    for i, fold in enumerate(folds):
        other = [walks[j] for j in folds[1 - i]]
        t1 = time.perf_counter()
        model, rep = train_model(base, other, heading_bias=True, step_em=False, weights=not args.quick)
        if args.wifi_corr_s is not None:
            model = model.with_(sigmas=replace(model.sigmas, wifi_corr_s=args.wifi_corr_s))
        reports.append((rep, time.perf_counter() - t1))
        for j in fold:
            w = walks[j]
            start = tuple(w.waypoints[0, 1:3])
            rb = track_walk(model, w, start_xy_m=start)
            errs["a"].append(evaluate_track(w.waypoints, rb.t_ms, rb.dr_xy_m, skip_first=True).err_wp_m)
            errs["b"].append(evaluate_track(w.waypoints, rb.t_ms, rb.p_xy_m, skip_first=True).err_wp_m)
            errs["b_online"].append(evaluate_track(w.waypoints, rb.t_ms, rb.online_xy_m, skip_first=True).err_wp_m)
            rc = track_walk(model, w, start_xy_m=None)
            errs["c"].append(evaluate_track(w.waypoints, rc.t_ms, rc.p_xy_m).err_wp_m)
            start_sigma_c.append(rc.sigma_major_m[0])
            errs["centroid"].append(np.linalg.norm(w.waypoints[:, 1:3] - base.graph.p_xy_m.mean(axis=0), axis=1))
            fp = build_fingerprints([x for k, x in enumerate(walks) if k != j])
            rd = track_walk(model, w, start_xy_m=None, fingerprints=fp)
            rbw = track_walk(model, w, start_xy_m=start, fingerprints=fp)
            errs["b_wifi"].append(evaluate_track(w.waypoints, rbw.t_ms, rbw.p_xy_m, skip_first=True).err_wp_m)
            errs["d"].append(evaluate_track(w.waypoints, rd.t_ms, rd.p_xy_m).err_wp_m)
            for k, r, skip in (("b", rb, True), ("b_wifi", rbw, True), ("d", rd, False)):
                maha2[k].append(mahalanobis2_at_waypoints(w.waypoints, r, skip_first=skip))
            cover["d"].append(nearest_m(w.waypoints[:, 1:3], fp.p_xy_m))
            e_w, c_w = wifi_alone(fp, w)
            errs["wifi"].append(e_w)
            cover["wifi"].append(c_w)
            for k, r in (("b", rb), ("c", rc), ("d", rd)):
                ms[k].append((r.time_per_step_s * 1000, r.offline_time_per_step_s * 1000, max(len(r.t_ms) - 1, 1)))
            print(f"  walk {Path(w.path).stem[-8:]}: b {errs['b'][-1].mean() if errs['b'][-1].size else float('nan'):5.2f} m"
                  f"  c {errs['c'][-1].mean():6.2f} m  d {errs['d'][-1].mean():6.2f} m", flush=True)

    def ratio(v, t):
        return f"{v:6.2f} ({v / t:4.2f}×)" if t else f"{v:6.2f}        "

    labels = {"a": "(a) dead reckoning, known start", "b": "(b) CRF, known start",
              "b_online": "(b') same, online (filtered, live)",
              "b_wifi": "(b+w) (b) + WiFi: fusion check",
              "c": "(c) CRF, unknown start", "d": "(d) CRF + WiFi (leave-one-out)",
              "wifi": "WiFi alone, per scan (k-NN, l-o-o)",
              "centroid": "floor centroid (no information)"}
    print()
    print(f"posefix mapmatch benchmark: {len(walks)} walks, indoor-site1-F1, {base.graph.n_vertices} vertices "
          f"at {base.graph.cell_m} m; model {size_kib:.1f} KiB, built in {build_s:.2f} s")
    for i, (rep, dt) in enumerate(reports):
        print(f"  fold {i}: trained on {len(folds[1 - i])} walks in {dt:.1f} s: {rep}")
    print()
    hdr = (f"{'':34s} {'n':>4s}  {'mean m (÷target)':>17s}  {'p95 m (÷target)':>17s}  "
           f"{'online ms/step (÷2.0)':>21s}  {'offline ms/step':>15s}")
    print(hdr)
    print("-" * len(hdr))
    for k in ("a", "b", "b_online", "b_wifi", "c", "d", "wifi", "centroid"):
        s = summarise(errs[k])
        tm, tp = TARGETS.get(k[0] if k not in ("a", "centroid", "wifi", "b_wifi") else k, (None, None))
        if k in ms:
            n_all = sum(n for _, _, n in ms[k])
            on = sum(a * n for a, _, n in ms[k]) / n_all
            off = sum(b * n for _, b, n in ms[k]) / n_all
            t_txt = f"{on:6.2f} ({on / TARGET_MS_PER_STEP:4.2f}×)"
            o_txt = f"{off:6.2f}"
        else:
            t_txt = o_txt = ""
        print(f"{labels[k]:34s} {s['n']:4d}  {ratio(s['mean_m'], tm):>17s}  {ratio(s['p95_m'], tp):>17s}  "
              f"{t_txt:>21s}  {o_txt:>15s}")
    print(f"{'README naive PDR (reference)':34s} {'':4s}  {NAIVE_PDR[0]:6.2f}{'':11s}  {NAIVE_PDR[1]:6.2f}")
    sc = np.asarray(start_sigma_c)
    print(f"(c) start left undetermined by the walk's shape: smoothed start marginal p(y_0 | walk) has a 1σ "
          f"major semi-axis of median {np.median(sc):.1f} m; under 3 m in {np.sum(sc < 3.0)} of {sc.size} walks")
    lo_d, hi_d = walk_bootstrap(errs["d"])
    print(f"(d) mean with the {len(errs['d'])} walks resampled with replacement: 90 % interval "
          f"{lo_d:.2f}-{hi_d:.2f} m (which walks are in the set moves the mean this much)")
    honest = []
    for k in ("b", "b_wifi", "d"):
        m2 = np.concatenate(maha2[k])
        honest.append(f"{k.replace('_wifi', '+w')} {100 * np.mean(m2 <= 4.0):.0f} % (median {np.median(m2):.2f})")
    tau = model.sigmas.wifi_corr_s
    print(f"ellipses, share of waypoints inside their 2σ ellipse (86 % if honest; median squared Mahalanobis "
          f"distance, 1.39 if honest): " + ", ".join(honest)
          + f"; WiFi discount τ = {tau:g} s" + (" (scans independent)" if tau == 0 else ""))
    for k in ("d", "wifi"):
        e, c = np.concatenate(errs[k]), np.concatenate(cover[k])
        parts = []
        for lo, hi in ((0.0, 3.0), (3.0, 12.0), (12.0, np.inf)):
            sel = (c >= lo) & (c < hi)
            if sel.any():
                parts.append(f"{lo:g}-{hi:g} m: n {sel.sum()}, mean {e[sel].mean():.2f} m")
        print(f"{labels[k].split(' (')[0]}, by distance from the truth to the nearest other-walk scan: " + "; ".join(parts))
    if args.figure:
        draw_figure(base, walks[0], args.figure)
        print(f"figure -> {args.figure}")
    print("\nTargets: (b) mean ≤ 2.0 m, p95 ≤ 4.0 m; (c)/(d) mean ≤ 3.0 m; ≤ 2 ms per step. Ratio > 1 misses the target.")
    if not args.no_browser:
        # The device path: the same tracker in the browser (benchmarks/browser_tracker.py, its own module).
        from benchmarks.browser_tracker import print_browser_block

        print_browser_block(floor)
    return 0


def bench_suggestions(repeats: int = 3) -> int:
    """Suggestions for the demo drive (posefix demo: 600 s at 10 Hz through Helsinki, seed 2019;
    keyframes one per second): wall-clock of ``suggest_for_run`` with the drivable-area cache
    cleared before each call (what every call cost before the cache) against repeated calls."""
    from posefix.core.simulate import simulate
    from posefix.mapmatch import suggest_for_run
    from posefix.mapmatch.suggest import drivable_cache_info

    osm = Path(__file__).resolve().parents[1] / "data" / "osm" / "helsinki.osm.pbf"
    run = simulate(duration_s=600.0, rate_hz=10.0, osm_path=str(osm), seed=2019, edit_every_s=0).run
    idx = np.arange(0, run.n, 10)
    args = (run.lon_deg[idx], run.lat_deg[idx], run.q_body_to_enu_wxyz[idx], osm)
    cold, warm = [], []
    for _ in range(repeats):
        drivable_cache_info(clear=True)
        t0 = time.perf_counter()
        sug = suggest_for_run(*args)
        cold.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        suggest_for_run(*args)
        warm.append(time.perf_counter() - t0)
    c, w = float(np.median(cold)), float(np.median(warm))
    print(f"suggestions, demo drive: {idx.size} keyframes, {sug.n_vertices} vertices at 2 m; median of {repeats}")
    print(f"  cache cleared (rebuild every call, the old behaviour): {c:6.2f} s")
    print(f"  repeated (drivable area cached):                       {w:6.2f} s  ({w / c:4.2f}× the rebuild)")
    return 0


def walk_bootstrap(errors: list[np.ndarray], n_boot: int = 2000, seed: int = 0) -> tuple[float, float]:
    """5 and 95 % points of the pooled waypoint mean when the walks (each an array of its
    waypoint errors) are resampled with replacement: how much the mean moves with which walks
    happen to be in the set (walks differ far more than waypoints within a walk)."""
    sums = np.array([e.sum() for e in errors])
    counts = np.array([e.size for e in errors])
    idx = np.random.default_rng(seed).integers(0, len(errors), size=(n_boot, len(errors)))
    means = sums[idx].sum(axis=1) / np.maximum(counts[idx].sum(axis=1), 1)
    return float(np.percentile(means, 5)), float(np.percentile(means, 95))


def mahalanobis2_at_waypoints(waypoints: np.ndarray, res, skip_first: bool = False) -> np.ndarray:
    """Squared Mahalanobis distance (w,) of each waypoint's error under the reported ellipse:
    the track interpolated at the waypoint's time (as the error is measured) against the
    covariance of the track row nearest in time, rebuilt from its 1σ semi-axes and angle.
    A calibrated 2-D Gaussian gives a χ²₂: median 1.39, 86 % within 4 (the 2σ ellipse)."""
    from posefix.mapmatch.evaluate import interpolate_xy

    wp = np.asarray(waypoints, dtype=float)
    t = np.asarray(res.t_ms, dtype=float)
    err = interpolate_xy(wp[:, 0], t, res.p_xy_m) - wp[:, 1:3]
    i = np.clip(np.searchsorted(t, wp[:, 0]), 1, t.size - 1)
    i = np.where(np.abs(t[i - 1] - wp[:, 0]) <= np.abs(t[i] - wp[:, 0]), i - 1, i) if t.size > 1 else np.zeros_like(i)
    a = np.radians(res.angle_deg[i])
    u = np.stack([np.cos(a), np.sin(a)], axis=1)  # major axis
    v = np.stack([-np.sin(a), np.cos(a)], axis=1)
    m2 = (np.sum(err * u, axis=1) / res.sigma_major_m[i]) ** 2 + (np.sum(err * v, axis=1) / res.sigma_minor_m[i]) ** 2
    return m2[1:] if skip_first else m2


def nearest_m(p_xy_m: np.ndarray, survey_xy_m: np.ndarray) -> np.ndarray:
    """Distance (n,) from each point to the nearest survey position."""
    return np.min(np.linalg.norm(p_xy_m[:, None, :] - survey_xy_m[None, :, :], axis=2), axis=1)


def wifi_alone(fp, walk) -> tuple[np.ndarray, np.ndarray]:
    """Errors (m) of the fingerprint map's position for each scan of ``walk`` within its
    waypoint span (truth: the straight line between waypoints at the scan's time), and the
    truth's distance to the nearest survey position."""
    from posefix.mapmatch.evaluate import interpolate_xy
    from posefix.mapmatch.sensors import wifi_scans

    wp = walk.waypoints
    err, truth = [], []
    for t_ms, scan in wifi_scans(walk, fp.max_age_ms, fp.scan_time):
        if not wp[0, 0] <= t_ms <= wp[-1, 0]:
            continue
        r = fp.predict(scan)
        if r is None:
            continue
        q = interpolate_xy(t_ms, wp[:, 0], wp[:, 1:3])[0]
        err.append(float(np.linalg.norm(r[0] - q)))
        truth.append(q)
    if not err:
        return np.zeros(0), np.zeros(0)
    return np.asarray(err), nearest_m(np.asarray(truth), fp.p_xy_m)


def draw_figure(model, walk, path: str) -> None:
    """One walk on the floor: walkable cells, waypoints, dead reckoning, live and smoothed
    matched tracks, 2σ ellipses of the smoothed marginals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    from posefix.mapmatch import track_walk

    res = track_walk(model, walk, start_xy_m=tuple(walk.waypoints[0, 1:3]))
    p = model.graph.p_xy_m
    fig, ax = plt.subplots(figsize=(7, 5.2))
    ax.plot(p[:, 0], p[:, 1], ".", color="0.8", ms=2, label="graph vertices (0.8 m)")
    ax.plot(res.dr_xy_m[:, 0], res.dr_xy_m[:, 1], "-", color="tab:blue", lw=1, label="dead reckoning")
    ax.plot(res.online_xy_m[:, 0], res.online_xy_m[:, 1], "--", color="tab:orange", lw=1,
            label="CRF live (filtered mean)")
    ax.plot(res.p_xy_m[:, 0], res.p_xy_m[:, 1], "-", color="tab:red", lw=1.5, label="CRF (smoothed mean)")
    for i in range(0, len(res.t_ms), 6):
        ax.add_patch(Ellipse(res.p_xy_m[i], 4 * res.sigma_major_m[i], 4 * res.sigma_minor_m[i],
                             angle=res.angle_deg[i], fill=False, color="tab:red", lw=0.6))
    wp = walk.waypoints
    ax.plot(wp[:, 1], wp[:, 2], "ko", ms=4, label="surveyed waypoints")
    allp = np.vstack([wp[:, 1:3], res.p_xy_m, res.dr_xy_m])
    lo, hi = allp.min(axis=0) - 6, allp.max(axis=0) + 6
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, floor frame)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{Path(walk.path).stem}: known start, 2σ ellipses every 6 steps")
    ax.legend(loc="best", fontsize=8)
    fig.savefig(path, dpi=80, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
