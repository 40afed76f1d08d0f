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
