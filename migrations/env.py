"""Alembic environment: the only way posefix's schema changes.

The database URL comes from the Alembic config (``sqlalchemy.url``, set by
``posefix db upgrade`` and the tests) or else from the settings (POSEFIX_DATABASE_URL).
Each domain's models module is imported here so its tables join ``Base.metadata``.
"""

from __future__ import annotations

from alembic import context

from posefix.db import Database
from posefix.db import Base
import posefix.users.models  # noqa: F401
import posefix.runs.models  # noqa: F401
import posefix.edits.models  # noqa: F401
import posefix.jobs.models  # noqa: F401
import posefix.tiles.models  # noqa: F401
import posefix.tasks.models  # noqa: F401
import posefix.maps.models  # noqa: F401

config = context.config
target_metadata = Base.metadata


def _url() -> str:
    url = config.get_main_option("sqlalchemy.url")
    if url:
        return url
    from posefix.config import Settings

    return Settings().resolved_database_url


def run_migrations_offline() -> None:
    url = _url()
    context.configure(
        url=url, target_metadata=target_metadata, literal_binds=True,
        render_as_batch=url.startswith("sqlite"),
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    url = _url()
    db = Database(url)
    try:
        with db.engine.connect() as connection:
            context.configure(
                connection=connection, target_metadata=target_metadata,
                render_as_batch=db.is_sqlite,
            )
            with context.begin_transaction():
                context.run_migrations()
    finally:
        db.dispose()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
