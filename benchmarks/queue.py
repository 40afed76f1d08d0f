"""Benchmark the task queue over loopback HTTP on PostgreSQL.

    python -m benchmarks.queue [--quick] [--operators N] [--seconds S] [--database-url URL]

Creates a fresh PostgreSQL database (on the server of POSEFIX_TEST_PG_URL, default
127.0.0.1:5432), migrates it, imports RUNS copies of a simulated 2-minute drive
(121 keyframes), creates one task over them with 50 assignments per run, and starts
``posefix serve --workers 2`` (no job worker: this measures the API, not the engine). Then N
simulated operators (default 50), each with its own API token and connection, loop with no
think time for S seconds (default 20; bounded), then paced like people (a think time
of 0.5-1.5 x 2 s before asking and before submitting) for S more seconds: ``POST /tasks/next``
(an atomic lease) and ``POST /assignments/{id}/submit`` with one moved keyframe (the edit
rules are checked against the run, as a browser's submit would be).

Prints cycles per second and the p50/p95 latency of each call for both phases, beside
targets and their ratio: saturated throughput ≥ 20 cycles/s (each of 50 operators finishing
a task every 2.5 s, far above human pace); paced p95 ≤ 250 ms (the service's interactive
target). Saturated latencies have no target: with no think time a closed loop's latency is
operators / throughput (Little's law). Checks the invariants afterwards: no assignment
leased twice, no run done twice by one operator, every 2xx submit stored exactly once.
The database is dropped at the end.
"""

from __future__ import annotations

import argparse
import os
import random
import tempfile
import threading
import time
import uuid
from pathlib import Path

import httpx

import subprocess

from benchmarks.server import Row, free_port, print_table
from benchmarks.server import start_server as serve

PG_URL = os.environ.get("POSEFIX_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _pg_exec(sql: str) -> None:
    import psycopg

    with psycopg.connect(PG_URL.replace("postgresql+psycopg://", "postgresql://"), autocommit=True) as conn:
        conn.execute(sql)


def prepare(url: str, data_dir: Path, n_runs: int, n_operators: int) -> tuple[list[str], dict[int, dict]]:
    """Migrate, create accounts and tokens, import runs, create the task (in-process)."""
    os.environ.update({"POSEFIX_DATABASE_URL": url, "POSEFIX_DATA_DIR": str(data_dir), "POSEFIX_ENVIRONMENT": "test"})
    from posefix.db import upgrade_database
    from posefix.config import Settings
    from posefix.core.simulate import simulate
    from posefix.db import Database
    from posefix.io import write_run
    from posefix.runs import service as runs_service
    from posefix.security import hash_password
    from posefix.tasks import clock, lifecycle
    from posefix.tasks.schemas import TaskCreate
    from posefix.users.models import Role, TokenScope, User
    from posefix.users.service import Principal, create_token
    from posefix.runs.access import visible_run_ids

    settings = Settings()
    upgrade_database(url)
    db = Database(url)
    sim = simulate(duration_s=120, rate_hz=5, seed=7, edit_every_s=0, regime="drift")
    csv = data_dir / "drive.csv"
    write_run(sim.run, csv)
    tokens: list[str] = []
    moves: dict[int, dict] = {}
    try:
        with db.transaction() as s:
            digest = hash_password("bench-password")
            admin = User(username="bench-admin", password_hash=digest, role=Role.admin, disabled=False)
            ops = [User(username=f"bench-op{i:03d}", password_hash=digest, role=Role.operator, disabled=False) for i in range(n_operators)]
            s.add_all([admin, *ops])
            s.flush()
            for u in ops:
                p = Principal(user_id=u.id, username=u.username, role=Role.operator, via="session", scope=TokenScope.write, credential_hash="")
                tokens.append(create_token(s, settings, p, "bench", TokenScope.write)[1])
            ap = Principal(user_id=admin.id, username=admin.username, role=Role.admin, via="session", scope=TokenScope.write, credential_hash="")
        run_ids = []
        for i in range(n_runs):
            with db.transaction() as s, csv.open("rb") as fh:
                run = runs_service.import_run(s, settings, ap, name=f"bench-{i}", file_name=csv.name, file=fh, images=[])
                run_ids.append(run.id)
        from posefix.runs.repository import keyframe_columns

        with db.transaction() as s:
            for rid in run_ids:
                k, _, _, lon, lat, _ = keyframe_columns(s, rid)[4]
                moves[rid] = {"index": k, "lon": lon + 1e-5, "lat": lat}
            body = TaskCreate(title="bench", run_ids=run_ids, assignments_per_run=min(n_operators, 50), lease_s=600)
            lifecycle.create_task(s, settings, ap, body, clock.now(), visible=visible_run_ids(ap, settings))
    finally:
        db.dispose()
    return tokens, moves


def start_server(env: dict[str, str], port: int, log_path: Path, workers: int) -> subprocess.Popen:
    """``posefix serve`` with ``workers`` HTTP processes (several need PostgreSQL), no worker."""
    return serve(env, port, log_path, ("--workers", str(workers), "--no-embedded-worker"))


class Stats:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.lat: dict[str, list[float]] = {"next": [], "submit": []}
        self.cycles = 0
        self.empty = 0
        self.errors: list[str] = []
        self.submitted: list[int] = []

    def p(self, kind: str, q: float) -> float:
        xs = sorted(self.lat[kind])
        return 1000 * xs[min(int(q * len(xs)), len(xs) - 1)] if xs else float("nan")


def operator(base: str, token: str, moves: dict[int, dict], deadline: float, stats: Stats, think_s: float) -> None:
    rng = random.Random(token)
    with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=60) as c:
        while time.perf_counter() < deadline:
            if think_s:
                time.sleep(rng.uniform(0.5, 1.5) * think_s)
            t0 = time.perf_counter()
            r = c.post("/api/v1/tasks/next")
            t1 = time.perf_counter()
            if r.status_code != 200:
                with stats.lock:
                    stats.errors.append(f"next {r.status_code} {r.text[:120]}")
                continue
            a = r.json()["assignment"]
            with stats.lock:
                stats.lat["next"].append(t1 - t0)
            if a is None:
                with stats.lock:
                    stats.empty += 1
                return  # this operator has done every run
            if think_s:
                time.sleep(rng.uniform(0.5, 1.5) * think_s)  # the operator corrects the run
            t1 = time.perf_counter()
            r = c.post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": [moves[a["run_id"]]]})
            t2 = time.perf_counter()
            with stats.lock:
                if r.status_code == 200:
                    stats.lat["submit"].append(t2 - t1)
                    stats.cycles += 1
                    stats.submitted.append(a["id"])
                else:
                    stats.errors.append(f"submit {r.status_code} {r.text[:120]}")


