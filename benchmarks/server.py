"""Benchmark the web service end to end over loopback HTTP.

    python -m benchmarks.server [--quick] [--postgres [ADMIN_URL] | --database-url URL] [--workers N]
                                [--operators N] [--load-s S] [--generator-processes P]

Starts ``posefix serve`` (its own process: ``--workers`` uvicorn processes, by default one per
core as ``posefix serve`` does; on SQLite with its job worker beside them, a thread with one
process and a process with several; on PostgreSQL a separate ``posefix worker`` process) on a
fresh data directory, then measures, as a client would see it:

- import: upload of a one-hour 100 Hz run (360,001 samples, 3,601 keyframes) as CSV, from
  the first byte sent to the keyframes GeoJSON being served (target ≤ 3 s);
- latency p50/p95 of the keyframes GeoJSON, a preview with one moved keyframe (target
  p95 ≤ 100 ms) and an edit submission, on that 3,601-keyframe run;
- tiles per second from a PMTiles and an MBTiles file: read in-process, and served over
  HTTP to 8 concurrent clients;
- load: N operators (default 50) for S seconds (default 60) under locust (headless, the
  operators in ``benchmarks/locustfile.py``), each logged in with its own session and looping
  over "load the run's keyframes, drag (preview), fetch 6 tiles" with 0.5-1.5 s of thinking
  between actions (target: no errors, p95 ≤ 250 ms). Each operator behaves as a browser tab
  does: keep-alive connections, gzip accepted, and a reload of the keyframes revalidated with
  ``If-None-Match`` (304 when unchanged) — what every browser does on its own for a
  ``no-cache`` response with an ETag: realism, not a shortcut. locust forks P worker
  processes (``--generator-processes``, default 5; a browser has its own CPU); its CSV
  statistics give the requests, failures and p50/p95 (locust rounds response times above
  100 ms to 2 significant digits), and the table shows the generator's CPU (locust's process
  tree, during the load and with its start-up), the server's CPU, the load average, and beside
  each client-side p95 the server's own p95 (from its /metrics histogram).

``--quick`` shrinks everything (10 min run, 10 operators for 10 s) to check the
benchmark itself in about a minute. Prints one table: figure, target, and their ratio
(ours / target: at most 1.00 meets a latency or time target; at least 1.00 meets a rate).
Figures are wall-clock on this machine and move with what else runs on it.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import random
import shutil
import signal
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import orjson

REPO = Path(__file__).resolve().parents[1]
ADMIN = ("bench-admin", "bench-admin-password")
OPERATOR_PASSWORD = "bench-operator-password"


@dataclass
class Row:
    metric: str
    figure: float
    unit: str
    target: float | None
    higher_is_better: bool = False
    note: str = ""

    def ratio(self) -> float | None:
        return None if not self.target else self.figure / self.target

    def verdict(self) -> str:
        ratio = self.ratio()
        if ratio is None:
            return ""
        return "meets" if (ratio >= 1.0 if self.higher_is_better else ratio <= 1.0) else "MISSES"


@dataclass
class Samples:
    latencies_s: list[float] = field(default_factory=list)

    def p(self, q: float) -> float:
        return float(np.percentile(self.latencies_s, q)) * 1000.0 if self.latencies_s else float("nan")


# ----------------------------------------------------------------------------- the server


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def prepare_database(env: dict[str, str], n_operators: int) -> None:
    """Migrate and create the accounts in-process (same code as `posefix users create`)."""
    os.environ.update(env)
    from posefix.db import upgrade_database
    from posefix.config import Settings
    from posefix.db import Database
    from posefix.users.models import Role
    from posefix.users.service import create_user

    settings = Settings()
    upgrade_database(settings.resolved_database_url)
    db = Database(settings.resolved_database_url)
    try:
        with db.transaction() as session:
            create_user(session, ADMIN[0], ADMIN[1], Role.admin)
            for i in range(n_operators):
                create_user(session, f"bench-op{i:03d}", OPERATOR_PASSWORD, Role.operator)
    finally:
        db.dispose()


def start_server(env: dict[str, str], port: int, log_path: Path, extra_args: tuple[str, ...] = ()) -> subprocess.Popen:
    """``posefix serve`` on loopback (``extra_args`` appended), once it answers /healthz."""
    log = open(log_path, "wb")
    process = subprocess.Popen(
        [str(Path(sys.executable).parent / "posefix"), "serve", "--host", "127.0.0.1", "--port", str(port), "--no-migrate",
         *extra_args],
        env={**os.environ, **env}, stdout=log, stderr=subprocess.STDOUT, cwd=REPO,
    )
    deadline = time.monotonic() + 180  # several processes start; a shared machine is slow
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the server exited with {process.returncode}; see {log_path}")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                return process
        except httpx.TransportError:
            time.sleep(0.2)
    process.terminate()  # not kill: serve stops its HTTP processes and job worker on SIGTERM
    try:
        process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
    raise RuntimeError(f"the server did not answer /healthz within 180 s; see {log_path}")


def login(base: str, username: str, password: str) -> httpx.Client:
    client = httpx.Client(base_url=base, headers={"Origin": base}, timeout=120)
    response = client.post("/api/v1/auth/login", json={"username": username, "password": password})
    response.raise_for_status()
    return client


# ----------------------------------------------------------------------------- the run


def make_run_csv(path: Path, duration_s: float, rate_hz: float) -> int:
    from posefix.core.simulate import simulate
    from posefix.io import write_run

    run = simulate(duration_s=duration_s, rate_hz=rate_hz, seed=11, edit_every_s=0).run
    write_run(run, path, fmt="csv")
    return run.n


def import_run(admin: httpx.Client, csv_path: Path, name: str) -> tuple[float, int]:
    """Seconds from starting the upload to the keyframes being served, and the run id."""
    started = time.perf_counter()
    with open(csv_path, "rb") as handle:
        response = admin.post("/api/v1/runs", data={"name": name}, files={"file": (csv_path.name, handle, "text/csv")})
    if response.status_code != 201:
        raise RuntimeError(f"upload failed: {response.status_code} {response.text[:300]}")
    run_id = response.json()["id"]
    keyframes = admin.get(f"/api/v1/runs/{run_id}/keyframes")
    keyframes.raise_for_status()
    return time.perf_counter() - started, run_id


def timed(fn) -> float:  # type: ignore[no-untyped-def]
    started = time.perf_counter()
    fn()
    return time.perf_counter() - started


def preview_body(features: list[dict], revision: int, rng: random.Random) -> dict:
    """Move one adjustable keyframe by 3-8 m in a random direction."""
    adjustable = [f for f in features if f["properties"]["adjustable"] and not f["properties"]["locked"]]
    feature = rng.choice(adjustable or features)
    lon, lat = feature["geometry"]["coordinates"][:2]
    distance_m, bearing = rng.uniform(3.0, 8.0), rng.uniform(0, 2 * np.pi)
    d_lat = distance_m * np.cos(bearing) / 111_320.0
    d_lon = distance_m * np.sin(bearing) / (111_320.0 * np.cos(np.radians(lat)))
    return {"base_revision": revision, "moves": [{"index": feature["properties"]["index"], "lon": lon + d_lon,
                                                  "lat": lat + d_lat}], "deleted": []}


def wait_for_job(client: httpx.Client, job_id: int, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status = client.get(f"/api/v1/jobs/{job_id}").json()["status"]
        if status == "succeeded":
            return
        if status == "dead":
            raise RuntimeError(f"job {job_id} died")
        time.sleep(0.05)
    raise RuntimeError(f"job {job_id} did not finish in {timeout_s} s")


def latency_rows(admin: httpx.Client, run_id: int, n_keyframes: int, repeats: int) -> list[Row]:
    rng = random.Random(5)
    keyframes = Samples()
    for _ in range(repeats):
        keyframes.latencies_s.append(timed(lambda: admin.get(f"/api/v1/runs/{run_id}/keyframes").raise_for_status()))
    collection = admin.get(f"/api/v1/runs/{run_id}/keyframes").json()
    features, revision = collection["features"], collection["revision"]
    previews = Samples()
    modes: dict[str, int] = {}
    for _ in range(repeats):
        body = preview_body(features, revision, rng)
        started = time.perf_counter()
        response = admin.post(f"/api/v1/runs/{run_id}/preview", json=body)
        previews.latencies_s.append(time.perf_counter() - started)
        response.raise_for_status()
        mode = response.json().get("preview", {}).get("mode", "?")  # local window or full solve
        modes[mode] = modes.get(mode, 0) + 1
    edits = Samples()
    for _ in range(max(3, repeats // 5)):
        body = preview_body(features, revision, rng)
        body["comment"] = "benchmark"
        started = time.perf_counter()
        response = admin.post(f"/api/v1/runs/{run_id}/edits", json=body)
        edits.latencies_s.append(time.perf_counter() - started)
        if response.status_code != 202:
            raise RuntimeError(f"edit refused: {response.status_code} {response.text[:300]}")
        wait_for_job(admin, response.json()["job_id"])
        revision = response.json()["revision"]
    label = f"{n_keyframes:,}-keyframe run"
    return [
        Row(f"keyframes GeoJSON p50 ({label})", keyframes.p(50), "ms", None),
        Row(f"keyframes GeoJSON p95 ({label})", keyframes.p(95), "ms", None),
        Row(f"preview p50 ({label})", previews.p(50), "ms", None),
        Row(f"preview p95 ({label})", previews.p(95), "ms", 100.0,
            note="solves: " + ", ".join(f"{n} {m}" for m, n in sorted(modes.items()))),
        Row(f"edit submission p50 ({label})", edits.p(50), "ms", None),
        Row(f"edit submission p95 ({label})", edits.p(95), "ms", None, note="202 returned; re-optimised by the worker"),
    ]


# ----------------------------------------------------------------------------- tiles


def write_mbtiles_copy(pmtiles_path: Path, mbtiles_path: Path) -> int:
    """The same tiles in an MBTiles file (TMS rows), so both containers serve one data set."""
    from pmtiles.reader import MmapSource, all_tiles

    conn = sqlite3.connect(mbtiles_path)
    conn.execute("CREATE TABLE metadata (name TEXT, value TEXT)")
    conn.execute("CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER, tile_data BLOB)")
    conn.execute("CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row)")
    with open(pmtiles_path, "rb") as handle:
        tiles = [(z, x, (1 << z) - 1 - y, data) for (z, x, y), data in all_tiles(MmapSource(handle))]
    conn.executemany("INSERT INTO tiles VALUES (?, ?, ?, ?)", tiles)
    conn.executemany("INSERT INTO metadata VALUES (?, ?)", [
        ("name", "bench"), ("format", "pbf"), ("minzoom", "12"), ("maxzoom", "16"),
        ("attribution", "© OpenStreetMap contributors"),
    ])
    conn.commit()
    conn.close()
    return len(tiles)


def tile_keys(path: Path) -> list[tuple[int, int, int]]:
    from pmtiles.reader import MmapSource, all_tiles

    with open(path, "rb") as handle:
        return [key for key, _ in all_tiles(MmapSource(handle))]


def in_process_rate(path: Path, keys: list[tuple[int, int, int]], seconds: float) -> float:
    from posefix.tiles.stores import open_tile_file

    store = open_tile_file(path)
    count, started = 0, time.perf_counter()
    while time.perf_counter() - started < seconds:
        for z, x, y in keys:
            assert store.get(z, x, y) is not None
        count += len(keys)
    return count / (time.perf_counter() - started)


async def http_tile_rate(base: str, cookies: httpx.Cookies, source: str, keys: list[tuple[int, int, int]],
                         seconds: float, concurrency: int = 8) -> tuple[float, int]:
    count, errors = 0, 0
    stop_at = time.perf_counter() + seconds
    async with httpx.AsyncClient(base_url=base, cookies=cookies, timeout=30) as client:
        async def fetch_loop(offset: int) -> None:
            nonlocal count, errors
            i = offset
            while time.perf_counter() < stop_at:
                z, x, y = keys[i % len(keys)]
                response = await client.get(f"/api/v1/tiles/{source}/{z}/{x}/{y}.pbf")
                count += 1
                errors += response.status_code != 200
                i += concurrency

        started = time.perf_counter()
        await asyncio.gather(*(fetch_loop(i) for i in range(concurrency)))
        return count / (time.perf_counter() - started), errors


# ----------------------------------------------------------------------------- load


def login_operators(base: str, n_operators: int) -> list[httpx.Cookies]:
    """One browser session per operator, made before the load starts (logins are not timed:
    argon2id is slow on purpose)."""
    sessions = []
    for i in range(n_operators):
        client = login(base, f"bench-op{i:03d}", OPERATOR_PASSWORD)
        sessions.append(client.cookies)
        client.close()
    return sessions


def adjustable_features(features: list[dict]) -> list[dict]:
    return [f for f in features if f["properties"]["adjustable"] and not f["properties"]["locked"]] or features


@dataclass
class LoadStats:
    """locust's statistics of the load, per request kind (``keyframes``, ``preview``, ``tile``)
    and ``"all"``: requests, failures, p50 and p95 in ms (locust keeps response times rounded
    to 2 significant digits above 100 ms, so a p95 moves in 10 ms steps)."""

    requests: dict[str, int]
    failures: dict[str, int]
    p50_ms: dict[str, float]
    p95_ms: dict[str, float]
    errors: list[str]  # "<kind> <error>: <occurrences>", most frequent first
    cpu_s: float  # CPU of locust's processes from test start to stop
    cpu_with_start_up_s: float  # of its whole process tree, start-up included


def read_locust_stats(prefix: Path) -> tuple[dict[str, int], dict[str, int], dict[str, float], dict[str, float], list[str]]:
    """Parse ``PREFIX_stats.csv`` (one row per request name and an ``Aggregated`` row) and
    ``PREFIX_failures.csv``."""
    import csv

    requests, failures, p50, p95 = {}, {}, {}, {}
    with open(f"{prefix}_stats.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            kind = "all" if row["Name"] == "Aggregated" else row["Name"]
            requests[kind], failures[kind] = int(row["Request Count"]), int(row["Failure Count"])
            p50[kind] = float(row["50%"]) if row["50%"] != "N/A" else float("nan")
            p95[kind] = float(row["95%"]) if row["95%"] != "N/A" else float("nan")
    with open(f"{prefix}_failures.csv", newline="") as handle:
        rows = sorted(csv.DictReader(handle), key=lambda r: -int(r["Occurrences"]))
    errors = [f"{r['Name']} {r['Error']}: {r['Occurrences']}" for r in rows]
    return requests, failures, p50, p95, errors


def run_load(base: str, sessions: list[httpx.Cookies], seconds: float, run_id: int,
             tiles: list[tuple[int, int, int]], processes: int, workdir: Path) -> LoadStats:
    """The operators (benchmarks/locustfile.py) under locust, headless, spread over
    ``processes`` forked locust worker processes (a browser per operator has its own CPU; one
    process for all 50 would make every operator wait while another parses its GeoJSON)."""
    import resource

    spawn_s = 1.0  # -r N spawns the N operators within 1 s; they start the load together after it
    config = workdir / "load.json"
    config.write_text(orjson.dumps({
        "run_id": run_id, "tiles": tiles, "seconds": seconds, "spawn_s": spawn_s,
        "sessions": [[{"name": c.name, "value": c.value, "domain": c.domain, "path": c.path} for c in jar.jar]
                     for jar in sessions],
    }).decode())
    config.with_suffix(".claims").mkdir()
    prefix, log_path = workdir / "locust", workdir / "locust.log"
    n = len(sessions)
    command = [str(Path(sys.executable).parent / "locust"), "-f", str(REPO / "benchmarks" / "locustfile.py"),
               "--headless", "-u", str(n), "-r", str(n), "-t", f"{spawn_s + seconds + 3:.0f}s",
               "--processes", str(max(1, min(processes, n))), "--host", base, "--csv", str(prefix),
               "--only-summary", "--loglevel", "WARNING"]
    env = {**os.environ, "POSEFIX_BENCH_LOAD": str(config),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH", "")]))}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)  # locust reaps its workers, this process reaps locust
    with open(log_path, "wb") as log:
        returncode = subprocess.run(command, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=REPO).returncode
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if not Path(f"{prefix}_stats.csv").exists():
        raise RuntimeError(f"locust exited with {returncode} and wrote no statistics; see {log_path}")
    requests, failures, p50, p95, errors = read_locust_stats(prefix)
    if len(list(config.with_suffix(".claims").iterdir())) != n:
        raise RuntimeError(f"not every operator started; see {log_path}")
    cpu_dir = config.with_suffix(".cpu")
    if len(list(cpu_dir.iterdir())) != max(1, min(processes, n)) + 1:
        raise RuntimeError(f"not every locust process reported its CPU in {cpu_dir}; see {log_path}")
    cpu_s = sum(float(path.read_text()) for path in cpu_dir.iterdir())
    cpu_with_start_up_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return LoadStats(requests, failures, p50, p95, errors, cpu_s, cpu_with_start_up_s)


def _stat(pid: int) -> list[str] | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def process_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process, its live children (uvicorn's worker processes)
    and its reaped children have used (Linux /proc)."""
    fields = _stat(pid)
    if fields is None:
        return float("nan")
    total = sum(int(v) for v in fields[11:15])
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (child := _stat(int(entry.name))) is not None and child[1] == str(pid):
            total += sum(int(v) for v in child[11:13])
    return total / os.sysconf("SC_CLK_TCK")


