"""Map-matching benchmark on two real floors: ``python -m benchmarks.mapmatch [--quick]``.

Floors: site1/F1 and site2/F2 of the Indoor Location Competition 2.0 (two buildings whose
floor files are laid out differently). Walks: the folder ``$POSEFIX_SHARED_DATA`` names,
when it holds the floors' walks, else the few walks in the repository's data/ (a fresh
clone runs on those); the output names the walks it used.

Each floor's walks (sorted by file name) are split in two: the **tuning** part (even
positions) and the **held-out** part (odd positions). The tuning walks train the model
(heading bias, step-length scale, f1/f2 weights: ``train_model``) and are the floor's WiFi
**site survey** (``build_fingerprints``); held-out walks are never trained on and never in
a survey. Sections (columns):

  F tuning     the floor's tuning walks, tracked with the model trained on them (fingerprints
               of the OTHER tuning walks): what tuning can see
  F held-out   the floor's held-out walks, model and survey from its tuning walks
  F <- G       crosswise: F's held-out walks with the parameters learned on the OTHER floor's
               tuning walks (F's own graph; F's survey for the WiFi rows)
  F tuning <- G  (``--tuning-cross``) the crosswise case on F's tuning walks (leave-one-out
               survey, as in F tuning): where a rule meant to hold crosswise can be decided
               without looking at held-out walks

Rows (errors at the surveyed waypoints, metres):
  dead reckoning      the same steps from the known start, no map (the peer every row beats)
  known start         CRF, first waypoint given (left out of the errors); mean, p95
  live                the same run's online (filtered) positions
  unknown, no WiFi    CRF from a uniform start (all waypoints)
  unknown + WiFi      CRF from a uniform start with the survey's fingerprints
  WiFi alone          the survey's k-NN position of every scan against the straight-line truth;
                      split by whether the truth is within 3 m of a survey scan (coverage)
  converged           share of waypoints where the unknown-start posterior reports converged
                      (one mode holding >= 95 % of the walk-marginalised smoothed marginal's mass
                      and the reported 1σ at most 5 m: posefix.mapmatch.tracker.walk_modes;
                      never from the Viterbi path), the error there, and walks converged at
                      their last step
  2σ coverage         share of waypoints inside the reported 2σ ellipse (86 % if honest)
  ms/step             CPU time of one process for the online step (one core)

Positions are smoothed posterior means; the ellipse is the smoothed marginal's.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
FLOORS = {"site1/F1": "indoor-site1-F1", "site2/F2": "indoor-site2-F2"}
TARGET_KNOWN = (2.0, 4.0)  # mean, p95 (m)
TARGET_WIFI = 3.0  # unknown start with survey WiFi, mean (m)
TARGET_COVER = (0.81, 0.91)  # 2σ coverage, 86 % ± 5
TARGET_CONVERGED_COVER = 0.90
TARGET_MS = 2.0
# WiFi alone is split by how far the truth is from the nearest survey scan: k-NN can only
# answer a surveyed place, so beyond a few metres (a scan's own smear: 3 s of walking) its
# error is the survey's gap, not the fingerprint distance.
NEAR_SURVEY_M = 3.0


def data_root() -> tuple[Path, str]:
    """The full walk set when ``$POSEFIX_SHARED_DATA`` names one (both floors with walks), else
    the repository's data/: nothing outside the repository is read unless asked for."""
    env = os.environ.get("POSEFIX_SHARED_DATA")
    if env and all(any((Path(env) / d / "walks").glob("*.txt")) for d in FLOORS.values()):
        return Path(env), "shared data set"
    return REPO / "data", "repository data/ (no shared data set found)"


