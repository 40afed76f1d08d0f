"""Commands of the 'engine' area: correct, evaluate, simulate, convert.

On this module's ``app``, which ``posefix.cli`` assembles. Heavy modules (numpy, pyarrow, scipy, the engine) are
imported inside the commands so ``posefix --help`` and every other command stay quick.
Bad input prints one line ``error: ...`` on stderr and exits with status 1; nothing is
written (outputs go to temporary files renamed at the end). Set ``POSEFIX_DEBUG=1`` to see
the traceback of an unexpected ``ValueError``/``OSError`` instead.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Optional

import click

from posefix.commands.common import CONTEXT, CommandError, single_threaded_blas, user_errors

app = click.Group()
PATH = click.Path(path_type=Path)


FORMAT_HELP = "csv, parquet, arrow, gpx, geojson, tum, kitti or comma2k19"
ORIGIN_HELP = (
    "Origin of a TUM file's local ENU frame as 'lat,lon,alt' (degrees, degrees, metres above "
    "the WGS84 ellipsoid). Needed to read TUM; for writing TUM the default is the first sample."
)


def _parse_origin(text: Optional[str]):
    if text is None:
        return None
    parts = [p.strip() for p in text.split(",")]
    if len(parts) not in (2, 3):
        raise CommandError(f"--origin: expected 'lat,lon,alt', got {text!r}")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise CommandError(f"--origin: not numbers: {text!r}") from None
    from posefix.core.geodesy import as_origin

    try:
        return as_origin(vals)
    except ValueError as exc:
        raise CommandError(f"--origin: {exc}") from None


class _Steps:
    """A tqdm bar over named steps of a command (shown on a terminal only).

    tqdm (and the multiprocessing it loads) is imported only when the bar is shown.
    """

    def __init__(self, names: list[str], quiet: bool):
        self.bar = None
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=len(names), unit="step", leave=False, file=sys.stderr,
                            bar_format="{desc}: {n_fmt}/{total_fmt} {bar} {elapsed}")

    def __call__(self, name: str) -> None:
        if self.bar is not None:
            self.bar.set_description_str(name)

    def done(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _preload_engine():
    """Import the engine in a background thread while the main thread parses input.

    A large file's CSV parser runs in C++ without the GIL, so importing the engine's modules
    alongside it overlaps that import on a multi-core machine (a small file is parsed in
    Python: then the two take turns). A failure is left for the main thread's own import to
    raise.
    """
    import threading

    def load() -> None:
        try:
            import posefix.engine  # noqa: F401
        except Exception:  # noqa: BLE001 - re-raised by the main thread's import
            pass

    th = threading.Thread(target=load, name="preload-posefix.engine", daemon=True)
    th.start()
    return th


def _check_output_path(path: Path, inputs: list[Path]) -> None:
    if not path.parent.exists():
        raise CommandError(f"{path}: output folder {str(path.parent)!r} does not exist")
    for p in inputs:
        try:
            if path.exists() and path.resolve() == p.resolve():
                raise CommandError(f"{path}: output would overwrite an input")
        except OSError:
            pass


# --------------------------------------------------------------------------- correct


@app.command("correct", context_settings=CONTEXT)
@click.argument("run_path", metavar="RUN", type=PATH)
@click.option("--edits", "-e", "edits_path", type=PATH, metavar="EDITS.json", help='Operator edits: {"edits": [{"t": s, "lat": deg, "lon": deg, "alt": m (optional)}], "deleted": [t, ...]}; each t names a sample to the millisecond. Omit for no edits.')
@click.option("--output", "-o", "output", type=PATH, metavar="OUT", required=True, help="Corrected run: every input sample in input order, other columns kept. Format from the extension (.csv, .parquet, .arrow, .gpx, .geojson, .tum) unless --format.")
@click.option("--config", "-c", "config", type=PATH, metavar="FILE", help="TOML file overriding engine settings (strengths in metres/radians, loss, drift, solver); defaults documented in posefix/core/default_config.toml.")
@click.option("--keyframes-every-s", type=float, metavar="S", help="One keyframe every S seconds (default from config: 1 s). Edited samples are always keyframes.")
@click.option("--keyframes-every-m", type=float, metavar="M", help="One keyframe every M metres travelled (instead of every S seconds).")
@click.option("--format", "-f", "fmt", help="Output format: csv, parquet, arrow, gpx, geojson or tum (default: from OUT's extension).")
@click.option("--input-format", help=f"Input format ({FORMAT_HELP}); default from RUN's extension or folder layout.")
@click.option("--origin", help=ORIGIN_HELP)
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors.")
def correct_command(
    run_path: Path,
    edits_path: Optional[Path],
    output: Path,
    config: Optional[Path],
    keyframes_every_s: Optional[float],
    keyframes_every_m: Optional[float],
    fmt: Optional[str],
    input_format: Optional[str],
    origin: Optional[str],
    quiet: bool,
) -> None:
    """Correct a pose run from operator edits: optimise keyframes, propagate to every sample.

    RUN is the pose run to correct: a file or folder (csv, parquet, arrow, gpx, geojson, tum,
    kitti or comma2k19); its format comes from the extension/layout unless --input-format.
    """
    single_threaded_blas()
    with user_errors():
        t_start = time.perf_counter()
        if keyframes_every_s is not None and keyframes_every_m is not None:
            raise CommandError("give either --keyframes-every-s or --keyframes-every-m, not both")
        for name, val in (("--keyframes-every-s", keyframes_every_s), ("--keyframes-every-m", keyframes_every_m)):
            if val is not None and not val > 0:
                raise CommandError(f"{name} must be a positive number, got {val}")
        o = _parse_origin(origin)
        from posefix.io import WRITE_FORMATS, detect_format, read_edits, read_run, write_run

        if fmt is not None and fmt not in WRITE_FORMATS:
            raise CommandError(f"--format: cannot write {fmt!r} (writable: {', '.join(WRITE_FORMATS)})")
        out_fmt = fmt or detect_format(output, for_writing=True)
        _check_output_path(output, [run_path] + ([edits_path] if edits_path else []))
        steps = _Steps(["read", "edits", "correct", "write"], quiet)
        preload = _preload_engine()
        steps("reading run")
        run = read_run(run_path, fmt=input_format, origin=o)
        steps.done()
        preload.join()
        steps("reading edits")
        from posefix.io.edits import EditSet

        edits = read_edits(edits_path) if edits_path is not None else EditSet()
        cfg = _load_config(config, keyframes_every_s, keyframes_every_m)
        steps.done()
        steps("optimising")
        from posefix.engine import correct

        result = correct(run, edits, cfg)
        steps.done()
        steps("writing")
        write_run(result.run, output, fmt=out_fmt, origin=o)
        steps.done()
        steps.close()
        if not quiet:
            _print_correction_summary(run, edits, result, output, time.perf_counter() - t_start)


def _load_config(config: Optional[Path], every_s: Optional[float], every_m: Optional[float]):
    import dataclasses

    from posefix.engine import CorrectionConfig

    cfg = CorrectionConfig.load(config) if config is not None else CorrectionConfig()
    if every_s is not None:
        cfg = dataclasses.replace(cfg, keyframes=dataclasses.replace(cfg.keyframes, every_s=every_s, every_m=0.0))
    if every_m is not None:
        cfg = dataclasses.replace(cfg, keyframes=dataclasses.replace(cfg.keyframes, every_m=every_m))
    return cfg


def _print_correction_summary(run, edits, result, output: Path, elapsed_s: float) -> None:
    s = result.solver
    k = len(result.keyframes.index)
    status = getattr(s, "status", "?")
    message = getattr(s, "message", "")
    iters = getattr(s, "iterations", "?")
    click.echo(
        f"corrected {run.n} samples ({k} keyframes, {len(edits.moves)} moves, {len(edits.deleted)} deleted) "
        f"-> {output} in {elapsed_s:.2f} s"
    )
    click.echo(f"solver: {status} after {iters} iterations: {message}")
    drift = result.drift
    off = getattr(drift, "offset_enu_m", None)
    spread = getattr(drift, "spread_m", None)
    if off is not None:
        import numpy as np

        off = np.asarray(off, dtype=float).reshape(-1)
        if off.size >= 2 and np.all(np.isfinite(off[:2])):
            sp = f", spread {float(spread):.2f} m" if spread is not None and np.isfinite(spread) else ""
            click.echo(f"drift implied by the edits: east {off[0]:+.2f} m, north {off[1]:+.2f} m{sp}")
    calib = getattr(drift, "calibration", None)
    if calib is not None:
        click.echo(_calibration_line(calib))
    if getattr(drift, "loc_sigma_h_m", None) is not None:
        click.echo("the raw GNSS jumps onto urban-canyon levels the pose bridged: levels taken out of the "
                   "location term (drift.gnss_levels)")
    for flag in getattr(result, "flags", []) or []:
        click.echo(f"flagged: keyframe {flag.index}: {flag.reason}: {flag.message}")


def _calibration_line(calib) -> str:
    """The model the run's edits chose and how well it predicts edits it did not see."""
    import math

    if calib.model == "prior":
        return (f"model: prior ({calib.n_edits} edit(s): too few to hold one out; the run stays as reported "
                "away from the edits)")
    scores = ", ".join(f"{k} {v:.2f} m" for k, v in calib.cv_rmse_by_model.items() if math.isfinite(v))
    ratio = getattr(calib, "spacing_ratio", float("nan"))
    why = (f" (the held-out RMSE x {ratio:.2f}: a held-out edit is predicted across twice the edits' spacing)"
           if math.isfinite(ratio) else "")
    return (f"model: {calib.model} (chosen by held-out edits; cross-validated RMSE at the edits: {scores}); "
            f"predicted RMSE of the run {calib.predicted_rmse_m:.2f} m{why}")


