"""Shared set-up of the tasks tests: a migrated database (SQLite file or a fresh PostgreSQL
database), the real app, users, simulated runs imported through the real service, a worker
drained in-process, and the tasks clock under test control."""

from __future__ import annotations

import atexit
import datetime as dt
import functools
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from alembic import command
from alembic.config import Config
from fastapi.testclient import TestClient

from posefix.config import Settings
from posefix.core.simulate import Simulation, simulate
from posefix.io import write_run
from posefix.main import create_app
from posefix.tasks import clock as task_clock
from posefix.users.models import Role
from posefix.users.service import Principal, create_user

REPO = Path(__file__).resolve().parents[2]
ORIGIN = "http://testserver"
PG_URL = os.environ.get("POSEFIX_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")
PASSWORD = "correct horse battery staple"


def migrate(url: str) -> None:
    cfg = Config(str(REPO / "migrations" / "alembic.ini"))
    cfg.set_main_option("script_location", str(REPO / "migrations"))
    cfg.set_main_option("sqlalchemy.url", url)
    command.upgrade(cfg, "head")


def _pg_admin_exec(sql: str) -> None:
    import psycopg

    raw = PG_URL.replace("postgresql+psycopg://", "postgresql://")
    with psycopg.connect(raw, autocommit=True) as conn:
        conn.execute(sql)


_TEMPLATES: dict[str, str] = {}


def _pg_url(name: str) -> str:
    return PG_URL.rsplit("/", 1)[0] + "/" + name


def _drop_templates() -> None:
    for kind, ref in _TEMPLATES.items():
        if kind == "postgres":
            try:
                _pg_admin_exec(f'DROP DATABASE IF EXISTS "{ref}" WITH (FORCE)')
            except Exception:  # noqa: BLE001 - the server may be gone at exit
                pass
        else:
            Path(ref).unlink(missing_ok=True)


atexit.register(_drop_templates)


def fresh_pg_url() -> tuple[str, str]:
    """A new PostgreSQL database of our own, already migrated: (url, name).

    The migrations run once per test process into a template database; each test copies it
    (CREATE DATABASE ... TEMPLATE), which is much faster than migrating again."""
    if "postgres" not in _TEMPLATES:
        tmpl = f"posefix_tasks_tmpl_{uuid.uuid4().hex[:8]}"
        _pg_admin_exec(f'CREATE DATABASE "{tmpl}"')
        _TEMPLATES["postgres"] = tmpl
        migrate(_pg_url(tmpl))
    name = f"posefix_tasks_{uuid.uuid4().hex[:10]}"
    _pg_admin_exec(f'CREATE DATABASE "{name}" TEMPLATE "{_TEMPLATES["postgres"]}"')
    return _pg_url(name), name


def fresh_sqlite_url(path: Path) -> str:
    """A migrated SQLite file: a copy of one migrated once per test process."""
    if "sqlite" not in _TEMPLATES:
        tmpl = Path(tempfile.mkdtemp(prefix="posefix-tasks-")) / "template.sqlite"
        migrate(f"sqlite:///{tmpl}")
        _TEMPLATES["sqlite"] = str(tmpl)
    shutil.copyfile(_TEMPLATES["sqlite"], path)
    return f"sqlite:///{path}"


@dataclass
class Env:
    app: Any
    settings: Settings
    clock: task_clock.ManualClock
    users: dict[str, int] = field(default_factory=dict)
    clients: dict[str, TestClient] = field(default_factory=dict)
    sims: dict[int, Simulation] = field(default_factory=dict)

    @property
    def db(self) -> Any:
        return self.app.state.db

    def add_user(self, username: str, role: str) -> int:
        with self.db.transaction() as s:
            u = create_user(s, username, PASSWORD, Role(role))
            self.users[username] = u.id
            return u.id

    def add_operators(self, names: list[str]) -> None:
        """Many operators at once: real user rows sharing one argon2 hash (hashing is slow on purpose)."""
        from posefix.security import hash_password
        from posefix.users.models import User

        digest = hash_password(PASSWORD)
        with self.db.transaction() as s:
            rows = [User(username=n, password_hash=digest, role="operator", disabled=False) for n in names]
            s.add_all(rows)
            s.flush()
            self.users.update({u.username: u.id for u in rows})

    def client(self, username: str) -> TestClient:
        if username not in self.clients:
            c = TestClient(self.app, headers={"Origin": ORIGIN})
            r = c.post("/api/v1/auth/login", json={"username": username, "password": PASSWORD})
            assert r.status_code == 200, r.text
            self.clients[username] = c
        return self.clients[username]

    def principal(self, username: str, role: str) -> Principal:
        return Principal(user_id=self.users[username], username=username, role=Role(role), via="test",
                         scope="write", credential_hash="")  # type: ignore[arg-type]

    def import_run(self, name: str, seed: int, *, duration_s: float = 60.0, owner: str = "admin") -> int:
        """A simulated drive uploaded through POST /runs; its truth is kept for gold tests."""
        sim = _simulation(seed, duration_s)
        buf = Path(self.settings.data_dir) / f"{name}.csv"
        write_run(sim.run, buf)
        with buf.open("rb") as fh:
            r = self.client(owner).post("/api/v1/runs", data={"name": name}, files={"file": (buf.name, fh, "text/csv")})
        assert r.status_code == 201, r.text
        run_id = r.json()["id"]
        self.sims[run_id] = sim
        return run_id

    def drain(self, max_jobs: int = 200) -> int:
        """Run every due job in this process (the worker), then return how many ran."""
        from posefix.worker.runner import Worker

        w = Worker(self.db, self.settings, name="test")
        n = 0
        while n < max_jobs and w.run_once():
            n += 1
        return n

    def keyframes(self, run_id: int, username: str = "admin") -> list[dict[str, Any]]:
        r = self.client(username).get(f"/api/v1/runs/{run_id}/keyframes")
        assert r.status_code == 200, r.text
        return r.json()["features"]