@dataclass
class Part:
    """Per-waypoint results of one section's walks (lists of per-walk arrays)."""

    err: dict = field(default_factory=lambda: {k: [] for k in ("a", "b", "live", "c", "d", "wifi", "wifi_near", "wifi_far")})
    m2: dict = field(default_factory=lambda: {k: [] for k in ("b", "c", "d")})
    conv: dict = field(default_factory=lambda: {k: [] for k in ("c", "d")})
    conv_end: dict = field(default_factory=lambda: {k: [] for k in ("c", "d")})
    ms: dict = field(default_factory=lambda: {k: [] for k in ("b", "c", "d")})
    walks: list = field(default_factory=list)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="at most 6 tuning and 6 held-out walks a floor; "
                    "learn only the heading bias and step scale")
    ap.add_argument("--no-unknown", action="store_true", help="skip the unknown-start rows (faster)")
    ap.add_argument("--figure", metavar="PNG", help="also draw one walk (floor, waypoints, DR, CRF, 2σ ellipses)")
    ap.add_argument("--no-browser", action="store_true", help="skip the browser tracker's block (benchmarks.browser_tracker)")
    ap.add_argument("--tuning-cross", action="store_true",
                    help="also track each floor's tuning walks with the other floor's parameters (F tuning <- G)")
    ap.add_argument("--suggest", action="store_true",
                    help="only time vehicle suggestions, road matcher beside grid (cache cleared vs repeated)")
    args = ap.parse_args(argv)
    if args.suggest:
        return bench_suggestions()

    from posefix.mapmatch import read_walk, train_model
    from posefix.mapmatch.api import build_model_report
    from posefix.mapmatch.model import model_bytes

    root, origin = data_root()
    print(f"posefix mapmatch benchmark; walks from the {origin}: {root}")
    floors = {}
    for name, d in FLOORS.items():
        files = sorted((root / d / "walks").glob("*.txt"))
        tune, held = files[0::2], files[1::2]
        if args.quick:
            tune, held = tune[:6], held[:6]
        t0 = time.perf_counter()
        base, report = build_model_report(root / d)
        build_s = time.perf_counter() - t0
        print(f"{name}: {base.graph.n_vertices} vertices at {base.graph.cell_m} m, model "
              f"{len(model_bytes(base)) / 1024:.1f} KiB, built in {build_s:.1f} s; {report.outline}")
        print(f"  tuning walks ({len(tune)}): {' '.join(f.stem[-8:] for f in tune)}")
        print(f"  held-out walks ({len(held)}): {' '.join(f.stem[-8:] for f in held)}")
        tw = [read_walk(f) for f in tune]
        t1 = time.perf_counter()
        trained, rep = train_model(base, tw, weights=not args.quick)
        print(f"  trained on its tuning walks in {time.perf_counter() - t1:.1f} s: {rep}")
        floors[name] = (base, trained, tw, [read_walk(f) for f in held])

    cols: dict[str, Part] = {}
    for name, (base, trained, tw, hw) in floors.items():
        print(f"{name} tuning part:", flush=True)
        cols[f"{name} tuning"] = run_part(trained, tw, None, tw, args, no_wifi_row=False)
        print(f"{name} held-out part:", flush=True)
        cols[f"{name} held-out"] = run_part(trained, hw, tw, None, args)
    for name, (base, _, tw, hw) in floors.items():
        other = next(n for n in floors if n != name)
        cross = transfer(floors[other][1], base)
        print(f"{name} held-out, parameters from {other}:", flush=True)
        cols[f"{name} <- {other}"] = run_part(cross, hw, tw, None, args, no_wifi_row=False)
        if args.tuning_cross:
            print(f"{name} tuning, parameters from {other}:", flush=True)
            cols[f"{name} tuning <- {other}"] = run_part(cross, tw, None, tw, args, no_wifi_row=False)
    print_table(cols, args)
    if args.figure:
        name = next(iter(floors))
        draw_figure(floors[name][1], floors[name][3][0], args.figure)
        print(f"figure -> {args.figure}")
    if not args.no_browser:
        # The device path: the same tracker in the browser (benchmarks/browser_tracker.py, its own module).
        from benchmarks.browser_tracker import print_browser_block

        print_browser_block(root / FLOORS["site1/F1"])
    return 0


def transfer(trained, base):
    """The parameters learned on one floor (step model, heading bias, weights, sigmas, beam) on
    another floor's graph."""
    return trained.with_(graph=base.graph)