# --------------------------------------------------------------------------- evaluate


@app.command("evaluate", context_settings=CONTEXT)
@click.argument("truth_path", metavar="TRUTH", type=PATH)
@click.argument("run_path", metavar="RUN", type=PATH)
@click.option("--json", "as_json", is_flag=True, help="Print the metrics as JSON (metres) instead of a table.")
@click.option("--origin", help=ORIGIN_HELP)
def evaluate_command(truth_path: Path, run_path: Path, as_json: bool, origin: Optional[str]) -> None:
    """Horizontal and 3-D position error of RUN against TRUTH: RMSE, mean, median, 95th percentile, max (metres).

    TRUTH is the ground-truth run (csv, parquet, arrow, gpx, geojson, tum, kitti or comma2k19);
    RUN's samples are compared with TRUTH interpolated at RUN's times.
    """
    with user_errors():
        o = _parse_origin(origin)
        from posefix.core.evaluate import evaluate
        from posefix.io import read_run

        truth = read_run(truth_path, origin=o)
        run = read_run(run_path, origin=o)
        ev = evaluate(truth, run)
        if as_json:
            click.echo(json.dumps(ev.to_dict(), indent=2))
            return
        click.echo(f"{'error (m)':<12}{'rmse':>10}{'mean':>10}{'median':>10}{'p95':>10}{'max':>10}")
        for name, st in (("horizontal", ev.horizontal), ("3-D", ev.three_d)):
            click.echo(f"{name:<12}{st.rmse_m:>10.3f}{st.mean_m:>10.3f}{st.median_m:>10.3f}{st.p95_m:>10.3f}{st.max_m:>10.3f}")
        extra = f"; {ev.n_outside} outside the truth's time span, not measured" if ev.n_outside else ""
        click.echo(f"samples compared: {ev.n_compared}{extra}")


