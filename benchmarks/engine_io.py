"""Benchmark the engine's I/O path on a one-hour 100 Hz run (360,001 samples, 36 edits).

    python -m benchmarks.engine_io [--duration-s 3600] [--rate-hz 100]

Prints one table: each figure beside its baseline or target, with the ratio (ours /
baseline; below 1.0 is better). Timings are wall-clock on this machine, best of a few
repeats, so they move with the load other processes put on it; the CPU seconds (user +
system, including threads and child processes) of the same call are printed beside them,
which a busy shared machine disturbs far less.

- simulate: ``posefix.core.simulate.simulate`` (target: "a couple of seconds").
- CSV parse: ``posefix.io.read_run`` vs the naive baseline (stdlib ``csv`` reading every
  row and converting fields one by one) and the issue's target (well under 1 s).
- CSV write: ``posefix.io.write_run``; GeoJSON/GPX write and GeoJSON read beside the CSV
  figures (GPX read, through gpxpy, is far slower and left out).
- posefix correct: the whole process, CSV in and out (target 2.5 s).
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    args = ap.parse_args()

    from posefix.core.simulate import simulate
    from posefix.io import EditSet, Move, read_run, write_edits, write_run

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        holder = {}

        def sim():
            holder["sim"] = simulate(args.duration_s, args.rate_hz, 100.0, seed=1, regime="mixed")

        t_sim = best_of(sim, 1)
        s = holder["sim"]
        rows.append(("simulate (mixed regime)", t_sim, CPU["last"], 2.0, "target"))
        t_write = best_of(lambda: write_run(s.run, d / "run.csv"))
        c_write = CPU["last"]
        write_edits(EditSet(moves=[Move(e.t_s, e.lat_deg, e.lon_deg) for e in s.edits]), d / "edits.json")
        t_read = best_of(lambda: read_run(d / "run.csv"))
        c_read = CPU["last"]
        t_naive = best_of(lambda: naive_parse(d / "run.csv"), 1)
        rows.append(("CSV parse vs stdlib csv", t_read, c_read, t_naive, "baseline"))
        rows.append(("CSV parse vs target", t_read, c_read, 1.0, "target"))
        rows.append(("CSV write", t_write, c_write, t_naive, "baseline (naive parse)"))
        for ext in ("geojson", "gpx"):
            t_w = best_of(lambda: write_run(s.run, d / f"run.{ext}"), 1)
            rows.append((f"{ext} write", t_w, CPU["last"], t_write, "CSV write"))
        t_r = best_of(lambda: read_run(d / "run.geojson"), 1)
        rows.append(("geojson read", t_r, CPU["last"], t_read, "CSV parse"))
        cmd = [sys.executable, "-c", "from posefix.cli import main; main()", "correct", str(d / "run.csv"),
               "--edits", str(d / "edits.json"), "--output", str(d / "out.csv"), "--quiet"]

        def run_cli():
            subprocess.run(cmd, check=True)

        t_cli = best_of(run_cli, 3)
        rows.append(("posefix correct, whole process", t_cli, CPU["last"], 2.5, "target"))
        n = s.run.n

    print(f"\nengine I/O benchmark: {n} samples, {len(s.edits)} edits\n")
    print(f"{'measure':<34}{'ours (s)':>10}{'cpu (s)':>10}{'ref (s)':>10}{'ratio':>8}  ref")
    for name, ours, cpu, ref, kind in rows:
        print(f"{name:<34}{ours:>10.3f}{cpu:>10.3f}{ref:>10.3f}{ours / ref:>8.2f}  {kind}")
    print(f"\nload average now: {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
