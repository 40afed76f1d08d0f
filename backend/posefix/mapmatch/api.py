"""The map-matching Python API used by the CLI, the server and notebooks.

    from posefix.mapmatch import build_model, load_model, save_model, Tracker, track_walk
    model = build_model("data/indoor-site1-F1")                      # Model
    tr = Tracker(model, start_xy_m=(81.3, 93.3))                   # online
    point = tr.step(step_xy_m, t_ms)                               # TrackPoint (vertex, Gaussian summary)
    result = track_walk(model, read_walk("walk.txt"), start_xy_m=None)   # TrackResult, offline

The web layer (``posefix.maps``) reaches the engine through this module only: the names it
re-exports and the few helpers below are the whole surface a server needs.
"""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

from posefix.mapmatch.evaluate import evaluate_track
from posefix.mapmatch.fingerprints import FingerprintMap, load_fingerprints
from posefix.mapmatch.floorplan import (FloorFormatError, FloorReport, GeoRef, load_ilc_floor, raster_from_polygons,
                                        read_ilc_floor)
from posefix.mapmatch.graph import build_graph
from posefix.mapmatch.model import Model, load_model, save_model
from posefix.mapmatch.sensors import (Steps, Walk, WalkFormatError, detect_steps, heading_from_rotation_vector,
                                      read_walk, steps_from_walk, wrap_angle)
from posefix.mapmatch.suggest import Suggestions, suggest_for_run
from posefix.mapmatch.tracker import Tracker, TrackResult, track_walk
from posefix.mapmatch.viterbi import GaussianSummary

__all__ = [
    "FingerprintMap", "FloorFormatError", "FloorReport", "GaussianSummary", "GeoRef", "Model", "TrackResult", "Tracker", "Walk",
    "WalkFormatError", "build_model", "build_model_report", "build_polygon_model", "current_summary", "evaluate_track",
    "load_fingerprints", "load_ilc_floor", "load_model", "read_ilc_floor", "read_track_csv", "read_walk", "save_model", "settled_steps",
    "suggest_for_run", "Suggestions", "track_walk", "track_walk_file", "train_model", "write_track_csv",
]

TRACK_COLUMNS = ["t", "x", "y", "lat", "lon", "sigma_major_m", "sigma_minor_m", "angle_deg", "converged", "n_modes",
                 "mode_spread_m"]


def build_model(floor_dir: str | Path, cell_m: float = 0.8, reach_m: float = 1.7, raster_m: float = 0.1,
                min_component_m2: float = 20.0, shops_walkable: bool = False) -> Model:
    """Model of a competition floor directory with default (untrained) parameters."""
    return build_model_report(floor_dir, cell_m, reach_m, raster_m, min_component_m2, shops_walkable)[0]


def build_model_report(floor_dir: str | Path, cell_m: float = 0.8, reach_m: float = 1.7, raster_m: float = 0.1,
                       min_component_m2: float = 20.0, shops_walkable: bool = False) -> tuple[Model, FloorReport]:
    """:func:`build_model` and what the floor reader used and skipped
    (:func:`posefix.mapmatch.floorplan.read_ilc_floor`)."""
    raster, report = read_ilc_floor(floor_dir, res_m=raster_m, shops_walkable=shops_walkable)
    graph = build_graph(raster, cell_m=cell_m, reach_m=reach_m, min_component_m2=min_component_m2)
    if graph.n_vertices == 0:
        raise ValueError(f"{floor_dir}:0: field walkable area: no reachable cell of {cell_m} m survived "
                         f"(areas under {min_component_m2} m² are dropped)")
    return Model(graph=graph), report


def build_polygon_model(width_m: float, height_m: float, walkable: list, blocked: list, cell_m: float = 0.8) -> Model:
    """Model of a floor given as walkable and blocked polygons in the floor frame (metres)."""
    raster = raster_from_polygons(width_m, height_m, walkable, blocked, res_m=min(0.1, cell_m / 8.0))
    return Model(graph=build_graph(raster, cell_m=cell_m))


def current_summary(tracker: Tracker) -> GaussianSummary:
    """The Gaussian summary (mean, 1σ ellipse) of the tracker's present belief."""
    return tracker.summary(tracker.column())