def check_invariants(url: str, submitted: list[int]) -> list[str]:
    from sqlalchemy import create_engine, text

    eng = create_engine(url)
    problems = []
    with eng.connect() as conn:
        twice = conn.execute(text(
            "SELECT count(*) FROM (SELECT operator_id, run_id FROM assignments WHERE operator_id IS NOT NULL "
            "GROUP BY operator_id, run_id HAVING count(*) > 1) x")).scalar()
        if twice:
            problems.append(f"{twice} (operator, run) pairs leased twice")
        stored = conn.execute(text(
            "SELECT count(*) FROM assignments WHERE status = 'submitted' AND id = ANY(:ids)"), {"ids": submitted}).scalar()
        if stored != len(submitted) or len(set(submitted)) != len(submitted):
            problems.append(f"{len(submitted)} submits answered 2xx but {stored} stored")
        held = conn.execute(text(
            "SELECT count(*) FROM (SELECT operator_id FROM assignments WHERE status = 'accepted' "
            "GROUP BY operator_id HAVING count(*) > 1) x")).scalar()
        if held:
            problems.append(f"{held} operators hold more than one lease")
    eng.dispose()
    return problems


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10 operators for 5 s (checks the benchmark itself)")
    ap.add_argument("--operators", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2, help="HTTP worker processes of the server")
    ap.add_argument("--think-s", type=float, default=2.0, help="mean think time of the paced phase (s)")
    args = ap.parse_args()
    if args.quick:
        args.operators, args.seconds, args.runs = 10, 5.0, 30
    name = f"posefix_bench_queue_{uuid.uuid4().hex[:8]}"
    url = PG_URL.rsplit("/", 1)[0] + "/" + name
    _pg_exec(f'CREATE DATABASE "{name}"')
    proc = None
    try:
        with tempfile.TemporaryDirectory(prefix="posefix-queue-") as tmp:
            data_dir = Path(tmp) / "var"
            data_dir.mkdir()
            print(f"setting up: {args.runs} runs, {args.operators} operators, PostgreSQL database {name}", flush=True)
            tokens, moves = prepare(url, data_dir, args.runs, args.operators)
            port = free_port()
            env = {"POSEFIX_DATABASE_URL": url, "POSEFIX_DATA_DIR": str(data_dir), "POSEFIX_ENVIRONMENT": "test",
                   "POSEFIX_LOG_LEVEL": "WARNING", "POSEFIX_EMBEDDED_WORKER": "false"}
            log_path = Path(os.environ.get("POSEFIX_BENCH_LOG", Path(tmp) / "server.log"))
            proc = start_server(env, port, log_path, args.workers)
            base = f"http://127.0.0.1:{port}"
            rows: list[Row] = []
            problems: list[str] = []
            for phase, think in (("saturated", 0.0), ("paced", args.think_s)):
                stats = Stats()
                print(f"{phase}: {args.operators} operators for {args.seconds:.0f} s against {base} "
                      f"({args.workers} HTTP processes, think {think:.1f} s)", flush=True)
                started = time.perf_counter()
                deadline = started + args.seconds
                threads = [threading.Thread(target=operator, args=(base, t, moves, deadline, stats, think)) for t in tokens]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(args.seconds + 120)
                elapsed = time.perf_counter() - started
                problems += check_invariants(url, stats.submitted)
                rate = stats.cycles / elapsed
                rows += [
                    Row(f"{phase}: next + submit cycles per second", rate, "/s", 20.0 if phase == "saturated" else None,
                        higher_is_better=True, note=f"{stats.cycles} cycles in {elapsed:.1f} s"),
                    Row(f"{phase}: POST /tasks/next p50", stats.p("next", 0.5), "ms", None),
                    Row(f"{phase}: POST /tasks/next p95", stats.p("next", 0.95), "ms", 250.0 if phase == "paced" else None),
                    Row(f"{phase}: POST /assignments/{{id}}/submit p50", stats.p("submit", 0.5), "ms", None),
                    Row(f"{phase}: POST /assignments/{{id}}/submit p95", stats.p("submit", 0.95), "ms", 250.0 if phase == "paced" else None),
                    Row(f"{phase}: errors", float(len(stats.errors)), "", None, note="; ".join(stats.errors[:2])),
                ]
            print_table(rows)
            print("invariants:", "held (no double lease, one lease per operator, every 2xx submit stored once)"
                  if not problems else "; ".join(problems))
    finally:
        if proc is not None:
            proc.terminate()
            try:
                proc.wait(timeout=15)
            except Exception:  # noqa: BLE001
                proc.kill()
        _pg_exec(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


if __name__ == "__main__":
    main()
