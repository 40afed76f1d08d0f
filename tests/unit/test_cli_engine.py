"""The engine's command line, end to end in subprocesses: simulate -> correct -> evaluate,
the real comma2k19 drive with and without edits, convert, and one-line errors."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from posefix.core.geodesy import enu_to_geodetic, geodetic_to_enu
from posefix.io import read_run

from .io_helpers import comma2k19_segment, leftovers

POSEFIX = [sys.executable, "-c", "from posefix.cli import main; main()"]


def posefix(*args, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, COLUMNS="120")
    return subprocess.run(POSEFIX + [str(a) for a in args], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)


def ok(*args, cwd=None) -> subprocess.CompletedProcess:
    res = posefix(*args, cwd=cwd)
    assert res.returncode == 0, res.stderr
    return res


def assert_one_line_error(res: subprocess.CompletedProcess, *fragments: str) -> None:
    assert res.returncode == 1
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert "Traceback" not in res.stderr
    for f in fragments:
        assert f in lines[0], lines[0]


@pytest.fixture(scope="module")
def simulated(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    res = ok("simulate", "--duration-s", 600, "--rate-hz", 10, "--edit-every-s", 60, "--seed", 7, "--regime", "canyon", "--out", out)
    assert "6001 samples" in res.stdout and "10 edits" in res.stdout
    return out


def test_simulate_writes_run_truth_edits(simulated):
    assert sorted(p.name for p in simulated.iterdir()) == ["edits.json", "run.csv", "truth.csv"]
    run = read_run(simulated / "run.csv")
    assert run.n == 6001 and run.has_gnss
    assert len(json.loads((simulated / "edits.json").read_text())["edits"]) == 10


def test_simulate_family_builds_the_families_pose_and_gnss(tmp_path):
    res = ok("simulate", "--family", "no_gnss", "--duration-s", 300, "--rate-hz", 2, "--edit-every-s", 60, "--seed", 3,
             "--out", tmp_path)
    assert "family no_gnss" in res.stdout and "601 samples" in res.stdout
    run = read_run(tmp_path / "run.csv")
    assert run.n == 601 and not run.has_gnss
    out = ok("simulate", "--family", "ekf", "--duration-s", 300, "--rate-hz", 2, "--out", tmp_path / "ekf")
    assert read_run(tmp_path / "ekf" / "run.csv").has_gnss and "raw GNSS" in out.stdout
    assert_one_line_error(posefix("simulate", "--family", "kalman", "--out", tmp_path / "x"), "--family", "kalman", "ekf")
    assert not (tmp_path / "x").exists()


def test_correct_then_evaluate_improves_the_run(simulated, tmp_path):
    out = tmp_path / "corrected.csv"
    res = ok("correct", simulated / "run.csv", "--edits", simulated / "edits.json", "--output", out)
    assert "corrected 6001 samples" in res.stdout and "solver:" in res.stdout
    # the accuracy it reports is carried from the held-out edits to the edits' real spacing
    assert re.search(r"predicted RMSE of the run \d+\.\d\d m \(the held-out RMSE x [01]\.\d\d: ", res.stdout), res.stdout
    before = json.loads(ok("evaluate", simulated / "truth.csv", simulated / "run.csv", "--json").stdout)
    after = json.loads(ok("evaluate", simulated / "truth.csv", out, "--json").stdout)
    assert after["horizontal"]["rmse_m"] < 0.5 * before["horizontal"]["rmse_m"]
    corrected = read_run(out)
    original = read_run(simulated / "run.csv")
    assert np.array_equal(corrected.t_s, original.t_s)  # every sample, input order
    assert np.array_equal(corrected.gnss_lat_deg, original.gnss_lat_deg)  # other columns kept
    table = ok("evaluate", simulated / "truth.csv", out).stdout
    assert "horizontal" in table and "rmse" in table and "p95" in table


def test_correct_writes_gpx_and_geojson_and_keyframe_options(simulated, tmp_path):
    ok("correct", simulated / "run.csv", "-e", simulated / "edits.json", "-o", tmp_path / "c.gpx", "--keyframes-every-m", 20, "-q")
    ok("correct", simulated / "run.csv", "-e", simulated / "edits.json", "-o", tmp_path / "c.out", "--format", "geojson",
       "--keyframes-every-s", 2, "-q")
    assert read_run(tmp_path / "c.gpx").n == 6001
    assert read_run(tmp_path / "c.out", fmt="geojson").n == 6001


@pytest.fixture(scope="module")
def comma_edits(tmp_path_factory) -> tuple[Path, list[int]]:
    """Three edits at real global_pose samples, each moved 2 m north of the fused pose."""
    run = read_run(comma2k19_segment())
    rows = [200, 600, 1000]
    o = (run.lat_deg[0], run.lon_deg[0], run.alt_m[0])
    p = geodetic_to_enu(run.lat_deg[rows], run.lon_deg[rows], run.alt_m[rows], o) + [0.0, 2.0, 0.0]
    lat, lon, _ = enu_to_geodetic(p, o)
    path = tmp_path_factory.mktemp("comma") / "edits.json"
    path.write_text(json.dumps({"edits": [{"t": float(run.t_s[r]), "lat": float(a), "lon": float(b)} for r, a, b in zip(rows, lat, lon)]}))
    return path, rows


def test_comma2k19_corrects_with_zero_edits(tmp_path):
    out = tmp_path / "c.csv"
    res = ok("correct", comma2k19_segment(), "--output", out)
    assert "corrected 1200 samples" in res.stdout and "0 moves" in res.stdout
    ev = json.loads(ok("evaluate", comma2k19_segment(), out, "--json").stdout)
    # without edits the run stays near its reported poses (the u-blox fix is ~1.5 m away)
    assert ev["horizontal"]["rmse_m"] < 1.5


def test_comma2k19_corrects_with_edits(comma_edits, tmp_path):
    edits, rows = comma_edits
    ok("correct", comma2k19_segment(), "--edits", edits, "--output", tmp_path / "c.geojson")
    ok("correct", comma2k19_segment(), "--output", tmp_path / "none.csv")
    src = read_run(comma2k19_segment())
    o = (src.lat_deg[0], src.lon_deg[0], src.alt_m[0])

    def north_shift(path):
        r = read_run(path)
        return (geodetic_to_enu(r.lat_deg, r.lon_deg, r.alt_m, o) - geodetic_to_enu(src.lat_deg, src.lon_deg, src.alt_m, o))[:, :2]

    with_edits, without = north_shift(tmp_path / "c.geojson"), north_shift(tmp_path / "none.csv")
    # each edited sample ends where it was put, 2 m north of its reported pose: three edits that
    # agree on one offset show the u-blox fixes (~1.4 m south, where the run goes without edits)
    # are biased, so those fixes no longer pull the run back
    assert np.all(np.abs(with_edits[rows, 1] - 2.0) < 0.25), with_edits[rows, 1]
    assert np.all(without[rows, 1] < -1.0)
    assert np.abs(with_edits[rows, 0]).max() < 0.25  # the edits were due north


def test_convert_between_formats(tmp_path):
    ok("convert", comma2k19_segment(), tmp_path / "c.gpx")
    res = ok("convert", tmp_path / "c.gpx", tmp_path / "c.tum")
    assert "converted 1200 samples" in res.stdout
    first = read_run(tmp_path / "c.gpx")
    line = next(ln for ln in (tmp_path / "c.tum").read_text().splitlines() if ln.startswith("# posefix"))
    origin = line.split("lat=")[1].split()[0] + "," + line.split("lon=")[1].split()[0] + "," + line.split("alt=")[1]
    back = read_run(tmp_path / "c.tum", origin=[float(v) for v in origin.split(",")])
    assert np.abs(back.lat_deg - first.lat_deg).max() < 1e-9
    ok("convert", tmp_path / "c.tum", tmp_path / "again.csv", "--origin", origin)


def _bad_csv(tmp_path: Path) -> Path:
    p = tmp_path / "bad.csv"
    p.write_text("t,lat,lon,alt,qw,qx,qy,qz\n0,60,24,0,1,0,0,0\n1,60,24,0,0,0,0,0\n")
    return p


def test_bad_run_prints_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "out.csv"
    res = posefix("correct", _bad_csv(tmp_path), "--output", out)
    assert_one_line_error(res, "bad.csv:3", "qw,qx,qy,qz", "zero quaternion")
    assert not out.exists() and leftovers(tmp_path) == []
    res = posefix("convert", _bad_csv(tmp_path), out)
    assert_one_line_error(res, "bad.csv:3")
    assert not out.exists()


def test_bad_edits_and_unmatched_times(simulated, tmp_path):
    out = tmp_path / "out.csv"
    bad = tmp_path / "edits.json"
    bad.write_text('{"edits": [\n {"t": 1, "lat": "x", "lon": 2}]}')
    assert_one_line_error(posefix("correct", simulated / "run.csv", "-e", bad, "-o", out), "edits.json:2", "edits[0].lat")
    bad.write_text('{"edits": [{"t": 12.3456, "lat": 60.17, "lon": 24.94}]}')
    assert_one_line_error(posefix("correct", simulated / "run.csv", "-e", bad, "-o", out), "edits[0].t", "matches no sample")
    assert not out.exists()


@pytest.mark.parametrize("args,fragments", [
    (["correct", "RUN", "-o", "OUT.csv", "--keyframes-every-s", "1", "--keyframes-every-m", "5"], ["either"]),
    (["correct", "RUN", "-o", "OUT.csv", "--keyframes-every-s", "0"], ["positive"]),
    (["correct", "RUN", "-o", "OUT.xyz"], ["unknown file extension"]),
    (["correct", "RUN", "-o", "OUT.csv", "--format", "kml"], ["--format", "writable"]),
    (["correct", "RUN", "-o", "missing/OUT.csv"], ["does not exist"]),
    (["correct", "RUN", "-o", "RUN"], ["overwrite an input"]),
    (["simulate", "--out", "d", "--regime", "foggy"], ["unknown regime"]),
    (["convert", "x.tum", "y.csv", "--origin", "60,abc"], ["--origin"]),
    (["evaluate", "RUN", "nothing.csv"], ["no such file"]),
])
def test_usage_errors_are_one_line(simulated, tmp_path, args, fragments):
    # in-process (click's runner) to keep the suite quick; the subprocess tests above
    # cover the real entry point
    (tmp_path / "x.tum").write_text("0 0 0 0 0 0 0 1\n")
    run = str(simulated / "run.csv")
    args = [run if a == "RUN" else str(tmp_path / a) if a in ("OUT.csv", "OUT.xyz", "missing/OUT.csv", "d", "x.tum", "y.csv", "nothing.csv") else a for a in args]
    res = in_process(*args)
    assert_one_line_error(res, *fragments)


def in_process(*args):
    from click.testing import CliRunner

    from posefix.cli import build_app

    app = build_app()
    res = CliRunner().invoke(app, [str(a) for a in args])
    return subprocess.CompletedProcess(args, res.exit_code, res.stdout, res.stderr)


def test_help_explains_options_with_units():
    text = in_process("correct", "--help").stdout
    for needle in ("--edits", "--output", "--config", "--keyframes-every-s", "--keyframes-every-m", "--format", "seconds", "metres"):
        assert needle in text
    sim = in_process("simulate", "--help").stdout
    for needle in ("--duration-s", "--rate-hz", "--edit-every-s", "--seed", "--osm", "--regime", "Hz", "seconds"):
        assert needle in sim
    assert "--json" in in_process("evaluate", "--help").stdout
    assert "--origin" in in_process("convert", "--help").stdout
    assert "correct" in ok("--help").stdout  # the installed entry point lists the command


def test_bad_config_is_one_line(simulated, tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[location]\nsigma_h_m = 'three'\n")
    res = in_process("correct", simulated / "run.csv", "-e", simulated / "edits.json", "-o", tmp_path / "o.csv", "--config", cfg)
    assert_one_line_error(res, "bad.toml", "sigma_h_m")
    assert not (tmp_path / "o.csv").exists()