# --------------------------------------------------------------------------- simulate


@app.command("simulate", context_settings=CONTEXT)
@click.option("--out", type=PATH, metavar="DIR", required=True, help="Folder to write run.csv (reported poses + raw GNSS), truth.csv and edits.json into (created if missing).")
@click.option("--duration-s", type=click.FloatRange(min=1.0), default=600.0, help="Length of the drive, seconds.")
@click.option("--rate-hz", type=click.FloatRange(min=0.1), default=100.0, help="Pose sample rate, Hz.")
@click.option("--edit-every-s", type=click.FloatRange(min=0.0), default=100.0, help="One edit (true position + click noise) every this many seconds, at the middle of each interval; 0 for none.")
@click.option("--seed", type=int, default=1, help="Random seed: the same options give the same drive.")
@click.option("--regime", default="mixed", help="GNSS error regime: white (noise), drift (pose bias moving a few cm/s, raw GNSS beside), canyon (offset jumps of 5-20 m for minutes, inherited by the pose), canyon_ins (the same jumps in the raw GNSS only; the pose bridged them), outliers (50 m bursts), mixed (canyon + outliers + drift).")
@click.option("--family", help="Build the reported pose the way a real unit does instead of a regime's error (posefix.core.families): ekf (odometry and yaw rate fused with gated single-point GNSS), ekf_smoothed (the same forward-backward), ins_lowpass (a GNSS/INS pose following a low-passed copy of the fix's bias), scale_heading (dead reckoning with a scale error and a heading bias), time_offset (pose stamped late against GNSS), outage (ekf with three minutes without fixes), no_gnss (ekf, no gnss columns). GNSS at --gnss-rate-hz (1 Hz unless given).")
@click.option("--osm", type=PATH, metavar="FILE.pbf", help="Drive along the streets of this OpenStreetMap extract (e.g. data/osm/helsinki.osm.pbf).")
@click.option("--click-noise-m", type=click.FloatRange(min=0.0), default=0.5, help="Operator click error of each edit, metres (1 sigma per horizontal axis).")
@click.option("--gnss-rate-hz", type=click.FloatRange(min=0.01), help="Raw GNSS fix rate, Hz (held between fixes); default 10, with --family 1.")
@click.option("--no-gnss-columns", is_flag=True, help="Leave the raw GNSS columns out of run.csv (the location term then uses the reported pose).")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors.")
def simulate_command(
    out: Path,
    duration_s: float,
    rate_hz: float,
    edit_every_s: float,
    seed: int,
    regime: str,
    family: Optional[str],
    osm: Optional[Path],
    click_noise_m: float,
    gnss_rate_hz: Optional[float],
    no_gnss_columns: bool,
    quiet: bool,
) -> None:
    """Simulate a drive with ground truth: writes DIR/run.csv, DIR/truth.csv and DIR/edits.json."""
    with user_errors():
        from posefix.core.families import FAMILIES, simulate_family
        from posefix.core.simulate import REGIMES, simulate

        if regime not in REGIMES:
            raise CommandError(f"--regime: unknown regime {regime!r} (known: {', '.join(REGIMES)})")
        if family is not None and family not in FAMILIES:
            raise CommandError(f"--family: unknown family {family!r} (known: {', '.join(FAMILIES)})")
        if family is not None and (osm is not None or no_gnss_columns):
            raise CommandError("--family builds its own drive and GNSS: leave out --osm and --no-gnss-columns "
                               "(the no_gnss family has none)")
        if osm is not None and not osm.is_file():
            raise CommandError(f"--osm: {osm}: no such file")
        if out.exists() and not out.is_dir():
            raise CommandError(f"--out: {out} exists and is not a folder")
        steps = _Steps(["simulate", "write run", "write truth", "write edits"], quiet)
        if family is not None:
            sim = simulate_family(family, duration_s=duration_s, rate_hz=rate_hz, edit_every_s=edit_every_s, seed=seed,
                                  gnss_rate_hz=1.0 if gnss_rate_hz is None else gnss_rate_hz, click_noise_m=click_noise_m)
        else:
            sim = simulate(
                duration_s=duration_s, rate_hz=rate_hz, edit_every_s=edit_every_s, seed=seed, regime=regime,
                osm_path=None if osm is None else str(osm), gnss_columns=not no_gnss_columns,
                gnss_rate_hz=10.0 if gnss_rate_hz is None else gnss_rate_hz, click_noise_m=click_noise_m, progress=steps,
            )
        steps.done()
        from posefix.io import EditSet, Move, write_edits, write_run

        out.mkdir(parents=True, exist_ok=True)
        steps("writing run.csv")
        write_run(sim.run, out / "run.csv")
        steps.done()
        steps("writing truth.csv")
        write_run(sim.truth, out / "truth.csv")
        steps.done()
        steps("writing edits.json")
        edits = EditSet(moves=[Move(e.t_s, e.lat_deg, e.lon_deg) for e in sim.edits])
        write_edits(edits, out / "edits.json")
        steps.done()
        steps.close()
        if not quiet:
            info = sim.info
            click.echo(
                f"simulated {sim.run.n} samples ({duration_s:g} s at {rate_hz:g} Hz, "
                f"{'family ' + family if family else 'regime ' + regime}, "
                f"{info['path_length_m'] / 1000:.1f} km, mean speed {info['mean_speed_mps']:.1f} m/s, "
                f"{len(sim.edits)} edits) -> {out}/run.csv, truth.csv, edits.json"
            )
            click.echo(
                f"reported pose error (horizontal RMS) {info['pose_error_rms_m']:.2f} m; "
                f"raw GNSS {info['gnss_error_rms_m']:.2f} m"
            )


