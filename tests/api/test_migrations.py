"""Alembic is the only schema path: upgrade from empty, downgrade to empty, models match."""

from __future__ import annotations

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import inspect

from posefix.db import alembic_config
from posefix.db import Base, Database

MINE = {"users", "auth_sessions", "api_tokens", "login_failures", "runs", "keyframes", "revisions", "run_images",
        "run_events", "edit_batches", "edits", "jobs"}


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_upgrade_downgrade_upgrade(fresh_database, backend):
    from alembic import command

    url = fresh_database(backend)
    cfg = alembic_config(url)
    command.upgrade(cfg, "heads")
    db = Database(url)
    try:
        tables = set(inspect(db.engine).get_table_names())
        assert MINE <= tables
        command.downgrade(cfg, "base")
        db.engine.dispose()
        assert set(inspect(db.engine).get_table_names()) <= {"alembic_version"}
        command.upgrade(cfg, "heads")
        db.engine.dispose()
        assert MINE <= set(inspect(db.engine).get_table_names())
    finally:
        db.dispose()


def test_models_match_migrations(db_url):
    import posefix.edits.models  # noqa: F401
    import posefix.jobs.models  # noqa: F401
    import posefix.runs.models  # noqa: F401
    import posefix.users.models  # noqa: F401

    db = Database(db_url)
    try:
        with db.engine.connect() as conn:
            ctx = MigrationContext.configure(conn, opts={"compare_type": False})
            diffs = compare_metadata(ctx, Base.metadata)
    finally:
        db.dispose()

    def table_of(d):
        op = d[0] if isinstance(d, tuple) else d[0][0]
        obj = d[1] if isinstance(d, tuple) else d[0][2]
        name = getattr(obj, "name", None) if op in ("add_table", "remove_table") else None
        if name is None:
            name = getattr(getattr(obj, "table", None), "name", None) or (d[2] if isinstance(d, tuple) and len(d) > 2 and isinstance(d[2], str) else None)
        return name

    mine = [d for d in diffs if table_of(d) in MINE]
    assert mine == []


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_stored_unlimited_moves_become_finite(fresh_database, backend):
    """Rules stored with max_move_m 0 (once 'unlimited') or beyond 10 km take 10 km."""
    import datetime as dt

    import sqlalchemy as sa
    from alembic import command

    url = fresh_database(backend)
    cfg = alembic_config(url)
    command.upgrade(cfg, "d4e8a1f7c2b9")
    db = Database(url)
    runs = sa.table("runs", *(sa.column(c) for c in (
        "id", "name", "status", "verified", "adjusted", "source_format", "original_filename", "n_samples", "n_keyframes", "t_start_s", "t_end_s", "min_lon", "min_lat", "max_lon",
        "max_lat", "length_m", "orientation_derived", "revision", "head_revision", "created_at", "updated_at")),
        sa.column("rules", sa.JSON))
    now = dt.datetime(2026, 12, 1, tzinfo=dt.UTC)
    row = dict(name="r", status="imported", verified=False, adjusted=False, source_format="csv",
               original_filename="r.csv", n_samples=2, n_keyframes=2, t_start_s=0.0, t_end_s=1.0, min_lon=0.0,
               min_lat=0.0, max_lon=0.0, max_lat=0.0, length_m=0.0, orientation_derived=False, revision=0,
               head_revision=0, created_at=now, updated_at=now)
    try:
        with db.engine.begin() as c:
            for i, value in enumerate((0.0, 30.0, 5e5), start=1):
                c.execute(sa.insert(runs).values(id=i, rules={"every_n": 1, "max_move_m": value}, **row))
        command.upgrade(cfg, "heads")
        with db.engine.connect() as c:
            got = dict(c.execute(sa.select(runs.c.id, runs.c.rules)).fetchall())
        assert {i: r["max_move_m"] for i, r in got.items()} == {1: 10_000.0, 2: 30.0, 3: 10_000.0}
        assert got[1]["every_n"] == 1
    finally:
        db.dispose()
