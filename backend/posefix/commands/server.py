"""Commands of the 'server' area: serve, worker, users create, db upgrade/downgrade."""

from __future__ import annotations

import signal
import sys
from typing import Annotated

import typer

from posefix.commands.common import single_threaded_blas

app = typer.Typer()

users_app = typer.Typer(help="Manage user accounts.", no_args_is_help=True)
db_app = typer.Typer(help="Database schema (Alembic migrations).", no_args_is_help=True)
app.add_typer(users_app, name="users")
app.add_typer(db_app, name="db")


@db_app.command("upgrade")
def db_upgrade(revision: Annotated[str, typer.Argument(help="target revision")] = "heads") -> None:
    """Migrate the database (POSEFIX_DATABASE_URL) up to REVISION (default: latest)."""
    from posefix.db import upgrade_database

    upgrade_database(None, revision)
    typer.echo(f"database upgraded to {revision}")


@db_app.command("downgrade")
def db_downgrade(revision: Annotated[str, typer.Argument(help="target revision, e.g. -1 or base")]) -> None:
    """Migrate the database down to REVISION."""
    from alembic import command

    from posefix.db import alembic_config

    command.downgrade(alembic_config(), revision)
    typer.echo(f"database downgraded to {revision}")


@users_app.command("create")
def users_create(
    username: Annotated[str, typer.Option("--username", help="login name")],
    role: Annotated[str, typer.Option("--role", help="admin, reviewer, operator or client")] = "operator",
    password_stdin: Annotated[bool, typer.Option("--password-stdin", help="read the password from stdin")] = False,
) -> None:
    """Create a user (asks for the password unless --password-stdin)."""
    from posefix.config import Settings
    from posefix.db import Database
    from posefix.errors import AppError
    from posefix.users.models import Role
    from posefix.users.service import create_user

    try:
        role_value = Role(role)
    except ValueError:
        raise typer.BadParameter(f"role must be one of {', '.join(r.value for r in Role)}", param_hint="--role") from None
    if password_stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = typer.prompt("password", hide_input=True, confirmation_prompt=True)
    from posefix.users.passwords import password_problem

    problem = password_problem(password, username, role_value)
    if problem is not None:
        typer.echo(f"error: {problem}", err=True)
        raise typer.Exit(2)
    settings = Settings()
    db = Database(settings.resolved_database_url)
    try:
        with db.transaction() as session:
            user = create_user(session, username, password, role_value)
            uid = user.id
    except AppError as exc:
        typer.echo(f"error: {exc.detail}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()
    typer.echo(f"created {role_value.value} {username!r} (id {uid})")


@app.command("serve")
def serve(
    host: Annotated[str, typer.Option(help="address to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port")] = 8000,
    workers: Annotated[int | None, typer.Option(help="HTTP processes (default: one per core)", min=1)] = None,
    embedded_worker: Annotated[bool | None, typer.Option(help=(
        "run a job worker with the server: a thread with one HTTP process, its own process with several "
        "(default: on SQLite)"))] = None,
    migrate: Annotated[bool, typer.Option(help="apply migrations before starting")] = True,
    keep_alive_s: Annotated[int, typer.Option(help=(
        "seconds an idle connection stays open; longer than clients keep idle pooled connections "
        "(httpx and requests 5 s) so a client never reuses one the server is just closing"), min=1)] = 75,
) -> None:
    """Serve the API and the front end (and, on SQLite, the job worker)."""
    single_threaded_blas()  # concurrent small solves: BLAS threads would only spin against each other
    from posefix.config import Settings, with_listen_origins
    from posefix.db import upgrade_database
    from posefix.serving import default_http_processes, run_server

    settings = with_listen_origins(Settings(), host, port)
    if not settings.csrf_origins:
        typer.echo("error: set POSEFIX_PUBLIC_URL (or POSEFIX_ALLOWED_ORIGINS), the address browsers use; "
                   "browser sessions are refused without it", err=True)
        raise typer.Exit(2)
    if migrate:
        upgrade_database(settings.resolved_database_url)
    embedded = settings.is_sqlite and settings.embedded_worker if embedded_worker is None else embedded_worker
    processes = workers or default_http_processes()
    worker_txt = ("job worker thread, " if processes == 1 else "job worker process, ") if embedded else ""
    typer.echo(f"posefix serving on http://{host}:{port}/ ({processes} HTTP process(es), {worker_txt}"
               f"{settings.resolved_database_url.split('://')[0]})")
    run_server(settings, host=host, port=port, processes=processes, job_worker=embedded, keep_alive_s=keep_alive_s)


@app.command("worker")
def worker(
    once: Annotated[bool, typer.Option(help="process jobs until none is left, then exit")] = False,
) -> None:
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
    typer.echo(f"worker {w.worker_id} started", err=True)
    try:
        if once:
            while w.run_once():
                pass
        else:
            w.run()
    finally:
        db.dispose()