def settled_steps(acc: np.ndarray, rotvec: np.ndarray, after_ms: float, until_ms: float,
                  model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Steps detected in raw samples (``acc``, ``rotvec``: (n, 4) rows ``t_ms, x, y, z``) that
    fall in (``after_ms`` + the minimum step interval, ``until_ms``]: their (k,) times and
    (k, 2) floor-frame vectors under the model's step model."""
    t_steps, freq = detect_steps(acc)
    # A peak can shift by a sample as more signal arrives: new steps must come at least
    # the minimum step interval after the last one reported.
    new = (t_steps > after_ms + 300) & (t_steps <= until_ms)
    if not np.any(new):
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    t_new, f_new = t_steps[new], freq[new]
    th = np.unwrap(heading_from_rotation_vector(rotvec[:, 1:4]))
    heading = wrap_angle(np.interp(t_new, rotvec[:, 0], th))
    vec = Steps(t_ms=t_new, freq_hz=f_new, heading_rad=np.asarray(heading, dtype=float)).vectors_m(model.step_model)
    return t_new.astype(np.int64), vec


def train_model(model: Model, walks: list[Walk], heading_bias: bool = True, step_em: bool = False,
                weights: bool = True, progress: Callable[[], None] | None = None,
                step_scale: bool = True, wifi_weight: bool = False, walk_spread: bool = True) -> tuple[Model, dict]:
    """Learn the heading bias, then the step-length scale, then (``walk_spread``) how far the
    walks' own heading offsets and step scales spread about them, which ``track_walk``
    marginalises (:func:`posefix.mapmatch.learn.learn_walk_spread`; the model's defaults stay
    with fewer than three walks to measure it on), then (optionally) γ by hard EM, then the
    f1/f2 weights,
    and f3's when ``wifi_weight`` and at least three walks have
    WiFi scans: each training walk then gets f3 from a fingerprint map of the *other*
    training walks (leave-one-walk-out, so the weight is learned for a scan the map has
    not seen, as when tracking), from a uniform start (slow: about 2 min for 15 walks).
    Off by default: on site1/F1 it learns w3 = 0.09 / 0.03 and the held-out (d) error is
    13.4 m against 11.5 m with w3 = 1 on the calibrated covariance (docs/mapmatch.md).

    Every walk starts at its first waypoint. Returns the new model and a report dict.
    """
    from posefix.mapmatch.learn import (clamp_states, learn_heading_bias, learn_step_constants,
                                        learn_step_scale, learn_walk_spread, learn_weights, walk_features)

    tick = progress or (lambda: None)
    surveyed = [w for w in walks if w.waypoints.shape[0] >= 2]
    if not surveyed:
        raise ValueError("training needs walks with at least two TYPE_WAYPOINT lines")
    report: dict = {}
    if heading_bias:
        b = learn_heading_bias(surveyed, model.step_model)
        model = model.with_(step_model=replace(model.step_model, heading_bias_rad=b))
        report["heading_bias_deg"] = round(float(np.degrees(b)), 2)
    if step_scale:
        sm = learn_step_scale(surveyed, model.step_model)
        report["step_scale"] = round(sm.height_m / model.step_model.height_m, 3)
        model = model.with_(step_model=sm)
    if walk_spread:
        # After the floor's bias and scale: the walks' own offsets and scales about them.
        sd_h, sd_k, n = learn_walk_spread(surveyed, model.step_model)
        if sd_h is not None:
            model = model.with_(walk_heading_sd_rad=sd_h, walk_scale_sd=sd_k)
        report["walk_spread"] = (f"heading {np.degrees(model.walk_heading_sd_rad):.1f} deg, step scale "
                                 f"{100 * model.walk_scale_sd:.1f} %"
                                 + (f" (measured on {n} walks)" if sd_h is not None
                                    else f" (default: {n} walks with two waypoint segments, 3 needed)"))
    tick()
    if step_em:
        sm = learn_step_constants(model, [(steps_from_walk(w), tuple(w.waypoints[0, 1:3])) for w in surveyed])
        model = model.with_(step_model=sm)
        report["gamma_m"] = round(sm.gamma_m, 3)
    tick()
    if weights:
        from posefix.mapmatch.fingerprints import build_fingerprints

        with_wifi = [w for w in surveyed if w.wifi] if wifi_weight else []
        data, data_wifi = [], []
        for w in surveyed:
            st = steps_from_walk(w)
            if len(st) < 3:
                continue
            t = np.concatenate([[int(w.acc[0, 0])], st.t_ms])
            wf = walk_features(model, st.vectors_m(model.step_model), t, start_xy_m=tuple(w.waypoints[0, 1:3]))
            clamp = clamp_states(model.graph, t, w.waypoints)
            data.append((wf, clamp))
            if len(with_wifi) >= 3 and w.wifi:
                data_wifi.append((w, st, t, clamp))
        fit = learn_weights(model, data, learn=("f1", "f2"))
        if data_wifi:
            # f3 matters when the start is unknown (with a known start the steps alone are
            # better than any WiFi fix and the weight goes to 0): learn it from a uniform start.
            from posefix.mapmatch.features import evidence_shares

            model = model.with_(weights=fit.weights)
            data = []
            for w, st, t, clamp in data_wifi:
                fp = build_fingerprints([x for x in with_wifi if x is not w], method="knn")
                if not fp.f3_calibrated:  # the other walks are too few a survey: w3 not learned
                    report["f3"] = fp.f3_note
                    continue
                pred = fp.predict_walk(w, model.graph.p_xy_m)
                # Each scan discounted for its correlation with the previous one, as when
                # tracking: a score times its share is the Gaussian with Σ / share.
                shares = evidence_shares(np.array([tp for tp, _, _ in pred]) / 1000.0, model.sigmas.wifi_corr_s)
                wifi = {int(np.argmin(np.abs(st.t_ms - tp))): (mu, cov / sh)
                        for (tp, mu, cov), sh in zip(pred, shares) if sh > 0.0}
                data.append((walk_features(model, st.vectors_m(model.step_model), t, wifi=wifi), clamp))
            if data:
                fit = learn_weights(model, data, learn=("f3",), max_iter=10)
        model = model.with_(weights=fit.weights)
        report["weights"] = {k: round(v, 3) for k, v in fit.weights.items()}
        report["log_likelihood"] = round(fit.log_likelihood, 2)
    tick()
    return model, report


def track_walk_file(model: Model, walk_path: str | Path, start_xy_m=None, fingerprints=None,
                    heading: str = "rotation_vector", estimate: str = "mean",
                    on_step: Callable[[int, int], None] | None = None,
                    wifi_corr_s: float | None = None) -> TrackResult:
    """Read a walk file and track it (see :func:`posefix.mapmatch.tracker.track_walk`)."""
    return track_walk(model, read_walk(walk_path), start_xy_m=start_xy_m, fingerprints=fingerprints,
                      heading=heading, estimate=estimate, on_step=on_step, wifi_corr_s=wifi_corr_s)


def write_track_csv(path: str | Path, res: TrackResult, georef: GeoRef | None) -> None:
    """TRACK.csv: one row per step (and the start): t (unix ms), x, y (m), lat, lon (deg,
    empty without a geo-reference), sigma_major_m, sigma_minor_m (1σ), angle_deg (CCW from x),
    converged (1: the posterior converged on one place, the ellipse is a fix; 0: it did not),
    n_modes (places holding ≥ 1 % each), mode_spread_m (the farthest from the likeliest)."""
    ll = georef.to_lonlat(res.p_xy_m) if georef is not None else None
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TRACK_COLUMNS)
        for i in range(res.t_ms.size):
            lat = f"{ll[i, 1]:.8f}" if ll is not None else ""
            lon = f"{ll[i, 0]:.8f}" if ll is not None else ""
            w.writerow([int(res.t_ms[i]), f"{res.p_xy_m[i, 0]:.3f}", f"{res.p_xy_m[i, 1]:.3f}", lat, lon,
                        f"{res.sigma_major_m[i]:.3f}", f"{res.sigma_minor_m[i]:.3f}", f"{res.angle_deg[i]:.1f}",
                        int(res.modes[i].converged), res.modes[i].n, f"{res.modes[i].spread_m:.1f}"])


def read_track_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """TRACK.csv -> ``t_ms`` (n,), ``p_xy_m`` (n, 2); errors name file, line and field."""
    t, p = [], []
    with open(path, newline="") as fh:
        r = csv.reader(fh)
        header = next(r, None)
        if header is None or header[:3] != ["t", "x", "y"]:
            raise ValueError(f"{path}:1: field header: expected columns starting t,x,y")
        for lineno, row in enumerate(r, start=2):
            for j, name in enumerate(("t", "x", "y")):
                try:
                    float(row[j])
                except (ValueError, IndexError):
                    raise ValueError(f"{path}:{lineno}: field {name}: not a number")
            t.append(float(row[0]))
            p.append([float(row[1]), float(row[2])])
    if not t:
        raise ValueError(f"{path}:2: field t: no rows")
    return np.asarray(t), np.asarray(p)
