"""``posefix mapmatch``: build, fingerprints, train, track, evaluate (CRF map matching), and
suggest (a vehicle run's keyframes on the OpenStreetMap roads).

Heavy modules are imported inside the commands so ``posefix --help`` stays quick. Bad
input prints one line ``error: ...`` on stderr and exits with status 1; outputs are
written to a temporary file and renamed at the end, so a failure leaves nothing behind.
"""

from __future__ import annotations

import os
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional

import click

from posefix.commands.common import CONTEXT, user_errors

app = click.Group()
PATH = click.Path(path_type=Path)


@app.group("mapmatch", no_args_is_help=True)
def mm() -> None:
    """Map matching: indoor walks on floor plans (a CRF, MapCraft); vehicle runs on OpenStreetMap roads (suggest)."""


@contextmanager
def _atomic(path: Path, suffix: str) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename onto it only on success."""
    path.parent.mkdir(parents=True, exist_ok=True) if path.parent != Path("") else None
    fd, tmp = tempfile.mkstemp(prefix=".posefix-", suffix=suffix, dir=str(path.parent or "."))
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _parse_xy(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise click.BadParameter(f"expected 'X,Y' in metres (floor frame), got {text!r}")
    return x, y


@mm.command("build", context_settings=CONTEXT)
@click.option("--floor", type=PATH, required=True, help="Competition floor directory (floor_info.json, geojson_map.json).")
@click.option("--output", "-o", type=PATH, required=True, help="Model file to write (.npz).")
@click.option("--cell-m", type=float, default=0.8, help="Cell size, metres.")
@click.option("--reach-m", type=float, default=1.7, help="Longest single-step transition, metres.")
@click.option("--raster-m", type=float, default=0.1, help="Resolution of the wall/walkable raster, metres.")
@click.option("--min-component-m2", type=float, default=20.0, help="Drop connected areas smaller than this, m².")
@click.option("--shops-walkable/--shops-blocked", default=False, help="Let tracks enter shop polygons (no door data).")
def build(floor: Path, output: Path, cell_m: float, reach_m: float, raster_m: float, min_component_m2: float,
          shops_walkable: bool) -> None:
    """Build a floor graph (one vertex per walkable cell) and save the model."""
    with user_errors():
        from posefix.mapmatch.api import build_model_report
        from posefix.mapmatch.model import save_model

        t0 = time.perf_counter()
        model, report = build_model_report(floor, cell_m=cell_m, reach_m=reach_m, raster_m=raster_m,
                                           min_component_m2=min_component_m2, shops_walkable=shops_walkable)
        for line in report.lines():
            click.echo(line)
        dt = time.perf_counter() - t0
        with _atomic(output, ".npz") as tmp:
            size = save_model(model, tmp)
        g = model.graph
        click.echo(f"model: {g.n_vertices} vertices, {g.indices.size // 2} edges, {g.offsets.shape[0]} step moves; "
                   f"{size / 1024:.1f} KiB; built in {dt:.2f} s -> {output}")


@mm.command("fingerprints", context_settings=CONTEXT)
@click.option("--floor", type=PATH, required=True, help="Floor directory (checked to exist; positions are in its frame).")
@click.option("--walks", type=PATH, multiple=True, required=True, help="Walk files with TYPE_WAYPOINT lines (repeat the option).")
@click.option("--output", "-o", type=PATH, required=True, help="Fingerprint file to write (.npz).")
def fingerprints(floor: Path, walks: tuple[Path, ...], output: Path) -> None:
    """Build a WiFi fingerprint map (f3) and access-point peaks (f4) from surveyed walks."""
    with user_errors():
        from tqdm import tqdm

        from posefix.mapmatch.fingerprints import build_fingerprints, save_fingerprints
        from posefix.mapmatch.sensors import read_walk

        if not Path(floor).is_dir():
            raise ValueError(f"{floor}:0: field --floor: not a directory")
        ws = [read_walk(w) for w in tqdm(walks, desc="reading walks", unit="walk")]
        fp = build_fingerprints(ws)
        with _atomic(output, ".npz") as tmp:
            size = save_fingerprints(fp, tmp)
        click.echo(f"fingerprints: {fp.p_xy_m.shape[0]} scans, {fp.bssids.size} access points "
                   f"({fp.n_fitted_aps} with a fitted position), {len(fp.peak_xy_m)} peaks; "
                   f"{_f3_calibration_words(fp)}; "
                   f"{size / 1024:.1f} KiB -> {output}")
        if not fp.f3_calibrated:
            click.echo(f"warning: {fp.f3_note}; tracking with this file uses no WiFi fingerprints "
                       f"(f4 {'on' if fp.peak_sigma_m is not None else 'off too'})", err=True)


def _f3_calibration_words(fp) -> str:
    """What the survey measured of f3's error, or that it could not."""
    if not fp.f3_calibrated:
        return "f3 not calibrated (see the warning)"
    return (f"covariance scale {fp.cov_scale:.2f} (held-out calibration), outlier rate "
            f"{fp.outlier_frac:.2f}, walk-long error correlation {fp.walk_corr:.2f}")