def create_postgres_database(admin_url: str) -> tuple[str, str]:
    """A fresh database on the PostgreSQL server of ``admin_url``: (its URL, its name)."""
    import uuid

    from sqlalchemy import create_engine, text
    from sqlalchemy.engine import make_url

    name = f"posefix_bench_{uuid.uuid4().hex[:10]}"
    engine = create_engine(admin_url, isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    engine.dispose()
    return make_url(admin_url).set(database=name).render_as_string(hide_password=False), name


def drop_postgres_database(admin_url: str, name: str) -> None:
    from sqlalchemy import create_engine, text

    engine = create_engine(admin_url, isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    engine.dispose()


def start_worker(env: dict[str, str], log_path: Path) -> subprocess.Popen:
    """A ``posefix worker`` process (PostgreSQL: the API processes run no embedded worker)."""
    return subprocess.Popen([str(Path(sys.executable).parent / "posefix"), "worker"], env={**os.environ, **env},
                            stdout=open(log_path, "wb"), stderr=subprocess.STDOUT, cwd=REPO)


def latency_buckets(base: str) -> dict[tuple[str, str], dict[float, float]]:
    """The server's own latency histogram (GET /metrics): (method, route) -> {upper bound s: count}."""
    from prometheus_client.parser import text_string_to_metric_families

    out: dict[tuple[str, str], dict[float, float]] = {}
    for family in text_string_to_metric_families(httpx.get(f"{base}/metrics", timeout=30).text):
        for sample in family.samples:
            if sample.name == "posefix_http_request_duration_seconds_bucket":
                key = (sample.labels["method"], sample.labels["route"])
                out.setdefault(key, {})[float(sample.labels["le"])] = sample.value
    return out


def server_p95_s(before: dict, after: dict, method: str, route: str) -> float:
    """Upper bound of the histogram bucket holding the server-side 95th percentile between two
    snapshots (time inside the app, background tasks included)."""
    b, a = before.get((method, route), {}), after.get((method, route), {})
    bounds = sorted(a)
    counts = [a[le] - b.get(le, 0.0) for le in bounds]
    if not counts or counts[-1] <= 0:
        return float("nan")
    return next(le for le, c in zip(bounds, counts) if c >= 0.95 * counts[-1])


# ----------------------------------------------------------------------------- main


def print_table(rows: list[Row]) -> None:
    print()
    header = f"{'metric':<52} {'ours':>11} {'target':>11} {'ratio':>7}  verdict"
    print(header)
    print("-" * len(header))
    for row in rows:
        target = "" if row.target is None else f"{row.target:,.0f}"
        if row.target is not None:
            target = ("≥ " if row.higher_is_better else "≤ ") + target
        ratio = row.ratio()
        print(f"{row.metric:<52} {row.figure:>8,.1f} {row.unit:<3}{target:>10} "
              f"{'' if ratio is None else f'{ratio:.2f}':>7}  {row.verdict()}{('  ' + row.note) if row.note else ''}")
    print()
    print("ratio = ours / target: ≤ 1.00 meets a time target, ≥ 1.00 meets a rate target.")
    load_1, load_5, _ = os.getloadavg()
    print(f"machine: {os.cpu_count()} CPUs, load average {load_1:.1f} (1 min) {load_5:.1f} (5 min) at the end: "
          "figures taken on a busy machine are slower than the server's own cost.")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small run and a short load: checks the benchmark")
    parser.add_argument("--database-url", default="", help="PostgreSQL URL of an empty database (default: SQLite in a temp dir)")
    parser.add_argument("--postgres", nargs="?", const="postgresql+psycopg://postgres@127.0.0.1:5432/test", default="",
                        metavar="ADMIN_URL", help="a fresh PostgreSQL database made (and dropped) on this server "
                        "(default postgresql+psycopg://postgres@127.0.0.1:5432/test)")
    parser.add_argument("--workers", type=int, default=None,
                        help="uvicorn worker processes of the server (default: posefix serve's, one per core)")
    parser.add_argument("--operators", type=int, default=None, help="simulated operators (default 50; quick 10)")
    parser.add_argument("--load-s", type=float, default=None, help="load duration in s (default 60; quick 10)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary data directory")
    parser.add_argument("--generator-processes", type=int, default=5,
                        help="locust worker processes the operators are spread over (default 5)")
    args = parser.parse_args()
    quick = args.quick
    n_operators = args.operators or (10 if quick else 50)
    load_s = args.load_s or (10.0 if quick else 60.0)
    duration_s, rate_hz = (600.0, 100.0) if quick else (3600.0, 100.0)

    workdir = Path(tempfile.mkdtemp(prefix="posefix-bench-"))
    pg_name = ""
    if args.postgres:
        args.database_url, pg_name = create_postgres_database(args.postgres)
    from posefix.serving import default_http_processes

    args.workers = args.workers or default_http_processes()
    env = {
        "POSEFIX_DATA_DIR": str(workdir / "var"),
        "POSEFIX_ENVIRONMENT": "development",
        "POSEFIX_OPERATORS_SEE_ALL_RUNS": "true",
        "POSEFIX_LOG_LEVEL": "WARNING",
        "POSEFIX_DATABASE_URL": args.database_url,
    }
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    rows: list[Row] = []
    server = job_worker = None
    try:
        print(f"· data in {workdir}; creating {n_operators} operators", flush=True)
        prepare_database(env, n_operators)
        server = start_server(env, port, workdir / "server.log", ("--workers", str(args.workers)))
        if args.database_url:
            job_worker = start_worker(env, workdir / "worker.log")
        print(f"· server: {args.workers} uvicorn process(es) on {'PostgreSQL' if args.database_url else 'SQLite'}, "
              f"job worker {'process' if args.database_url or args.workers > 1 else 'thread'}", flush=True)
        admin = login(base, *ADMIN)

        print(f"· simulating a {duration_s / 60:.0f} min {rate_hz:g} Hz run", flush=True)
        csv_path = workdir / "run.csv"
        n_samples = make_run_csv(csv_path, duration_s, rate_hz)
        import_times = []
        run_id = 0
        for attempt in range(1 if quick else 3):
            seconds, run_id = import_run(admin, csv_path, f"bench run {attempt}")
            import_times.append(seconds)
        n_keyframes = len(admin.get(f"/api/v1/runs/{run_id}/keyframes").json()["features"])
        rows.append(Row(f"import {n_samples:,} samples → keyframes ready (median)", statistics.median(import_times),
                        "s", 3.0, note=f"CSV {csv_path.stat().st_size / 1e6:.0f} MB over loopback"))

        print(f"· latencies on the {n_keyframes}-keyframe run", flush=True)
        rows += latency_rows(admin, run_id, n_keyframes, repeats=15 if quick else 50)

        print("· tiles", flush=True)
        from posefix.basemap import build_basemap

        tiles_dir = workdir / "var" / "tiles"
        build_basemap(REPO / "data" / "osm" / "helsinki.osm.pbf", tiles_dir / "bench.pmtiles")
        write_mbtiles_copy(tiles_dir / "bench.pmtiles", tiles_dir / "bench.mbtiles")
        for name, file in (("bench-pm", "bench.pmtiles"), ("bench-mb", "bench.mbtiles")):
            response = admin.post("/api/v1/tile-sources", json={"name": name, "kind": "street", "path": f"tiles/{file}"})
            response.raise_for_status()
        keys = tile_keys(tiles_dir / "bench.pmtiles")
        seconds = 1.0 if quick else 3.0
        for label, file in (("PMTiles", "bench.pmtiles"), ("MBTiles", "bench.mbtiles")):
            rows.append(Row(f"tiles/s in-process ({label})", in_process_rate(tiles_dir / file, keys, seconds),
                            "/s", 5000.0, higher_is_better=True))
        for label, source in (("PMTiles", "bench-pm"), ("MBTiles", "bench-mb")):
            rate, errors = asyncio.run(http_tile_rate(base, admin.cookies, source, keys, seconds * 2))
            rows.append(Row(f"tiles/s over HTTP, 8 clients ({label})", rate, "/s", 300.0, higher_is_better=True,
                            note=f"{errors} errors" if errors else ""))

        print(f"· load: {n_operators} operators for {load_s:.0f} s", flush=True)
        sessions = login_operators(base, n_operators)
        before = latency_buckets(base)
        server_cpu_before = process_cpu_s(server.pid)
        load = run_load(base, sessions, load_s, run_id, keys[-40:], args.generator_processes, workdir)
        generator_cpu = load.cpu_s / load_s
        server_cpu = (process_cpu_s(server.pid) - server_cpu_before) / load_s
        load_during = os.getloadavg()[0]  # the 1-minute average: nearly the load run's own minute
        after = latency_buckets(base)
        rows.append(Row(f"load: requests ({n_operators} operators, {load_s:.0f} s)", load.requests["all"], "",
                        None, note=f"{load.requests['all'] / load_s:.0f} req/s"))
        rows.append(Row("load: errors", load.failures["all"], "", None,
                        note="target 0" + (f"; {'; '.join(load.errors)[:200]}" if load.errors else "")))
        rows.append(Row("load: CPU of the load generator", 100 * generator_cpu, "%", None,
                        note=f"of one core, locust with {args.generator_processes} worker processes "
                             f"({100 * load.cpu_with_start_up_s / load_s:.0f} % with its start-up); "
                             f"server process {100 * server_cpu:.0f} %; {os.cpu_count()} CPUs, "
                             f"load average {load_during:.1f} at the end of the load"))
        rows.append(Row("load: p50", load.p50_ms["all"], "ms", None))
        rows.append(Row("load: p95", load.p95_ms["all"], "ms", 250.0))
        routes = {"keyframes": ("GET", "/runs/{run_id}/keyframes"), "preview": ("POST", "/runs/{run_id}/preview"),
                  "tile": ("GET", "/tiles/{source}/{z:int}/{x:int}/{y:int}.{ext}")}
        for kind in sorted(k for k in load.requests if k != "all"):
            inside_s = server_p95_s(before, after, *routes[kind]) if kind in routes else float("nan")
            rows.append(Row(f"load: p95 of {kind} requests", load.p95_ms[kind], "ms", None,
                            note=f"{load.requests[kind]} requests; server-side p95 ≤ {inside_s * 1000:,.0f} ms (histogram bucket)"))
        admin.close()
    except BaseException:
        print_table(rows)
        print(f"the benchmark stopped early; server log: {workdir / 'server.log'}", file=sys.stderr)
        args.keep = True
        raise
    finally:
        for process in (server, job_worker):
            if process is None:
                continue
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
        if pg_name:
            drop_postgres_database(args.postgres, pg_name)
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    print_table(rows)
    load_errors = next((row.figure for row in rows if row.metric == "load: errors"), 0)
    if load_errors:
        sys.exit(1)


if __name__ == "__main__":
    main()
