"""Database: SQLAlchemy 2 engine and sessions, SQLite pragmas, the declarative base.

SQLite runs in WAL mode with a busy timeout. Transactions that write start with
``BEGIN IMMEDIATE`` on SQLite (``write_session``), so a transaction that reads and then
writes never fails on a stale snapshot; PostgreSQL uses its default READ COMMITTED.
Services never commit: ``transaction`` (the request edge, the worker) does.
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import DateTime, Engine, MetaData, create_engine, event
from sqlalchemy.orm import DeclarativeBase, Session, sessionmaker
from sqlalchemy.types import TypeDecorator

__all__ = [
    "Base", "Database", "UTCDateTime", "utcnow", "on_commit", "on_rollback", "MIGRATIONS_DIR", "alembic_config",
    "upgrade_database",
]

MIGRATIONS_DIR = Path(__file__).resolve().parents[2] / "migrations"

NAMING = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_N_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING)


def utcnow() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


class UTCDateTime(TypeDecorator):
    """Timezone-aware UTC datetimes on both SQLite (which drops the zone) and PostgreSQL."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: dt.datetime | None, dialect: Any) -> dt.datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime given to a UTC column")
        return value.astimezone(dt.UTC)

    def process_result_value(self, value: dt.datetime | None, dialect: Any) -> dt.datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=dt.UTC) if value.tzinfo is None else value.astimezone(dt.UTC)


def _configure_sqlite(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn: Any, _record: Any) -> None:
        # Let SQLAlchemy's "begin" event issue BEGIN itself (pysqlite's own is deferred-only).
        dbapi_conn.isolation_level = None
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute("PRAGMA synchronous=NORMAL")
        cur.execute("PRAGMA foreign_keys=ON")
        cur.execute("PRAGMA busy_timeout=30000")
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn: Any) -> None:
        mode = conn.get_execution_options().get("sqlite_begin", "DEFERRED")
        conn.exec_driver_sql(f"BEGIN {mode}")


def on_commit(session: Session, fn: Any) -> None:
    """Run ``fn()`` after the session's transaction commits (e.g. wake the worker)."""
    session.info.setdefault("on_commit", []).append(fn)


def on_rollback(session: Session, fn: Any) -> None:
    """Run ``fn()`` if the transaction rolls back (e.g. remove files written for it)."""
    session.info.setdefault("on_rollback", []).append(fn)


def _run_hooks(session: Session, key: str) -> None:
    for fn in session.info.pop(key, []):
        try:
            fn()
        except Exception:
            logging.getLogger("posefix.db").exception("%s hook failed", key)
    session.info.pop("on_commit", None)
    session.info.pop("on_rollback", None)


class Database:
    """The engine and two session factories: read (deferred) and write (immediate on SQLite)."""

    def __init__(self, url: str, *, echo: bool = False, pool_size: int = 10, max_overflow: int = 20):
        self.url = url
        self.is_sqlite = url.startswith("sqlite")
        kwargs: dict[str, Any] = {"echo": echo, "future": True}
        if self.is_sqlite:
            path = url.split("///", 1)[1] if "///" in url else ""
            if path and path != ":memory:":
                Path(path).parent.mkdir(parents=True, exist_ok=True)
            kwargs["connect_args"] = {"check_same_thread": False, "timeout": 30}
            if path and path != ":memory:":
                kwargs["pool_size"] = 20
                kwargs["max_overflow"] = 20
        else:
            kwargs["pool_pre_ping"] = True
            kwargs["pool_size"] = pool_size
            kwargs["max_overflow"] = max_overflow
        self.engine = create_engine(url, **kwargs)
        self.max_connections = kwargs.get("pool_size", 5) + kwargs.get("max_overflow", 10)
        if self.is_sqlite:
            _configure_sqlite(self.engine)
            write_engine = self.engine.execution_options(sqlite_begin="IMMEDIATE")
        else:
            write_engine = self.engine
        self._read = sessionmaker(bind=self.engine, expire_on_commit=False)
        self._write = sessionmaker(bind=write_engine, expire_on_commit=False)

    def session(self, *, write: bool = False) -> Session:
        return (self._write if write else self._read)()

    @contextmanager
    def transaction(self, *, write: bool = True) -> Iterator[Session]:
        """One unit of work: commit at the end, roll back on any error."""
        session = self.session(write=write)
        try:
            yield session
            session.commit()
        except BaseException:
            session.rollback()
            _run_hooks(session, "on_rollback")
            raise
        else:
            _run_hooks(session, "on_commit")
        finally:
            session.close()

    def dispose(self) -> None:
        self.engine.dispose()


def alembic_config(database_url: str | None = None):  # type: ignore[no-untyped-def]
    """Alembic config pointing at the repository's migrations, usable from any directory."""
    from alembic.config import Config

    from posefix.config import Settings

    cfg = Config(str(MIGRATIONS_DIR / "alembic.ini"))
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    cfg.set_main_option("sqlalchemy.url", (database_url or Settings().resolved_database_url).replace("%", "%%"))
    return cfg


def upgrade_database(database_url: str | None = None, revision: str = "heads") -> None:
    """Migrate the database (default: the configured one) up to ``revision``."""
    from alembic import command

    command.upgrade(alembic_config(database_url), revision)
