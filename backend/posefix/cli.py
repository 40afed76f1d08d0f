"""The ``posefix`` command line.

Each area's commands live in ``posefix.commands.<area>`` on that module's own ``click.Group``
(``app``); this module puts them on the root group and nothing imports it back.

Start-up is what a short command costs, so ``main`` loads only the area of the command on
the line: ``posefix correct`` never imports the server's modules. The parser is click's
(typer's parameter coercion imports pydantic: about 0.1 s of CPU on every command).
``--version`` answers before click is imported. ``posefix`` alone or ``posefix --help``
assembles every area.
"""

from __future__ import annotations

import sys

TYPE_CHECKING = False  # typing's own constant costs an import of typing at start-up
if TYPE_CHECKING:
    from typing import Callable

    import click

HELP = "posefix: correct vehicle and device trajectories (pose runs)."


def _engine() -> "click.Group":
    from posefix.commands import engine

    return engine.app


def _server() -> "click.Group":
    from posefix.commands import server

    return server.app


def _demo() -> "click.Group":
    from posefix.commands import demo

    return demo.app


def _tasks() -> "click.Group":
    from posefix.commands import tasks

    return tasks.app


def _mapmatch() -> "click.Group":
    from posefix.commands import mapmatch

    return mapmatch.app


# Every area, in the order ``--help`` lists them.
AREAS: dict[str, Callable[[], "click.Group"]] = {
    "engine": _engine, "server": _server, "demo": _demo, "tasks": _tasks, "mapmatch": _mapmatch,
}
# The area of each top-level command or command group.
COMMAND_AREA = {
    "correct": "engine", "evaluate": "engine", "simulate": "engine", "convert": "engine",
    "serve": "server", "worker": "server", "users": "server", "db": "server",
    "demo": "demo", "basemap": "demo", "tasks": "tasks", "mapmatch": "mapmatch",
}


def build_app(areas: list[str] | None = None) -> "click.Group":
    """The command line with the given areas' commands (default: all of them)."""
    import click

    def _version(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
        if value:
            _print_version()
            ctx.exit()

    app = click.Group(name="posefix", help=HELP, no_args_is_help=True, params=[
        click.Option(["--version", "-V"], is_flag=True, is_eager=True, expose_value=False, callback=_version,
                     help="Print the version and exit."),
    ])
    for area in areas or list(AREAS):
        for command in AREAS[area]().commands.values():
            app.add_command(command)
    return app


def _print_version() -> None:
    from posefix import __version__

    sys.stdout.write(f"posefix {__version__}\n")


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if args[:1] in (["--version"], ["-V"]):
        _print_version()
        return
    area = COMMAND_AREA.get(args[0]) if args else None
    app = build_app([area] if area is not None else None)
    app.main(args=args, prog_name="posefix")


if __name__ == "__main__":
    main()
