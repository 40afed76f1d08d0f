"""Commands of the 'server' area: serve, worker, users create, db upgrade/downgrade."""

from __future__ import annotations

import signal
import sys
from typing import Optional

import click

from posefix.commands.common import CONTEXT, single_threaded_blas

app = click.Group()


@app.group("users", no_args_is_help=True)
def users_app() -> None:
    """Manage user accounts."""


@app.group("db", no_args_is_help=True)
def db_app() -> None:
    """Database schema (Alembic migrations)."""


@db_app.command("upgrade", context_settings=CONTEXT)
@click.argument("revision", default="heads")
def db_upgrade(revision: str) -> None:
    """Migrate the database (POSEFIX_DATABASE_URL) up to REVISION (default: latest)."""
    from posefix.db import upgrade_database

    upgrade_database(None, revision)
    click.echo(f"database upgraded to {revision}")


@db_app.command("downgrade", context_settings=CONTEXT)
@click.argument("revision")
def db_downgrade(revision: str) -> None:
    """Migrate the database down to REVISION (e.g. -1 or base)."""
    from alembic import command

    from posefix.db import alembic_config

    command.downgrade(alembic_config(), revision)
    click.echo(f"database downgraded to {revision}")


@users_app.command("create", context_settings=CONTEXT)
@click.option("--username", required=True, help="login name")
@click.option("--role", default="operator", help="admin, reviewer, operator or client")
@click.option("--password-stdin", is_flag=True, help="read the password from stdin")
def users_create(username: str, role: str, password_stdin: bool) -> None:
    """Create a user (asks for the password unless --password-stdin)."""
    from posefix.config import Settings
    from posefix.db import Database
    from posefix.errors import AppError
    from posefix.users.models import Role
    from posefix.users.service import create_user

    try:
        role_value = Role(role)
    except ValueError:
        raise click.BadParameter(f"role must be one of {', '.join(r.value for r in Role)}", param_hint="--role") from None
    if password_stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = click.prompt("password", hide_input=True, confirmation_prompt=True)
    from posefix.users.passwords import password_problem

    problem = password_problem(password, username, role_value)
    if problem is not None:
        click.echo(f"error: {problem}", err=True)
        raise click.exceptions.Exit(2)
    settings = Settings()
    db = Database(settings.resolved_database_url)
    try:
        with db.transaction() as session:
            user = create_user(session, username, password, role_value)
            uid = user.id
    except AppError as exc:
        click.echo(f"error: {exc.detail}", err=True)
        raise click.exceptions.Exit(1) from None
    finally:
        db.dispose()
    click.echo(f"created {role_value.value} {username!r} (id {uid})")


@app.command("serve", context_settings=CONTEXT)
@click.option("--host", default="127.0.0.1", help="address to listen on")
@click.option("--port", type=int, default=8000, help="port")
@click.option("--workers", type=click.IntRange(min=1), help="HTTP processes (default: one per core)")
@click.option("--embedded-worker/--no-embedded-worker", default=None, help=(
    "run a job worker with the server: a thread with one HTTP process, its own process with several "
    "(default: on SQLite)"))
@click.option("--migrate/--no-migrate", default=True, help="apply migrations before starting")
@click.option("--keep-alive-s", type=click.IntRange(min=1), default=75, help=(
    "seconds an idle connection stays open; longer than clients keep idle pooled connections "
    "(httpx and requests 5 s) so a client never reuses one the server is just closing"))
def serve(host: str, port: int, workers: Optional[int], embedded_worker: Optional[bool], migrate: bool,
          keep_alive_s: int) -> None:
    """Serve the API and the front end (and, on SQLite, the job worker)."""
    single_threaded_blas()  # concurrent small solves: BLAS threads would only spin against each other
    from posefix.config import Settings, with_listen_origins
    from posefix.db import upgrade_database
    from posefix.serving import default_http_processes, run_server

    settings = with_listen_origins(Settings(), host, port)
    if not settings.csrf_origins:
        click.echo("error: set POSEFIX_PUBLIC_URL (or POSEFIX_ALLOWED_ORIGINS), the address browsers use; "
                   "browser sessions are refused without it", err=True)
        raise click.exceptions.Exit(2)
    if migrate:
        upgrade_database(settings.resolved_database_url)
    embedded = settings.is_sqlite and settings.embedded_worker if embedded_worker is None else embedded_worker
    processes = workers or default_http_processes()
    worker_txt = ("job worker thread, " if processes == 1 else "job worker process, ") if embedded else ""
    click.echo(f"posefix serving on http://{host}:{port}/ ({processes} HTTP process(es), {worker_txt}"
               f"{settings.resolved_database_url.split('://')[0]})")
    run_server(settings, host=host, port=port, processes=processes, job_worker=embedded, keep_alive_s=keep_alive_s)


@app.command("worker", context_settings=CONTEXT)
@click.option("--once/--no-once", default=False, help="process jobs until none is left, then exit")
def worker(once: bool) -> None:
    """Run a job worker (any number may share the database). SIGTERM finishes the current job."""
    single_threaded_blas()
    from posefix.config import Settings
    from posefix.db import Database
    from posefix.main import configure_logging
    from posefix.worker.runner import Worker

    settings = Settings()
    configure_logging(settings)
    db = Database(settings.resolved_database_url)
    w = Worker(db, settings)

    def _graceful(signum: int, _frame: object) -> None:
        w.stop()

    signal.signal(signal.SIGTERM, _graceful)
    signal.signal(signal.SIGINT, _graceful)
    click.echo(f"worker {w.worker_id} started", err=True)
    try:
        if once:
            while w.run_once():
                pass
        else:
            w.run()
    finally:
        db.dispose()