@functools.lru_cache(maxsize=32)
def _simulation(seed: int, duration_s: float) -> Simulation:
    return simulate(duration_s=duration_s, rate_hz=5.0, edit_every_s=0, seed=seed, regime="drift")


def shifted(lon: float, lat: float, east_m: float, north_m: float) -> tuple[float, float]:
    """lon/lat moved by a few metres (local spherical approximation is exact enough at metres)."""
    r = 6371008.8
    return lon + np.degrees(east_m / (r * np.cos(np.radians(lat)))), lat + np.degrees(north_m / r)


def build_env(tmp_path: Path, url: str) -> Env:
    """The app on an already migrated database (see fresh_pg_url / fresh_sqlite_url)."""
    from posefix.runs import service, solutions

    # The solver caches are per process and keyed by run id: every test's run 1 is another run.
    solutions.PROBLEMS.forget_all()
    service.GEOJSON_CACHE.clear()
    settings = Settings(environment="test", database_url=url, data_dir=tmp_path / "var", log_json=False,
                        log_level="WARNING", embedded_worker=False)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    app = create_app(settings)
    clk = task_clock.ManualClock(dt.datetime(2026, 11, 22, 12, 0, tzinfo=dt.UTC))
    task_clock.set_clock(clk)
    env = Env(app=app, settings=settings, clock=clk)
    env.add_user("admin", "admin")
    env.add_user("reviewer", "reviewer")
    env.add_user("client", "client")
    return env


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def env(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Env]:
    if request.param == "sqlite":
        e = build_env(tmp_path, fresh_sqlite_url(tmp_path / "tasks.sqlite"))
        try:
            yield e
        finally:
            e.db.dispose()
            task_clock.reset_clock()
        return
    url, name = fresh_pg_url()
    e = build_env(tmp_path, url)
    try:
        yield e
    finally:
        e.db.dispose()
        task_clock.reset_clock()
        _pg_admin_exec(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def task_body(run_ids: list[int], **over: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "title": "Correct the drives", "instructions": "Drag keyframes onto the road centre.", "run_ids": run_ids,
        "reward_cents": 50, "currency": "EUR", "assignments_per_run": 2, "lease_s": 600, "lifetime_s": 86400,
        "auto_approval_delay_s": 3600, "priority": 0, "conflict_policy": "flag",
    }
    body.update(over)
    return body


def truth_move(env: Env, run_id: int, k: int, error_east_m: float = 0.0, error_north_m: float = 0.0) -> dict[str, Any]:
    """A move of keyframe k onto the simulated truth (plus an error), as an operator would drag it."""
    sim = env.sims[run_id]
    feats = env.keyframes(run_id)
    t = feats[k]["properties"]["t"]
    row = int(np.argmin(np.abs(sim.truth.t_s - t)))
    lon, lat = shifted(float(sim.truth.lon_deg[row]), float(sim.truth.lat_deg[row]), error_east_m, error_north_m)
    return {"index": k, "lon": lon, "lat": lat}


def csv_bytes(run: Any, tmp: Path, name: str) -> bytes:
    p = tmp / name
    write_run(run, p)
    return p.read_bytes()


__all__ = ["Env", "env", "task_body", "truth_move", "shifted", "csv_bytes", "ORIGIN"]