@mm.command("train", context_settings=CONTEXT)
@click.option("--model", "model_path", type=PATH, required=True, help="Model file from 'build'.")
@click.option("--walks", type=PATH, multiple=True, required=True, help="Walk files with TYPE_WAYPOINT lines (repeat the option).")
@click.option("--output", "-o", type=PATH, required=True, help="Trained model file to write.")
@click.option("--heading-bias/--no-heading-bias", default=True, help="Learn the sensor-to-floor heading bias (rad).")
@click.option("--step-em/--no-step-em", default=False, help="Learn the step constant gamma (m) by hard EM.")
@click.option("--weights/--no-weights", default=True, help="Learn the weights of f1, f2 by conditional likelihood.")
@click.option("--step-scale/--no-step-scale", default=True, help="Scale step lengths by surveyed / dead-reckoned distance between waypoints.")
@click.option("--walk-spread/--no-walk-spread", default=True,
              help="Measure how far the walks' own heading offsets and step scales spread about the floor's; track marginalises them.")
def train(model_path: Path, walks: tuple[Path, ...], output: Path, heading_bias: bool, step_em: bool, weights: bool,
          step_scale: bool, walk_spread: bool) -> None:
    """Learn heading bias and its spread between walks, step-length scale, step constants and feature weights from surveyed walks.

    Each walk starts at its first waypoint; the waypoints clamp the likelihood (within 2 m).
    """
    with user_errors():
        from tqdm import tqdm

        from posefix.mapmatch.api import train_model
        from posefix.mapmatch.model import load_model, save_model
        from posefix.mapmatch.sensors import read_walk

        model = load_model(model_path)
        ws = [read_walk(w) for w in tqdm(walks, desc="reading walks", unit="walk")]
        bar = tqdm(total=3, desc="training", unit="stage")
        model2, report = train_model(model, ws, heading_bias=heading_bias, step_em=step_em, weights=weights,
                                     progress=lambda: bar.update(1), step_scale=step_scale,
                                     walk_spread=walk_spread)
        bar.close()
        with _atomic(output, ".npz") as tmp:
            size = save_model(model2, tmp)
        for k, v in report.items():
            click.echo(f"{k}: {v}")
        click.echo(f"model: {size / 1024:.1f} KiB -> {output}")


@mm.command("track", context_settings=CONTEXT)
@click.argument("walk", type=PATH)
@click.option("--model", "model_path", type=PATH, required=True, help="Model file.")
@click.option("--output", "-o", type=PATH, required=True, help="TRACK.csv: t (unix ms), x, y (m), lat, lon, sigma_major_m, sigma_minor_m, angle_deg, converged, n_modes, mode_spread_m.")
@click.option("--fingerprints", type=PATH, help="Fingerprint file (adds f3/f4).")
@click.option("--start", help="Known start 'X,Y' in metres (floor frame); default: unknown (uniform).")
@click.option("--heading", default="rotation_vector", help="Heading source: rotation_vector or gyro_mag.")
@click.option("--wifi-method", default="knn", help="WiFi position from fingerprints: knn (weighted k-NN, default), pathloss or hybrid.")
@click.option("--estimate", default="mean", help="Rows: 'mean' (smoothed posterior mean) or 'viterbi' (most likely path).")
@click.option("--wifi-corr-s", type=click.FloatRange(min=0.0),
              help="Correlation time of WiFi errors, seconds: scans closer than this share evidence "
                   "(default: the model's, 20 s; 0 counts every scan as independent).")
def track(walk: Path, model_path: Path, output: Path, fingerprints: Optional[Path], start: Optional[str], heading: str,
          wifi_method: str, estimate: str, wifi_corr_s: Optional[float]) -> None:
    """Track a walk: one row per step with the smoothed position and its 1σ error ellipse.

    WALK is the walk file (competition path format); its waypoints are not read.
    """
    with user_errors():
        import numpy as np
        from tqdm import tqdm

        from posefix.mapmatch.api import track_walk_file, write_track_csv
        from posefix.mapmatch.fingerprints import load_fingerprints
        from posefix.mapmatch.model import load_model

        model = load_model(model_path)
        fp = load_fingerprints(fingerprints, method=wifi_method) if fingerprints else None
        if fp is not None and not fp.f3_calibrated:
            click.echo(f"warning: {fingerprints}: {fp.f3_note}", err=True)
        xy = _parse_xy(start) if start else None
        bar = tqdm(desc="tracking", unit="step")

        def on_step(i: int, n: int) -> None:
            bar.total = n
            bar.update(i - bar.n)

        res = track_walk_file(model, walk, start_xy_m=xy, fingerprints=fp, heading=heading, estimate=estimate,
                              on_step=on_step, wifi_corr_s=wifi_corr_s)
        bar.close()
        with _atomic(output, ".csv") as tmp:
            write_track_csv(tmp, res, model.graph.georef)
        click.echo(f"track: {res.t_ms.size} rows, {1000 * res.time_per_step_s:.2f} ms/step, "
                   f"median 1σ {float(np.median(res.sigma_major_m)):.2f} m -> {output}")
        last = res.modes[-1]
        if last.converged:
            click.echo(f"converged: yes (one place holds {100 * last.mass[0]:.0f} %; converged on "
                       f"{100 * float(np.mean(res.converged)):.0f} % of the rows)")
        else:
            click.echo(f"converged: no - the walk fits {last.n} places up to {last.spread_m:.1f} m apart "
                       f"(the likeliest holds {100 * last.mass[0]:.0f} %); the rows are the posterior mean, not a fix")


