"""Commands of the 'tasks' area, on this module's ``app``, which posefix.cli assembles:

    posefix tasks maintain     expire leases, auto-approve, expire tasks once (cron-friendly;
                               the worker also does it every few seconds while work is live)
    posefix tasks list         tasks with their status and assignment counts
    posefix tasks operators    operator statistics (accuracy, agreement, throughput)
"""

from __future__ import annotations

import json
from typing import Optional

import click

from posefix.commands.common import CONTEXT

app = click.Group()


@app.group("tasks", no_args_is_help=True)
def tasks_app() -> None:
    """Crowdsourced correction tasks."""


def _db():  # type: ignore[no-untyped-def]
    from posefix.config import Settings
    from posefix.db import Database

    settings = Settings()
    return settings, Database(settings.resolved_database_url)


@tasks_app.command("maintain", context_settings=CONTEXT)
def maintain() -> None:
    """Return expired leases to the pool, auto-approve due work, expire old tasks (once)."""
    from posefix.tasks import clock
    from posefix.tasks.maintenance import maintain as maintain_tasks

    _settings, db = _db()
    try:
        with db.transaction() as s:
            counts = maintain_tasks(s, clock.now())
    finally:
        db.dispose()
    click.echo(json.dumps(counts))


@tasks_app.command("list", context_settings=CONTEXT)
@click.option("--status", help="only tasks in this status")
def list_tasks(status: Optional[str]) -> None:
    """Tasks, newest first, with assignment counts by status."""
    from posefix.tasks import repository as repo

    _settings, db = _db()
    try:
        with db.transaction(write=False) as s:
            rows, total = repo.list_tasks(s, None, status, 500, 0)
            counts = repo.counts_by_status(s, [t.id for t in rows])
            for t in rows:
                c = ", ".join(f"{k} {v}" for k, v in sorted(counts[t.id].items())) or "-"
                click.echo(f"{t.id:>5}  {t.status:<11} p{t.priority:<4} {t.title[:40]:<40}  {c}")
    finally:
        db.dispose()
    click.echo(f"{total} task(s)")


@tasks_app.command("operators", context_settings=CONTEXT)
def operators() -> None:
    """Operator statistics as JSON lines."""
    from posefix.tasks import repository as repo
    from posefix.tasks.operators import operator_stats

    _settings, db = _db()
    try:
        with db.transaction(write=False) as s:
            for row in operator_stats(s, repo.operators(s)):
                row["qualifications"] = [{"name": q["name"], "value": q["value"]} for q in row["qualifications"]]
                click.echo(json.dumps(row, default=str))
    finally:
        db.dispose()
