"""Commands of the 'demo' area: ``posefix demo`` and ``posefix basemap build``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import click

from posefix.commands.common import CONTEXT, single_threaded_blas

app = click.Group()


@app.group("basemap", no_args_is_help=True)
def basemap_app() -> None:
    """Offline basemap tiles from OpenStreetMap extracts."""


@app.command("demo", context_settings=CONTEXT)
@click.option("--host", default="127.0.0.1", help="address to listen on")
@click.option("--port", type=int, default=8000, help="port")
@click.option("--data-dir", type=click.Path(path_type=Path), help="where the database and files go (default: POSEFIX_DATA_DIR or ./var)")
@click.option("--serve/--no-serve", default=True, help="start the server after setting up")
def demo(host: str, port: int, data_dir: Optional[Path], serve: bool) -> None:
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
        summary = set_up_demo(settings, show_progress=True, say=lambda message: click.echo(f"· {message}", err=True))
    except DemoError as exc:
        click.echo(f"error: {exc}", err=True)
        raise click.exceptions.Exit(2) from None
    click.echo("added: " + (", ".join(summary.created) if summary.created else "nothing (all there already)"))
    click.echo(f"tile sources: {', '.join(summary.tile_sources)}")
    click.echo("runs: " + ", ".join(f"{name} (id {run_id})" for name, run_id in summary.runs.items()))
    click.echo("")
    click.echo("demo accounts (development only; the passwords are public):")
    for account in summary.accounts:
        click.echo(f"  {account.role:<9} {account.username:<10} password: {account.password}")
    if not serve:
        return
    from posefix.config import with_listen_origins
    from posefix.serving import default_http_processes, run_server

    settings = with_listen_origins(settings, host, port)
    url_host = "localhost" if host in ("0.0.0.0", "127.0.0.1", "::") else host
    processes = default_http_processes()
    click.echo("")
    click.echo(f"posefix demo: open http://{url_host}:{port}/ and log in as operator1 (Ctrl-C stops; "
               f"{processes} HTTP process(es) and a job worker)")
    env = {"POSEFIX_DATA_DIR": str(Path(settings.data_dir).resolve()), "POSEFIX_OPERATORS_SEE_ALL_RUNS": "true"}
    run_server(settings, host=host, port=port, processes=processes, job_worker=True, env=env)


@basemap_app.command("build", context_settings=CONTEXT)
@click.argument("osm", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(path_type=Path))
@click.option("--min-zoom", type=int, default=12, help="lowest zoom")
@click.option("--max-zoom", type=int, default=16, help="highest zoom (the map over-zooms beyond it)")
def basemap_build(osm: Path, out: Path, min_zoom: int, max_zoom: int) -> None:
    """Build vector basemap tiles (roads, rail, buildings, water, parks) from an OSM extract.

    OSM is the OpenStreetMap extract (.osm.pbf, .osm); OUT the PMTiles file to write
    (register it as a tile source).
    """
    from posefix.basemap import build_basemap

    try:
        summary = build_basemap(osm, out, min_zoom=min_zoom, max_zoom=max_zoom, show_progress=True)
    except (OSError, ValueError) as exc:
        click.echo(f"error: {exc}", err=True)
        raise click.exceptions.Exit(2) from None
    west, south, east, north = summary.bounds_lonlat
    click.echo(
        f"wrote {summary.path}: {summary.tiles} tiles, {summary.bytes / 1024:.0f} KiB, zooms "
        f"{summary.min_zoom}-{summary.max_zoom}, lon {west:.4f}..{east:.4f} lat {south:.4f}..{north:.4f}"
    )