# --------------------------------------------------------------------------- convert


@app.command("convert", context_settings=CONTEXT)
@click.argument("input_path", metavar="IN", type=PATH)
@click.argument("output_path", metavar="OUT", type=PATH)
@click.option("--origin", help=ORIGIN_HELP)
@click.option("--from", "input_format", help=f"Input format ({FORMAT_HELP}); default from IN.")
@click.option("--to", "output_format", help="Output format (csv, parquet, arrow, gpx, geojson, tum); default from OUT's extension.")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors.")
def convert_command(
    input_path: Path,
    output_path: Path,
    origin: Optional[str],
    input_format: Optional[str],
    output_format: Optional[str],
    quiet: bool,
) -> None:
    """Convert a pose run between formats (orientation derived from the track when IN has none).

    IN is the run to read: a file or folder (csv, parquet, arrow, gpx, geojson, tum, kitti or
    comma2k19); OUT the file to write (.csv, .parquet, .arrow, .gpx, .geojson, .tum).
    """
    with user_errors():
        o = _parse_origin(origin)
        from posefix.io import WRITE_FORMATS, detect_format, read_run, write_run

        if output_format is not None and output_format not in WRITE_FORMATS:
            raise CommandError(f"--to: cannot write {output_format!r} (writable: {', '.join(WRITE_FORMATS)})")
        out_fmt = output_format or detect_format(output_path, for_writing=True)
        _check_output_path(output_path, [input_path])
        run = read_run(input_path, fmt=input_format, origin=o)
        write_run(run, output_path, fmt=out_fmt, origin=o)
        if not quiet:
            derived = " (orientation derived from the track)" if run.orientation_derived else ""
            click.echo(f"converted {run.n} samples -> {output_path} ({out_fmt}){derived}")
