"""Commands of the 'demo' area: ``posefix demo`` and ``posefix basemap build``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from posefix.commands.common import single_threaded_blas

app = typer.Typer()

basemap_app = typer.Typer(help="Offline basemap tiles from OpenStreetMap extracts.", no_args_is_help=True)
app.add_typer(basemap_app, name="basemap")


@app.command("demo")
def demo(
    host: Annotated[str, typer.Option(help="address to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port")] = 8000,
    data_dir: Annotated[Path | None, typer.Option(help="where the database and files go (default: POSEFIX_DATA_DIR or ./var)")] = None,
    serve: Annotated[bool, typer.Option(help="start the server after setting up")] = True,
) -> None:
    """Set up demo accounts, the offline Helsinki basemap and two runs, then serve (SQLite, embedded worker).

    Safe to run again: only what is missing is added.
    """
    single_threaded_blas()
    from posefix.config import Settings
    from posefix.demo import DemoError, set_up_demo

    overrides: dict[str, object] = {"operators_see_all_runs": True}
    if data_dir is not None:
        overrides["data_dir"] = data_dir
    settings = Settings(**overrides)
    try:
        summary = set_up_demo(settings, show_progress=True, say=lambda message: typer.echo(f"· {message}", err=True))
    except DemoError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    typer.echo("added: " + (", ".join(summary.created) if summary.created else "nothing (all there already)"))
    typer.echo(f"tile sources: {', '.join(summary.tile_sources)}")
    typer.echo("runs: " + ", ".join(f"{name} (id {run_id})" for name, run_id in summary.runs.items()))
    typer.echo("")
    typer.echo("demo accounts (development only; the passwords are public):")
    for account in summary.accounts:
        typer.echo(f"  {account.role:<9} {account.username:<10} password: {account.password}")
    if not serve:
        return
    from posefix.config import with_listen_origins
    from posefix.serving import default_http_processes, run_server

    settings = with_listen_origins(settings, host, port)
    url_host = "localhost" if host in ("0.0.0.0", "127.0.0.1", "::") else host
    processes = default_http_processes()
    typer.echo("")
    typer.echo(f"posefix demo: open http://{url_host}:{port}/ and log in as operator1 (Ctrl-C stops; "
               f"{processes} HTTP process(es) and a job worker)")
    env = {"POSEFIX_DATA_DIR": str(Path(settings.data_dir).resolve()), "POSEFIX_OPERATORS_SEE_ALL_RUNS": "true"}
    run_server(settings, host=host, port=port, processes=processes, job_worker=True, env=env)


@basemap_app.command("build")
def basemap_build(
    osm: Annotated[Path, typer.Argument(help="OpenStreetMap extract (.osm.pbf, .osm)")],
    out: Annotated[Path, typer.Argument(help="PMTiles file to write (register it as a tile source)")],
    min_zoom: Annotated[int, typer.Option(help="lowest zoom")] = 12,
    max_zoom: Annotated[int, typer.Option(help="highest zoom (the map over-zooms beyond it)")] = 16,
) -> None:
    """Build vector basemap tiles (roads, rail, buildings, water, parks) from an OSM extract."""
    from posefix.basemap import build_basemap

    try:
        summary = build_basemap(osm, out, min_zoom=min_zoom, max_zoom=max_zoom, show_progress=True)
    except (OSError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    west, south, east, north = summary.bounds_lonlat
    typer.echo(
        f"wrote {summary.path}: {summary.tiles} tiles, {summary.bytes / 1024:.0f} KiB, zooms "
        f"{summary.min_zoom}-{summary.max_zoom}, lon {west:.4f}..{east:.4f} lat {south:.4f}..{north:.4f}"
    )