def run_part(model, walks, survey, loo_survey, args, no_wifi_row: bool = True) -> Part:
    """Track ``walks``; WiFi fingerprints from ``survey`` (all of it) or, for the tuning part,
    from ``loo_survey`` minus the walk tracked. ``no_wifi_row``: also the unknown start without
    WiFi (the slowest row; it does not depend on the learned parameters beyond the heading)."""
    from posefix.mapmatch import track_walk
    from posefix.mapmatch.evaluate import evaluate_track
    from posefix.mapmatch.fingerprints import build_fingerprints

    part = Part()
    fp_all = build_fingerprints(survey) if survey else None
    if fp_all is not None:
        cap = f"a walk's WiFi counts at most {1 / fp_all.walk_corr:.1f} fixes" if fp_all.walk_corr > 0 else "not measured"
        print(f"  survey: {fp_all.p_xy_m.shape[0]} scans of {len(survey)} walks; f3 walk-long error correlation "
              f"ρ = {fp_all.walk_corr:.2f} ({cap})" + ("" if fp_all.f3_calibrated else f"; {fp_all.f3_note}"))
    for w in walks:
        if w.waypoints.shape[0] < 2:
            continue
        part.walks.append(Path(w.path).stem[-8:])
        start = tuple(w.waypoints[0, 1:3])
        rb = track_walk(model, w, start_xy_m=start)
        part.err["a"].append(evaluate_track(w.waypoints, rb.t_ms, rb.dr_xy_m, skip_first=True).err_wp_m)
        part.err["b"].append(evaluate_track(w.waypoints, rb.t_ms, rb.p_xy_m, skip_first=True).err_wp_m)
        part.err["live"].append(evaluate_track(w.waypoints, rb.t_ms, rb.online_xy_m, skip_first=True).err_wp_m)
        part.m2["b"].append(mahalanobis2_at_waypoints(w.waypoints, rb, skip_first=True))
        part.ms["b"].append((rb.time_per_step_s * 1000, len(rb.t_ms) - 1))
        if args.no_unknown:
            continue
        fp = fp_all if fp_all is not None else build_fingerprints([x for x in loo_survey if x is not w])
        if fp_all is None and not fp.f3_calibrated:  # the leave-one-out survey of the tuning part
            print(f"    {part.walks[-1]}: {fp.f3_note}")
        for key, f in ((("c", None),) if no_wifi_row else ()) + (("d", fp),):
            r = track_walk(model, w, start_xy_m=None, fingerprints=f)
            part.err[key].append(evaluate_track(w.waypoints, r.t_ms, r.p_xy_m).err_wp_m)
            part.m2[key].append(mahalanobis2_at_waypoints(w.waypoints, r))
            part.conv[key].append(r.converged[nearest_rows(r.t_ms, w.waypoints[:, 0])])
            part.conv_end[key].append(bool(r.converged[-1]))
            part.ms[key].append((r.time_per_step_s * 1000, len(r.t_ms) - 1))
        e_wifi, near = wifi_alone(fp, w)
        part.err["wifi"].append(e_wifi)
        part.err["wifi_near"].append(e_wifi[near <= NEAR_SURVEY_M])
        part.err["wifi_far"].append(e_wifi[near > NEAR_SURVEY_M])
        c_txt = f"unknown {part.err['c'][-1].mean():6.2f} m, " if no_wifi_row else ""
        print(f"    {part.walks[-1]}: known {part.err['b'][-1].mean():5.2f} m, {c_txt}"
              f"+WiFi {part.err['d'][-1].mean():6.2f} m (converged at the end: {part.conv_end['d'][-1]})", flush=True)
    return part


