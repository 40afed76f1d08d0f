"""Each candidate model of ``engine.calibrate`` on the held-out benchmark's runs: its true RMSE,
its cross-validated RMSE at the edits, and what a convex combination of the candidates would do.

    python -m benchmarks.engine_candidates [--seeds 11,12,13] [--heldout]

Without ``--heldout`` only the tuned families (``engine_heldout.TUNED``) are run, at the seeds
given: the part a change to the choice may be looked at on.  ``--heldout`` adds the held-out
half and the real drives, printed apart.  Per run and candidate (gnss, plain, relative, naive):

    true: horizontal RMSE against the truth over every sample (edits every L seconds);
    CV:   RMSE of the leave-one-edit-out residuals (each a prediction across a gap of 2L),
          as ``engine.choose`` computes them;
    ratio = true / CV: what the run-wide RMSE is of the held-out one.  The choice assumes this
          ratio is alike across candidates (``calibrate.model_scale``); the reported prediction
          is the chosen model's CV times R, the ratio the pose's fitted error process gives for
          linear interpolation at the real spacing (``calibrate.spacing_ratio``, printed as R).

and two alternatives to choosing one candidate:

    stack: weights w on the simplex minimising the held-out squared error
           sum_k |sum_m w_m r_k,m|^2 (grid step 0.05), the run's estimate sum_m w_m p_m;
    best blend (oracle): the best w p_model + (1 - w) p_naive against the truth, for scale.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from benchmarks.engine import edit_set
from benchmarks.engine_heldout import COMMA_SPACINGS_S, HELD_OUT, SPACINGS_S, TUNED, at_most, comma_case, nagoya_case
from posefix.core import geodesy
from posefix.core.families import simulate_family
from posefix.engine import CorrectionConfig, prepare
from posefix.engine.calibrate import CV_MAX_HELD_OUT, MIN_EDITS, Calibration, held_out_picks
from posefix.engine.choose import held_out_residuals
from posefix.engine.naive import naive_held_out


def _rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1))))


def _positions(problem, sol) -> np.ndarray:
    run = problem.full_run(sol).run
    return geodesy.geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, problem.origin)[:, :2]


def simplex(k: int, step: float = 0.05) -> np.ndarray:
    """Every weight vector on the k-simplex with entries on a grid of ``step``."""
    n = int(round(1 / step))
    pts = [np.array(c) / n for c in itertools.product(range(n + 1), repeat=k - 1) if sum(c) <= n]
    return np.array([np.append(p, 1.0 - p.sum()) for p in pts])


def candidates_of(sim) -> dict:
    """Each candidate's positions (n,2) and held-out residuals (picks,2), the chosen model's, and the truth."""
    problem = prepare(sim.run, CorrectionConfig())
    truth = geodesy.geodetic_to_enu(sim.truth.lat_deg, sim.truth.lon_deg, sim.truth.alt_m, problem.origin)[:, :2]
    index, edit_kf, c, alt, deleted = problem._resolve_edit_set(edit_set(sim))
    flags = problem._check_rules(index, edit_kf, c, deleted)
    t_kf = problem.run.t_s[index]
    order = np.argsort(t_kf[edit_kf], kind="stable")
    edit_kf, c, alt = edit_kf[order], c[order], alt[order]
    m = len(edit_kf)
    picks = held_out_picks(m, CV_MAX_HELD_OUT)
    y = problem.p_enu_m[index][edit_kf, :2] - c[:, :2]
    pos, loo = {}, {}
    names = ("gnss", "plain", "relative") if problem.g_enu_m is not None else ("relative",)
    for name in names:
        sol = problem.solve_rows(index, edit_kf, c, alt, deleted, None, flags,
                                 calibration=Calibration(model=name, cv_rmse_m=float("nan")))
        pos[name] = _positions(problem, sol)
        loo[name] = held_out_residuals(problem, sol, index, edit_kf, c, alt, deleted, picks)
    naive = problem.solve_rows(index, edit_kf, c, alt, deleted, None, flags,
                               calibration=Calibration(model="naive", cv_rmse_m=float("nan")))
    pos["naive"] = _positions(problem, naive)
    loo["naive"] = naive_held_out(t_kf[edit_kf], y, picks)
    chosen = problem.solve(edit_set(sim))
    return dict(truth=truth, pos=pos, loo=loo, m=m, chosen=chosen.drift.calibration.model,
                predicted=chosen.drift.calibration.predicted_rmse_m, spacing=chosen.drift.calibration.spacing_ratio,
                posefix=_positions(problem, chosen))


def row(name: str, every: float, seed, r: dict) -> dict:
    truth, pos, loo = r["truth"], r["pos"], r["loo"]
    true = {k: _rmse(p - truth) for k, p in pos.items()}
    cv = {k: _rmse(v) for k, v in loo.items()}
    models = list(pos)
    W = simplex(len(models))
    R = np.stack([loo[k] for k in models])
    w = W[int(np.argmin(np.mean(np.sum(np.einsum("wm,mnd->wnd", W, R) ** 2, axis=2), axis=1)))]
    stack = _rmse(sum(wi * pos[k] for wi, k in zip(w, models)) - truth)
    blend = min(_rmse(a * pos[k] + (1 - a) * pos["naive"] - truth) for k in models for a in np.linspace(0, 1, 21))
    out = dict(case=name, every=every, seed=seed, m=r["m"], true=true, cv=cv, chosen=r["chosen"],
               posefix=_rmse(r["posefix"] - truth), predicted=r["predicted"], stack=stack, blend=blend, w=dict(zip(models, w)))
    cells = " ".join(f"{k[:5]:>5} {true[k]:5.2f}/{cv[k]:5.2f} ({true[k] / cv[k]:4.2f})" for k in models)
    print(f"   {name:>16} {seed!s:>4} {every:>4.0f}s {r['m']:>3} | {cells} | chose {r['chosen']:>8} {out['posefix']:5.2f} "
          f"pred/true {out['predicted'] / out['posefix']:4.2f} (R {r['spacing']:4.2f}) "
          f"| stack {stack:5.2f} [{' '.join(f'{v:.2f}' for v in w)}] | blend {blend:5.2f}", flush=True)
    return out


def summary(title: str, rows: list[dict]) -> None:
    if not rows:
        return
    naive = np.array([r["true"]["naive"] for r in rows])
    gtsam = np.array([r["true"].get("plain", np.inf) for r in rows])
    for label, key in (("chosen", "posefix"), ("stack", "stack"), ("blend (oracle)", "blend")):
        v = np.array([r[key] for r in rows])
        print(f"   {title}, {label}: <= naive {int(np.sum(at_most(v, naive)))}/{len(v)}, <= plain (GTSAM's graph) "
              f"{int(np.sum(at_most(v, gtsam)))}/{len(v)}, mean /naive {np.mean(v / naive):.3f}")
    honest = np.array([r["predicted"] / r["posefix"] for r in rows])
    print(f"   {title}: predicted RMSE within x1.5 of the truth on {100 * np.mean((honest <= 1.5) & (honest >= 1 / 1.5)):.0f} %")
    ratios = {}
    for r in rows:
        for k in r["true"]:
            ratios.setdefault(k, []).append(r["true"][k] / r["cv"][k])
    print(f"   {title}, true/CV median (range): " + ", ".join(
        f"{k} {np.median(v):.2f} ({min(v):.2f}-{max(v):.2f})" for k, v in ratios.items()))


def family_part(title: str, families, seeds) -> None:
    print(f"\n   {title}")
    rows = []
    for fam in families:
        for seed in seeds:
            for every in SPACINGS_S:
                sim = simulate_family(fam, duration_s=1800.0, rate_hz=5.0, edit_every_s=every, seed=seed)
                rows.append(row(fam, every, seed, candidates_of(sim)))
    summary(title, rows)


def real_part(title: str, make, spacings) -> None:
    print(f"\n   {title}")
    rows = []
    for variant in ("ekf", "smoothed", "no_gnss"):
        for every in spacings:
            sim = make(variant, every)
            if len(sim.edits) >= MIN_EDITS:
                rows.append(row(sim.regime, every, "-", candidates_of(sim)))
    summary(title, rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default=",".join(str(s) for s in TUNED[1]), help="tuned families' seeds, comma separated")
    ap.add_argument("--heldout", action="store_true", help="also the held-out half and the real drives, apart")
    args = ap.parse_args(argv)
    print("Candidates per run: true RMSE / CV RMSE (true/CV), the chosen model, the LOO stack and the oracle blend with naive")
    seeds = tuple(int(s) for s in args.seeds.split(","))
    family_part(f"tuned: {', '.join(TUNED[0])}, seeds {', '.join(map(str, seeds))}", TUNED[0], seeds)
    if args.heldout:
        family_part(f"held out: {', '.join(HELD_OUT[0])}, seed {HELD_OUT[1][0]}", HELD_OUT[0], HELD_OUT[1])
        real_part("held out, real: Nagoya", nagoya_case, SPACINGS_S)
        real_part("held out, real: comma2k19", comma_case, COMMA_SPACINGS_S)


if __name__ == "__main__":
    main()
