"""Benchmark the engine's I/O and whole-process paths against plain scripts, in one run.

    python -m benchmarks.engine_io [--duration-s 3600] [--rate-hz 100] [--repeats 5] [--formats-only] [--gpx-read]

Prints one table: each figure beside its peer or target, with the ratios (ours / ref;
below 1.0 is better) of wall time and of CPU time. Timings are wall-clock, best of a few
repeats, so they move with the load other processes put on the machine; the CPU seconds
(user + system, threads and child processes included) of the same call are printed beside
them, which a busy shared machine disturbs far less (a target is read as CPU seconds in the
CPU ratio: on an idle machine wall time is at most that, less where threads share the work). Whole processes of ours and of the peers alternate, so each repeat sees
the same load.

Peers (``benchmarks/peers``): the GTSAM script (pyarrow CSV in, keyframes every second,
Pose3 + GPSFactor/Cauchy + BetweenFactorPose3 + edits as tight GPS factors, LM, the
correction interpolated to every sample, pyarrow CSV out) and the naive script (edit
offsets interpolated in time). Bytecode of posefix and the peers is compiled first, as an
install does.

Parts:
- hour at 100 Hz (``posefix.core.simulate``, mixed regime, seed 1, 36 edits): CSV parse
  (target 0.25 s) beside the stdlib ``csv`` reader, CSV write (target 0.3 s), the Parquet
  and Arrow IPC round trips (target 0.1 s), GeoJSON/GPX beside CSV (GeoJSON read and GPX
  write target 0.5 s; GPX read through gpxpy with ``--gpx-read``), and ``posefix correct``
  as a whole process against both scripts (target <= 0.5x GTSAM and under the naive script).
- small runs, whole process: the real comma2k19 drive (1,200 rows, 3 edits; the run the
  start-up work was profiled on: tuned) and a held-out simulated 2-minute drive at 10 Hz
  (1,201 rows, seed 7, never profiled), target <= 0.5x the GTSAM script.
- the CLI's own cost: ``posefix --version`` beside ``python -c pass`` (target: the
  difference under 0.1 s).
"""

from __future__ import annotations

import argparse
import csv
import resource
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


CPU: dict[str, float] = {}


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (user + system)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def best_of(fn, repeats: int = 3) -> float:
    """Best wall time of ``repeats`` calls; the CPU time of that call goes in ``CPU["last"]``."""
    best = float("inf")
    for _ in range(repeats):
        c = _cpu_s()
        t = time.perf_counter()
        fn()
        wall = time.perf_counter() - t
        if wall < best:
            best, CPU["last"] = wall, _cpu_s() - c
    return best


def naive_parse(path: Path) -> int:
    rows = 0
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        next(reader)
        for row in reader:
            [float(v) if v else float("nan") for v in row]
            rows += 1
    return rows


REPO = Path(__file__).resolve().parents[1]
PEERS = Path(__file__).resolve().parent / "peers"
POSEFIX = [sys.executable, "-c", "from posefix.cli import main; main()"]


def compile_bytecode() -> None:
    """What an install does (this machine's shells may set PYTHONDONTWRITEBYTECODE)."""
    import posefix

    subprocess.run([sys.executable, "-m", "compileall", "-q", str(Path(posefix.__file__).parent), str(PEERS)],
                   check=True, stdout=subprocess.DEVNULL)


def whole_processes(cmds: dict[str, list[str]], repeats: int) -> dict[str, tuple[float, float]]:
    """Best wall time (and its CPU) of each command, the commands alternating per repeat."""
    best: dict[str, tuple[float, float]] = {k: (float("inf"), 0.0) for k in cmds}
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    for _ in range(repeats):
        for name, cmd in cmds.items():
            c = _cpu_s()
            t = time.perf_counter()
            subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
            wall = time.perf_counter() - t
            if wall < best[name][0]:
                best[name] = (wall, _cpu_s() - c)
    return best


def correct_commands(run: Path, edits: Path, out_dir: Path) -> dict[str, list[str]]:
    return {
        "posefix": POSEFIX + ["correct", str(run), "--edits", str(edits), "--output", str(out_dir / "pf.csv"), "--quiet"],
        "gtsam": [sys.executable, str(PEERS / "gtsam_correct.py"), str(run), str(edits), str(out_dir / "gt.csv")],
        "naive": [sys.executable, str(PEERS / "naive_correct.py"), str(run), str(edits), str(out_dir / "nv.csv")],
    }


def add_whole_process_rows(rows: list, label: str, best: dict[str, tuple[float, float]]) -> None:
    ours, cpu = best["posefix"]
    rows.append((f"{label}: correct vs GTSAM", ours, cpu, best["gtsam"][0], "GTSAM script", best["gtsam"][1]))
    rows.append((f"{label}: correct vs naive", ours, cpu, best["naive"][0], "naive script", best["naive"][1]))


def comma2k19_run(d: Path) -> tuple[Path, Path]:
    """The real drive in data/ as CSV, with three 3 m moves north at 1/4, 1/2 and 3/4."""
    from posefix.io import EditSet, Move, read_run, write_edits, write_run

    run = read_run(REPO / "data" / "comma2k19")
    write_run(run, d / "comma.csv")
    picks = [int(run.n * f) for f in (0.25, 0.5, 0.75)]
    moves = [Move(float(run.t_s[i]), float(run.lat_deg[i]) + 3.0 / 111_320, float(run.lon_deg[i])) for i in picks]
    write_edits(EditSet(moves=moves), d / "comma-edits.json")
    return d / "comma.csv", d / "comma-edits.json"


