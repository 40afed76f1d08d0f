"""The ``posefix`` command line.

Each group of commands lives in ``posefix.commands.<area>`` and registers itself on
``app``; this module only assembles them, so the engine, the server and map matching
can grow their commands without touching one another.
"""

from __future__ import annotations

import typer

app = typer.Typer(
    name="posefix",
    help="posefix: correct vehicle and device trajectories (pose runs).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _register() -> None:
    # Imported for their side effect of adding commands to ``app``.
    from posefix.commands import demo, engine, mapmatch, server, tasks  # noqa: F401


def main() -> None:
    _register()
    app()


if __name__ == "__main__":
    main()
