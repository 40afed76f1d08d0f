"""Live parity cases for the browser tracker (frontend/src/tracker): the Python online filter's
output on the repository's walks, written next to the model and fingerprint bytes it read.

    python -m tests.vectors.tracker_parity OUT_DIR [--floor site1|site2 ...]

writes ``OUT_DIR/cases.json``: a list of ``{name, floor, walk, model, fingerprints, start,
t_ms, x, y, sigma_major_m, sigma_minor_m, modes, ms_per_step}`` where ``walk``/``model``/
``fingerprints`` are file paths (the TypeScript test reads the same bytes) and the arrays
are ``posefix.mapmatch.track_walk``'s live (forward-filtered) positions, one per step plus
the start; ``modes`` holds each row's :func:`posefix.mapmatch.modes.posterior_modes`
(``mass``, ``mean``, ``spread_m``, ``sigma_major_m``, ``converged``). ``OUT_DIR/modes.json``:
the definition's corners on one floor's vertices (``{name, model, prob, ...modes}``: equal
masses, places near and far, a long blob), where the walks may not reach. The vitest parity
test runs this on every run, so a change to the Python filter shows up at once rather than
in a frozen fixture.

The models exercise every term the tracker has: f2 on, a heading bias, a step model off
the defaults, and fingerprints with f4's σ set when the small survey cannot calibrate it.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from posefix.mapmatch import build_model, load_model, read_walk, save_model, track_walk
from posefix.mapmatch.fingerprints import build_fingerprints, load_fingerprints, save_fingerprints
from posefix.mapmatch.modes import Modes, posterior_modes

REPO = Path(__file__).resolve().parents[2]
FLOORS = {"site1": REPO / "data" / "indoor-site1-F1", "site2": REPO / "data" / "indoor-site2-F2"}


def floor_model(floor: Path):
    """The floor's model with every tracker term switched on (values are arbitrary but physical)."""
    model = build_model(floor, cell_m=0.8)
    return model.with_(step_model=replace(model.step_model, height_m=1.75, heading_bias_rad=0.07),
                       weights={"f1": 0.8, "f2": 0.4, "f3": 1.0, "f4": 0.5})


def fingerprint_file(walks: list[Path], out: Path, f3: bool = True) -> Path:
    """Fingerprints of ``walks``; two survey walks calibrate neither f3 nor f4, so parity
    switches both on (``f3=False``: f3 as built, left out), with f3's heavy-tailed form."""
    fp = build_fingerprints([read_walk(w) for w in walks])
    if fp.peak_sigma_m is None:
        fp.peak_sigma_m = 10.0
    # Two walks measure no outlier beyond the 99 % ellipse: f3's heavy tail gets a physical ε.
    fp.robust, fp.outlier_frac = True, max(fp.outlier_frac, 0.05)
    if f3:
        fp.f3_calibrated, fp.f3_note = True, ""
    save_fingerprints(fp, out)
    return out


def modes_json(m: Modes) -> dict:
    return {"mass": m.mass.tolist(), "mean": m.mean_xy_m.tolist(), "spread_m": m.spread_m,
            "sigma_major_m": m.sigma_major_m, "converged": m.converged}


def run_case(name: str, floor: str, walk: Path, model_path: Path, fp_path: Path | None, start: str) -> dict:
    model = load_model(model_path)
    w = read_walk(walk)
    xy = (float(w.waypoints[0, 1]), float(w.waypoints[0, 2])) if start == "first_waypoint" else None
    fp = load_fingerprints(fp_path) if fp_path is not None else None
    tic = time.process_time()
    res = track_walk(model, w, start_xy_m=xy, fingerprints=fp, estimate="viterbi")
    total = time.process_time() - tic
    n = max(res.t_ms.size - 1, 1)
    return {
        "name": name, "floor": floor, "walk": str(walk), "model": str(model_path),
        "fingerprints": None if fp_path is None else str(fp_path), "start": None if xy is None else list(xy),
        "t_ms": res.t_ms.tolist(), "x": res.online_xy_m[:, 0].tolist(), "y": res.online_xy_m[:, 1].tolist(),
        "sigma_major_m": res.sigma_major_m.tolist(), "sigma_minor_m": res.sigma_minor_m.tolist(),
        "modes": [modes_json(m) for m in res.modes],
        "ms_per_step": 1000.0 * res.time_per_step_s, "total_ms_per_step": 1000.0 * total / n,
    }


def cases(out: Path, floors: list[str]) -> list[dict]:
    out.mkdir(parents=True, exist_ok=True)
    found = []
    for floor in floors:
        d = FLOORS[floor]
        walks = sorted((d / "walks").glob("*.txt"))
        model_path = out / f"{floor}.npz"
        save_model(floor_model(d), model_path)
        for w in walks:
            found.append(run_case(f"{floor} {w.stem} known start", floor, w, model_path, None, "first_waypoint"))
        # WiFi: fingerprints of the other walks; one walk from a known start, one unknown.
        fp_path = fingerprint_file(walks[1:], out / f"{floor}-fp.npz")
        found.append(run_case(f"{floor} {walks[0].stem} known start + WiFi", floor, walks[0], model_path, fp_path, "first_waypoint"))
        found.append(run_case(f"{floor} {walks[0].stem} unknown start + WiFi", floor, walks[0], model_path, fp_path, "unknown"))
        off_path = fingerprint_file(walks[1:2], out / f"{floor}-fp-f3-off.npz", f3=False)
        found.append(run_case(f"{floor} {walks[0].stem} unknown start + uncalibrated f3", floor, walks[0], model_path,
                              off_path, "unknown"))
    return found


def mode_cases(model_path: Path) -> list[dict]:
    """Distributions over the floor's vertices at the converged rule's corners."""
    p = load_model(model_path).graph.p_xy_m
    c1 = p[len(p) // 3]
    d1 = np.linalg.norm(p - c1, axis=1)
    c2 = p[int(np.argmin(np.abs(d1 - 25.0)))]  # a vertex 25 m away
    c3 = p[int(np.argmax(d1))]  # the farthest vertex

    def blob(c, s, along=None):
        d = p - c
        b = np.exp(-0.5 * (d[:, 0] ** 2 / (along or s) ** 2 + d[:, 1] ** 2 / s**2))
        return b / b.sum()

    two = np.zeros(len(p))
    two[[len(p) // 3, int(np.argmax(d1))]] = 1.0
    found = {
        "uniform (every bin the same mass: ties)": np.ones(len(p)),
        "two single vertices (a tie between modes)": two,
        "one blob": blob(c1, 1.5),
        "97 % and 3 % 25 m apart": 0.97 * blob(c1, 1.5) + 0.03 * blob(c2, 1.5),
        "97 % and 3 % far apart": 0.97 * blob(c1, 1.5) + 0.03 * blob(c3, 1.5),
        "long blob": blob(c1, 1.0, along=9.0),
        "60 % and 40 %": 0.6 * blob(c1, 2.0) + 0.4 * blob(c3, 2.0),
    }
    return [{"name": k, "model": str(model_path), "prob": v.tolist(), **modes_json(posterior_modes(p, v))}
            for k, v in found.items()]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--floor", action="append", choices=sorted(FLOORS), help="default: every floor")
    args = ap.parse_args(argv)
    found = cases(args.out, args.floor or sorted(FLOORS))
    (args.out / "cases.json").write_text(json.dumps(found))
    floor = (args.floor or sorted(FLOORS))[-1]
    (args.out / "modes.json").write_text(json.dumps(mode_cases(args.out / f"{floor}.npz")))
    print(f"{len(found)} cases in {args.out / 'cases.json'}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