def simulated_run(d: Path, name: str, duration_s: float, rate_hz: float, seed: int):
    from posefix.core.simulate import simulate
    from posefix.io import EditSet, Move, write_edits, write_run

    s = simulate(duration_s, rate_hz, 100.0 if duration_s > 600 else 30.0, seed=seed, regime="mixed")
    write_run(s.run, d / f"{name}.csv")
    write_edits(EditSet(moves=[Move(e.t_s, e.lat_deg, e.lon_deg) for e in s.edits]), d / f"{name}-edits.json")
    return s, d / f"{name}.csv", d / f"{name}-edits.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--formats-only", action="store_true", help="stop after the hour's file formats (no whole processes)")
    ap.add_argument("--gpx-read", action="store_true", help="also time reading the hour's GPX (gpxpy: some 10 s)")
    args = ap.parse_args()
    compile_bytecode()

    from posefix.io import read_run, write_run

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        holder = {}

        def sim():
            holder["sim"] = simulated_run(d, "hour", args.duration_s, args.rate_hz, 1)

        t_sim = best_of(sim, 1)
        s, hour_csv, hour_edits = holder["sim"]
        rows.append(("simulate + write (mixed regime)", t_sim, CPU["last"], 2.0, "target"))
        t_read = best_of(lambda: read_run(hour_csv))
        c_read = CPU["last"]
        t_naive = best_of(lambda: naive_parse(hour_csv), 1)
        rows.append(("CSV parse vs stdlib csv", t_read, c_read, t_naive, "baseline", CPU["last"]))
        rows.append(("CSV parse vs target", t_read, c_read, 0.25, "target"))
        t_write = best_of(lambda: write_run(s.run, d / "w.csv"))
        c_write = CPU["last"]
        rows.append(("CSV write vs target", t_write, c_write, 0.3, "target"))
        for ext, kind in (("parquet", "Parquet"), ("arrow", "Arrow IPC")):
            def round_trip(path: Path = d / f"run.{ext}") -> None:
                write_run(s.run, path)
                read_run(path)

            t_rt = best_of(round_trip)
            rows.append((f"{kind} write + read", t_rt, CPU["last"], 0.1, "target"))
        for ext in ("geojson", "gpx"):
            t_w = best_of(lambda: write_run(s.run, d / f"run.{ext}"))
            rows.append((f"{ext} write vs CSV", t_w, CPU["last"], t_write, "CSV write", c_write))
            if ext == "gpx":
                rows.append(("gpx write vs target", t_w, CPU["last"], 0.5, "target"))
        t_r = best_of(lambda: read_run(d / "run.geojson"))
        rows.append(("geojson read vs CSV", t_r, CPU["last"], t_read, "CSV parse", c_read))
        rows.append(("geojson read vs target", t_r, CPU["last"], 0.5, "target"))
        if args.gpx_read:
            t_r = best_of(lambda: read_run(d / "run.gpx"), 1)
            rows.append(("gpx read (gpxpy) vs CSV", t_r, CPU["last"], t_read, "CSV parse", c_read))
        if args.formats_only:
            n = s.run.n
            _print(rows, n, s, "")
            return
        n = s.run.n
        best = whole_processes(correct_commands(hour_csv, hour_edits, d), max(2, args.repeats // 2))
        add_whole_process_rows(rows, "hour", best)
        rows.append(("hour: correct vs target", best["posefix"][0], best["posefix"][1], 0.5 * best["gtsam"][0],
                     "0.5 x GTSAM script", 0.5 * best["gtsam"][1]))

        comma_csv, comma_edits = comma2k19_run(d)
        best = whole_processes(correct_commands(comma_csv, comma_edits, d), args.repeats)
        add_whole_process_rows(rows, "comma2k19 1,200 (tuned)", best)
        _, small_csv, small_edits = simulated_run(d, "small", 120.0, 10.0, 7)
        best = whole_processes(correct_commands(small_csv, small_edits, d), args.repeats)
        add_whole_process_rows(rows, "sim 1,201 (held out)", best)

        best = whole_processes({"posefix": POSEFIX + ["--version"], "python": [sys.executable, "-c", "pass"]},
                               args.repeats * 2)
        overhead = best["posefix"][0] - best["python"][0]
        rows.append(("CLI overhead (--version - python)", overhead, best["posefix"][1] - best["python"][1], 0.1, "target"))

    _print(rows, n, s, "; small runs 1,200 and 1,201 rows")


def _print(rows: list, n: int, s, small: str) -> None:
    print(f"\nengine I/O benchmark: hour {n} samples, {len(s.edits)} edits{small}\n")
    print(f"{'measure':<42}{'ours (s)':>9}{'cpu (s)':>9}{'ref (s)':>9}{'ref cpu':>9}{'ratio':>7}{'cpu ratio':>10}  ref")
    for name, ours, cpu, ref, kind, *ref_cpu in rows:
        rc = ref_cpu[0] if ref_cpu else ref  # a target: the same seconds either way
        print(f"{name:<42}{ours:>9.3f}{cpu:>9.3f}{ref:>9.3f}{rc:>9.3f}{ours / ref:>7.2f}{cpu / rc:>10.2f}  {kind}")
    print(f"\nload average now: {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