def nearest_rows(t_ms: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Index of the track row nearest in time to each query time."""
    t = np.asarray(t_ms, dtype=float)
    i = np.clip(np.searchsorted(t, t_query), 1, max(t.size - 1, 1))
    if t.size == 1:
        return np.zeros(len(t_query), dtype=int)
    return np.where(np.abs(t[i - 1] - t_query) <= np.abs(t[i] - t_query), i - 1, i)


def _cat(xs) -> np.ndarray:
    return np.concatenate(xs) if xs else np.zeros(0)


def _fmt(v: float, unit: str = "") -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.2f}{unit}"


def summary_rows(p: Part) -> list[tuple[str, str]]:
    """(label, value) rows of one section."""
    def mp(k):
        e = _cat(p.err[k])
        return f"{_fmt(e.mean())} / {_fmt(np.percentile(e, 95))}" if e.size else "-"

    def cover(k, sel=None):
        m2 = _cat(p.m2[k])
        if sel is not None:
            m2 = m2[sel]
        return f"{100 * np.mean(m2 <= 4.0):.0f} % (n {m2.size})" if m2.size else "-"

    def ms(k):
        n = sum(x for _, x in p.ms[k])
        return _fmt(sum(a * x for a, x in p.ms[k]) / n) if n else "-"

    rows = [("walks / waypoints scored", f"{len(p.walks)} / {_cat(p.err['b']).size}"),
            ("dead reckoning, mean / p95", mp("a")), ("known start, mean / p95", mp("b")),
            ("known start, live, mean / p95", mp("live")),
            ("unknown, no WiFi, mean / p95", mp("c")), ("unknown + WiFi, mean / p95", mp("d")),
            ("WiFi alone per scan, mean / p95", mp("wifi")),
            (f"  truth <= {NEAR_SURVEY_M:.0f} m from a survey scan: share, mean", near_far(p, "wifi_near")),
            ("  farther: share, mean", near_far(p, "wifi_far"))]
    for k, lab in (("c", "no WiFi"), ("d", "+ WiFi")):
        conv = _cat(p.conv[k]).astype(bool)
        if conv.size:
            e = _cat(p.err[k])[conv]
            rows.append((f"converged {lab}: waypoints, err, walks",
                         f"{100 * conv.mean():.0f} %, {_fmt(e.mean() if e.size else np.nan)} m, "
                         f"{sum(p.conv_end[k])}/{len(p.conv_end[k])}"))
    rows.append(("2σ coverage known start", cover("b")))
    for k, lab in (("d", "+ WiFi"), ("c", "no WiFi")):
        conv = _cat(p.conv[k]).astype(bool)
        if conv.size:
            rows.append((f"2σ coverage unknown {lab}, all", cover(k)))
            rows.append((f"2σ coverage unknown {lab}, converged", cover(k, conv) if conv.any() else "-"))
    rows.append(("ms/step online known / unknown / +WiFi", " / ".join(ms(k) for k in "bcd")))
    return rows


def near_far(p: Part, k: str) -> str:
    """Share of the WiFi-alone scans in this group, and their mean error."""
    e, n = _cat(p.err[k]), _cat(p.err["wifi"]).size
    return f"{100 * e.size / n:.0f} %, {_fmt(e.mean())}" if e.size and n else "-"


def print_table(cols: dict[str, Part], args) -> None:
    names = list(cols)
    table = [summary_rows(cols[n]) for n in names]
    labels = [lab for lab, _ in max(table, key=len)]
    w0 = max(len(x) for x in labels) + 2
    widths = [max(len(n), *(len(v) for _, v in t)) + 2 for n, t in zip(names, table)]
    print()
    print(" " * w0 + "".join(n.rjust(w) for n, w in zip(names, widths)))
    print("-" * (w0 + sum(widths)))
    for lab in labels:
        vals = [dict(t).get(lab, "") for t in table]
        print(lab.ljust(w0) + "".join(v.rjust(w) for v, w in zip(vals, widths)))
    print()
    print("Targets on held-out walks and floors (ratio = ours ÷ target; > 1 misses):")
    for n in names:
        if "tuning" in n:
            continue
        p = cols[n]
        b, a = _cat(p.err["b"]), _cat(p.err["a"])
        line = (f"  {n}: known start mean {b.mean():.2f} m ({b.mean() / TARGET_KNOWN[0]:.2f}x), "
                f"p95 {np.percentile(b, 95):.2f} m ({np.percentile(b, 95) / TARGET_KNOWN[1]:.2f}x); "
                f"dead reckoning {a.mean():.2f} m (known start ÷ it: {b.mean() / a.mean():.2f})")
        d = _cat(p.err["d"])
        if d.size:
            line += f"; unknown + WiFi {d.mean():.2f} m ({d.mean() / TARGET_WIFI:.2f}x)"
        m2 = np.concatenate([_cat(p.m2["b"]), _cat(p.m2["d"])])
        line += f"; 2σ coverage (known + unknown with WiFi) {100 * np.mean(m2 <= 4.0):.0f} % (86 ± 5)"
        conv = _cat(p.conv["d"]).astype(bool)
        if conv.any():
            line += f", converged {100 * np.mean(_cat(p.m2['d'])[conv] <= 4.0):.0f} % (≥ 90)"
        ms = [a for k in "bcd" for a, _ in p.ms[k]]
        line += f"; worst walk's ms/step {max(ms):.2f} ({max(ms) / TARGET_MS:.2f}x)"
        print(line)


def bench_suggestions(repeats: int = 3) -> int:
    """Vehicle suggestions, road matcher (the default) beside the grid, on simulated Helsinki
    drives at 10 Hz with keyframes one per second: the demo's (600 s, seed 2019; the drive both
    matchers were developed on) and a held-out one (600 s, seed 7, never used for tuning).
    Wall-clock median of ``repeats`` calls of ``suggest_vehicle_run``, once with every cache
    cleared before the call (first call on a new area) and once repeated (network or drivable
    area cached), with the ratio roads / grid."""
    from posefix.core.simulate import simulate
    from posefix.mapmatch.suggest import drivable_cache_info
    from posefix.roads import network as road_network_module
    from posefix.roads.suggest import suggest_vehicle_run

    osm = Path(__file__).resolve().parents[1] / "data" / "osm" / "helsinki.osm.pbf"
    print(f"vehicle suggestions, roads vs grid; median of {repeats}; load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs")
    print(f"  {'drive':<26}{'cache':<10}{'roads (s)':>10}{'grid (s)':>10}{'ratio':>7}{'roads kf/s':>12}{'grid kf/s':>11}")
    for label, seed in (("demo, seed 2019 (tuned)", 2019), ("seed 7 (held out)", 7)):
        run = simulate(duration_s=600.0, rate_hz=10.0, osm_path=str(osm), seed=seed, edit_every_s=0).run
        idx = np.arange(0, run.n, 10)
        args = (run.lon_deg[idx], run.lat_deg[idx], run.q_body_to_enu_wxyz[idx], osm)
        times: dict[tuple[str, str], list[float]] = {}
        answered = {}
        for _ in range(repeats):
            for matcher in ("roads", "grid"):
                drivable_cache_info(clear=True)
                road_network_module._cache.clear()
                for cache in ("cleared", "repeated"):
                    t0 = time.perf_counter()
                    sug = suggest_vehicle_run(*args, t_s=run.t_s[idx], matcher=matcher)
                    times.setdefault((matcher, cache), []).append(time.perf_counter() - t0)
                    answered[matcher] = sug.matcher
        for cache in ("cleared", "repeated"):
            r = float(np.median(times[("roads", cache)]))
            g = float(np.median(times[("grid", cache)]))
            print(f"  {label:<26}{cache:<10}{r:>10.3f}{g:>10.2f}{r / g:>7.3f}{idx.size / r:>12,.0f}{idx.size / g:>11,.0f}")
        if answered["roads"] != "roads":
            print(f"  (the road matcher handed {label} to the {answered['roads']} matcher)")
        print(f"  {'':<26}{idx.size} keyframes")
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
    """:func:`posefix.mapmatch.evaluate.mahalanobis2_at_waypoints` (its one home)."""
    from posefix.mapmatch.evaluate import mahalanobis2_at_waypoints as m2

    return m2(waypoints, res, skip_first=skip_first)


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