@mm.command("evaluate", context_settings=CONTEXT)
@click.argument("walk", type=PATH)
@click.argument("track_csv", metavar="TRACK_CSV", type=PATH)
@click.option("--skip-first", is_flag=True, help="Leave out the first waypoint (when it was the given start).")
def evaluate(walk: Path, track_csv: Path, skip_first: bool) -> None:
    """Error (m) at the waypoints, and at every row against the straight-line truth.

    WALK is the walk file with TYPE_WAYPOINT lines (the truth), TRACK_CSV the TRACK.csv from 'track'.
    """
    with user_errors():
        from posefix.mapmatch.api import read_track_csv
        from posefix.mapmatch.evaluate import evaluate_track, summarise
        from posefix.mapmatch.sensors import read_walk

        w = read_walk(walk)
        t, p = read_track_csv(track_csv)
        e = evaluate_track(w.waypoints, t, p, skip_first=skip_first)
        for name, arr in (("waypoints", e.err_wp_m), ("steps", e.err_steps_m)):
            s = summarise([arr])
            click.echo(f"{name}: n={s['n']} mean={s['mean_m']:.2f} m median={s['median_m']:.2f} m p95={s['p95_m']:.2f} m")


@mm.command("suggest", context_settings=CONTEXT)
@click.argument("run_path", metavar="RUN", type=PATH)
@click.option("--osm", type=PATH, required=True, help="OpenStreetMap extract (.osm.pbf), e.g. data/osm/helsinki.osm.pbf.")
@click.option("--output", "-o", type=PATH, required=True,
              help="SUGGESTIONS.csv: row, t_s, lon, lat (suggested), moved_m, off_road, sigma_m; one line per keyframe.")
@click.option("--every-s", type=click.FloatRange(min=0.0, min_open=True), default=1.0,
              help="Keyframe spacing, seconds (the engine's default keyframes).")
@click.option("--matcher", type=click.Choice(["roads", "grid"]), default="roads",
              help="roads: the road network (the grid takes over when most keyframes have no road within 50 m); "
                   "grid: the drivable-area grid.")
@click.option("--cell-m", type=click.FloatRange(min=0.5, max=10.0), default=2.0, help="Grid cell size, metres (--matcher grid).")
@click.option("--format", "input_format", help="Input format (default: from the extension).")
def suggest(run_path: Path, osm: Path, output: Path, every_s: float, matcher: str, cell_m: float,
            input_format: Optional[str]) -> None:
    """Suggest where a vehicle run's keyframes lie on the roads (the editor's suggestions).

    RUN is a pose run (CSV, Parquet, GPX, ...), typically one `posefix correct` wrote.
    """
    with user_errors():
        import numpy as np

        from posefix.core.keyframes import select_keyframes
        from posefix.io import read_run
        from posefix.roads import suggest_vehicle_run

        run = read_run(run_path, fmt=input_format)
        idx = select_keyframes(run.t_s, np.zeros((run.n, 3)), every_s=every_s)
        t0 = time.perf_counter()
        sug = suggest_vehicle_run(run.lon_deg, run.lat_deg, run.q_body_to_enu_wxyz, osm, t_s=run.t_s, matcher=matcher,
                                  cell_m=cell_m, index=idx)
        elapsed = time.perf_counter() - t0
        with _atomic(output, ".csv") as tmp:
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write("row,t_s,lon,lat,moved_m,off_road,sigma_m\n")
                for j, i in enumerate(sug.index):
                    fh.write(f"{i},{run.t_s[i]:.3f},{sug.lonlat_deg[j, 0]:.8f},{sug.lonlat_deg[j, 1]:.8f},"
                             f"{sug.moved_m[j]:.3f},{int(sug.off_road[j])},{sug.sigma_m[j]:.3f}\n")
        click.echo(f"suggest: {idx.size} keyframes on the {sug.matcher} matcher in {elapsed:.2f} s; median move "
                   f"{float(np.median(sug.moved_m)):.1f} m, {int(sug.off_road.sum())} off the road -> {output}")
