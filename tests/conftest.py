"""Fixtures of the web service and worker tests: a real database on each backend.

``db_url`` is parametrised over SQLite (a file per test session) and PostgreSQL (a uniquely
named database per session and xdist worker at POSEFIX_TEST_PG_URL, dropped at the end).
Both are built by running the Alembic migrations. Between tests every table is emptied.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

REPO = Path(__file__).resolve().parents[1]
ORIGIN = "http://testserver"
PASSWORD = "correct horse battery"
PG_URL = os.environ.get("POSEFIX_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def migrate(url: str, revision: str = "heads") -> None:
    from posefix.db import upgrade_database

    upgrade_database(url, revision)


def _pg_create(name: str) -> str:
    admin = create_engine(PG_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    admin.dispose()
    return make_url(PG_URL).set(database=name).render_as_string(hide_password=False)


def _pg_drop(name: str) -> None:
    admin = create_engine(PG_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    admin.dispose()


@pytest.fixture(scope="session")
def fresh_database(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """A factory of empty databases (not migrated), removed at the end of the session."""
    made: list[str] = []
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")

    def make(backend: str) -> str:
        if backend == "sqlite":
            path = tmp_path_factory.mktemp("db") / f"{uuid.uuid4().hex[:8]}.sqlite"
            return f"sqlite:///{path}"
        name = f"posefix_test_{worker}_{uuid.uuid4().hex[:10]}"
        url = _pg_create(name)
        made.append(name)
        return url

    yield make
    for name in made:
        _pg_drop(name)


@pytest.fixture(scope="session", params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def db_url(request: pytest.FixtureRequest, fresh_database: Any) -> str:
    url = fresh_database(request.param)
    migrate(url)
    return url


def _empty_tables(url: str) -> None:
    import posefix.edits.models  # noqa: F401
    import posefix.jobs.models  # noqa: F401
    import posefix.runs.models  # noqa: F401
    import posefix.users.models  # noqa: F401
    from posefix.db import Base, Database

    for optional in ("posefix.tiles.models", "posefix.tasks.models", "posefix.maps.models"):
        try:
            __import__(optional)
        except ModuleNotFoundError:
            pass
    db = Database(url)
    tables = [t.name for t in reversed(Base.metadata.sorted_tables)]
    with db.engine.begin() as conn:
        existing = set(db.engine.dialect.get_table_names(conn))
        names = [t for t in tables if t in existing]
        if db.is_sqlite:
            for t in names:
                conn.execute(text(f'DELETE FROM "{t}"'))
        else:
            conn.execute(text("TRUNCATE " + ", ".join(f'"{t}"' for t in names) + " RESTART IDENTITY CASCADE"))
    db.dispose()


@pytest.fixture
def settings(db_url: str, tmp_path: Path) -> Any:
    from posefix.config import Settings
    from posefix.runs import service, solutions

    _empty_tables(db_url)
    solutions.PROBLEMS.forget_all()
    service.GEOJSON_CACHE.clear()
    return Settings(
        environment="test", database_url=db_url, data_dir=tmp_path / "var", log_level="WARNING",
        job_backoff_base_s=0.05, worker_poll_s=0.05, job_lease_s=5.0, job_heartbeat_s=1.0,
    )


@pytest.fixture
def app(settings: Any) -> Iterator[Any]:
    from posefix.main import create_app

    application = create_app(settings)
    yield application
    application.state.db.dispose()


@pytest.fixture
def client(app: Any) -> Iterator[Any]:
    from fastapi.testclient import TestClient

    with TestClient(app, headers={"Origin": ORIGIN}) as c:
        yield c


_HASHES: dict[str, str] = {}


def add_user(app: Any, username: str, role: str, password: str = PASSWORD) -> int:
    """A user row; the argon2id hash of each password is computed once per test process."""
    from posefix.security import hash_password
    from posefix.users.models import Role, User

    if password not in _HASHES:
        _HASHES[password] = hash_password(password)
    with app.state.db.transaction() as session:
        user = User(username=username, password_hash=_HASHES[password], role=Role(role).value, disabled=False)
        session.add(user)
        session.flush()
        return user.id


def direct_token(app: Any, user_id: int, scope: str = "write") -> dict[str, str]:
    """A personal API token made by the service (no login round trip)."""
    from posefix.users.models import Role, TokenScope
    from posefix.users.service import Principal, create_token

    with app.state.db.transaction() as session:
        principal = Principal(user_id, "", Role.admin, "session", TokenScope.write, "")
        _, secret = create_token(session, app.state.settings, principal, "test", TokenScope(scope))
    return {"Authorization": f"Bearer {secret}"}


def login(app: Any, username: str, password: str = PASSWORD) -> Any:
    from fastapi.testclient import TestClient

    c = TestClient(app, headers={"Origin": ORIGIN})
    r = c.post("/api/v1/auth/login", json={"username": username, "password": password})
    assert r.status_code == 200, r.text
    return c


def token_for(app: Any, username: str, scope: str = "write") -> dict[str, str]:
    c = login(app, username)
    r = c.post("/api/v1/tokens", json={"name": "test", "scope": scope})
    assert r.status_code == 201, r.text
    return {"Authorization": f"Bearer {r.json()['token']}"}


@pytest.fixture
def users(app: Any) -> dict[str, dict[str, str]]:
    """One user per role, each with a write token: {role: headers}."""
    out = {}
    for role in ("admin", "reviewer", "operator", "client"):
        out[role] = direct_token(app, add_user(app, role, role))
    return out


def drive_csv(n: int = 600, *, hz: float = 10.0, t0: float = 1.7e9, lat0: float = 60.17, lon0: float = 24.94,
              images_every: int = 0, seed: int = 0) -> bytes:
    """A drive north at ~11 m/s with a few metres of GNSS-like noise, interchange CSV."""
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / hz
    lat = lat0 + np.arange(n) * 1e-5 + rng.normal(0, 2e-6, n)
    lon = lon0 + rng.normal(0, 3e-6, n)
    yaw = np.pi / 2
    qw, qz = np.cos(yaw / 2), np.sin(yaw / 2)
    head = "t,lat,lon,alt,qw,qx,qy,qz" + (",image" if images_every else "")
    rows = [head]
    for i in range(n):
        row = f"{t[i]:.3f},{lat[i]:.9f},{lon[i]:.9f},12.5,{qw:.12f},0,0,{qz:.12f}"
        if images_every:
            row += f",img{i:05d}.jpg" if i % images_every == 0 else ","
        rows.append(row)
    return ("\n".join(rows) + "\n").encode()


def upload(client: Any, headers: dict[str, str], data: bytes | None = None, name: str = "drive",
           filename: str = "drive.csv", images: list[tuple[str, bytes]] | None = None) -> Any:
    files: list[tuple[str, tuple[str, bytes, str]]] = [("file", (filename, data if data is not None else drive_csv(), "application/octet-stream"))]
    for fname, content in images or []:
        files.append(("images", (fname, content, "application/octet-stream")))
    return client.post("/api/v1/runs", files=files, data={"name": name}, headers=headers)


def wait_job(app: Any, job_id: int, timeout: float = 30.0) -> dict[str, Any]:
    """Run the worker in this process until the job is finished."""
    import time

    from posefix.jobs import repository as jobs
    from posefix.worker.runner import Worker

    worker = Worker(app.state.db, app.state.settings, name="test")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with app.state.db.transaction(write=False) as s:
            job = jobs.get(s, job_id)
            assert job is not None
            if job.status in ("succeeded", "dead"):
                return {"status": job.status, "result": job.result, "attempts": job.attempts, "error": job.last_error}
        if not worker.run_once():
            time.sleep(0.05)
    raise AssertionError(f"job {job_id} not finished in {timeout} s")
