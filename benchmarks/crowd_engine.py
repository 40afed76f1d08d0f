"""The engine's part of the crowd benchmark, without the API: does correcting fused clicks beat
correcting the best operator's own, and does the fused position's sigma (``Edit.sigma_m``) help?

    python -m benchmarks.crowd_engine [--seeds 1,2,3,4,5,6,7,8,9,10,11,12] [--tuned 1,2,5,6] [--runs 6]

The drives of ``benchmarks.crowd`` (the same simulator seeds: ``seed * 100 + crowd * 10 + i``,
180 s at 5 Hz).  Per drive three honest operators place every 5th keyframe (and the last) at
the truth plus Gaussian noise per axis: crowd A three of 0.5, 1, 2, 2, 4, 8 m drawn per drive,
crowd B 0.5, 1 and 2 m (what the accuracy requirement admits).  The clicks are fused by inverse
variance with the true scales (the oracle weights the crowd pipeline estimates; its fusion
is within about 0.02 of them), so what is left is the engine's: each operator's clicks
corrected alone (the best of the three is "best single"), and the fused clicks corrected as
ordinary edits (the configured sigma) and carrying their fused sigma ``1 / sqrt(sum 1/s_i^2)``.
Keyframe RMSE against the truth, the ratio to the best single per seed, the unweighted median
of the per-seed ratios, and how often each fused correction chose naive interpolation;
tuned and held-out seeds apart.  About 10 s a seed on an idle core.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import statistics
import time

import numpy as np

from posefix.core.simulate import simulate
from posefix.engine import Edit, Edits, prepare

R_EARTH = 6371008.8
SKILLS = [0.5, 1.0, 2.0, 2.0, 4.0, 8.0]
ADMITTED = (0.5, 1.0, 2.0)


def _en(lon, lat, lon0: float, lat0: float) -> np.ndarray:
    return np.column_stack([np.radians(np.asarray(lon) - lon0) * R_EARTH * np.cos(np.radians(lat0)),
                            np.radians(np.asarray(lat) - lat0) * R_EARTH])


def drive(seed: int, crowd: int, i: int, skills: tuple[float, ...], rng: np.random.Generator) -> dict:
    sim = simulate(duration_s=180.0, rate_hz=5.0, edit_every_s=0, seed=seed * 100 + crowd * 10 + i)
    problem = prepare(sim.run)
    t = sim.run.t_s[problem.keyframe_index]
    lon_t, lat_t = np.interp(t, sim.truth.t_s, sim.truth.lon_deg), np.interp(t, sim.truth.t_s, sim.truth.lat_deg)
    lon0, lat0 = float(lon_t[0]), float(lat_t[0])
    truth = _en(lon_t, lat_t, lon0, lat0)
    ks = sorted(set(range(0, len(t), 5)) | {len(t) - 1})

    def edits(x_m: np.ndarray, sigma: float | None = None) -> Edits:
        lon = lon0 + np.degrees(x_m[:, 0] / (R_EARTH * np.cos(np.radians(lat0))))
        lat = lat0 + np.degrees(x_m[:, 1] / R_EARTH)
        return Edits(tuple(Edit(k, float(a), float(b), None, sigma) for k, a, b in zip(ks, lon, lat)))

    def rmse(es: Edits) -> tuple[float, str]:
        sol = problem.solve_edits(es)
        lon, lat, _ = problem.lonlatalt(sol)
        return float(np.sqrt(np.mean(np.sum((_en(lon, lat, lon0, lat0) - truth) ** 2, axis=1)))), sol.drift.calibration.model

    clicks = [truth[ks] + rng.normal(0.0, s, (len(ks), 2)) for s in skills]
    w = np.array([1.0 / s**2 for s in skills])
    fused = sum(wi * c for wi, c in zip(w, clicks)) / w.sum()
    return {"seed": seed, "crowd": "AB"[crowd], "best": min(rmse(edits(c))[0] for c in clicks),
            "plain": rmse(edits(fused)), "sigma": rmse(edits(fused, float(1.0 / np.sqrt(w.sum()))))}


def summary(label: str, rows: list[dict]) -> None:
    for crowd in "AB":
        rs = [r for r in rows if r["crowd"] == crowd]
        if not rs:
            continue
        best = statistics.mean(r["best"] for r in rs)
        print(f"  {label} {crowd} ({len(rs)} drives): best single {best:.3f} m")
        for how, title in (("plain", "fused, as ordinary edits"), ("sigma", "fused, carrying their sigma")):
            seeds = sorted({r["seed"] for r in rs})
            per = {s: statistics.mean(r[how][0] for r in rs if r["seed"] == s) / statistics.mean(r["best"] for r in rs if r["seed"] == s)
                   for s in seeds}
            m = statistics.mean(r[how][0] for r in rs)
            naive = sum(r[how][1] == "naive" for r in rs)
            print(f"    {title:<28} {m:.3f} m (ratio {m / best:.3f}; per seed {' '.join(f'{s}:{v:.2f}' for s, v in per.items())}; "
                  f"median {statistics.median(per.values()):.3f}); naive chosen {naive}/{len(rs)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3,4,5,6,7,8,9,10,11,12")
    ap.add_argument("--tuned", default="1,2,5,6", help="seeds used while tuning (reported apart)")
    ap.add_argument("--runs", type=int, default=6)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s]
    tuned = {int(s) for s in args.tuned.split(",") if s}
    started = time.perf_counter()
    rows = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        for crowd in (0, 1):
            for i in range(args.runs):
                skills = ADMITTED if crowd else tuple(sorted(rng.choice(SKILLS, 3, replace=False)))
                rows.append(drive(seed, crowd, i, skills, rng))
    print("Keyframe RMSE against the truth, mean over drives; ratio to the best single operator corrected alone")
    summary("tuned seeds", [r for r in rows if r["seed"] in tuned])
    summary("held-out seeds", [r for r in rows if r["seed"] not in tuned])
    print(f"{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
