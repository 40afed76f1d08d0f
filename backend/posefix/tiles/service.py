"""Tile-source rules: registration checks, serving tiles with validators, deleting.

Services never commit; the request does (see ``posefix.deps.get_session``).
"""

from __future__ import annotations

import functools
import hashlib
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from urllib.parse import urlsplit

from pydantic_settings import BaseSettings, SettingsConfigDict
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from posefix.basemap.tiling import is_valid_tile
from posefix.config import Settings
from posefix.errors import AppError, BadRequest, Conflict, NotFound, Unprocessable
from posefix.filestore import file_store
from posefix.tiles import repository as repo
from posefix.tiles.models import TileFormat, TileSource
from posefix.tiles.schemas import TileSourceCreate, TileSourcePublic
from posefix.tiles.stores import (
    MEDIA_TYPES, RASTER_FORMATS, MBTilesStore, PMTilesStore, TileFileError, UpstreamError, UpstreamStore,
    open_tile_file,
)

log = logging.getLogger("posefix.tiles")

__all__ = [
    "TileSettings", "BadGateway", "TileFileUnavailable", "TileBody", "create_source", "list_sources", "get_source",
    "delete_source", "read_tile", "to_public", "source_file_path", "resolve_data_path",
]


class TileSettings(BaseSettings):
    """Tile serving settings (``POSEFIX_TILE_*``)."""

    model_config = SettingsConfigDict(env_prefix="POSEFIX_TILE_", env_file=".env", extra="ignore")

    # Upstream tiles younger than this are served from the disk cache without asking upstream.
    upstream_max_age_s: float = 7 * 86400.0
    # Longest wait for one upstream tile, body included (connecting takes at most 3 s of it).
    upstream_timeout_s: float = 10.0
    # Largest upstream tile accepted (bytes); a bigger body is dropped as it arrives.
    upstream_max_bytes: int = 8 * 1024 * 1024
    # Networks ("10.1.2.0/24", "127.0.0.1") and host names an upstream may resolve into even
    # though they are not public addresses: a site's own tile server. Empty: public only.
    upstream_allow: list[str] = []
    # Browsers may reuse a served tile this long before revalidating with its ETag.
    browser_max_age_s: int = 3600
    # Empty: <data_dir>/tile-cache.
    cache_dir: Path | None = None


@functools.lru_cache(maxsize=1)
def tile_settings() -> TileSettings:
    """The tile settings, read once per process (``tile_settings.cache_clear()`` re-reads them)."""
    return TileSettings()


# A tile request looks its source up by name; the answer is kept this long per process,
# so a source deleted through another API process stops serving here within this time.
SOURCE_CACHE_S = 2.0
_SOURCE_CACHE: dict[str, tuple[float, TileSource]] = {}


def cached_source(session: Session, name: str) -> TileSource:
    """``get_source`` for the hot tile path: a detached copy, reused for SOURCE_CACHE_S."""
    now = time.monotonic()
    hit = _SOURCE_CACHE.get(name)
    if hit is not None and hit[0] > now:
        return hit[1]
    source = get_source(session, name)
    session.expunge(source)
    _SOURCE_CACHE[name] = (now + SOURCE_CACHE_S, source)
    return source


def forget_cached_sources() -> None:
    _SOURCE_CACHE.clear()


class BadGateway(AppError):
    status_code, code = 502, "upstream_failed"


class TileFileUnavailable(AppError):
    """A registered tile file that has gone missing or bad since it was registered."""

    status_code, code = 503, "tile_file_unavailable"


@dataclass(frozen=True)
class TileBody:
    """One tile ready to send: bytes as stored, their media type, encoding and validator."""

    data: bytes
    media_type: str
    encoding: str | None
    etag: str
    max_age_s: int


def resolve_data_path(data_dir: Path, path: str) -> tuple[Path, str]:
    """(absolute path, path relative to the data directory) of a tile file; refuses escapes.

    The relative form is what is stored, so the data directory can move.
    """
    root = Path(data_dir).resolve()
    try:
        candidate = Path(path)
        absolute = (candidate if candidate.is_absolute() else root / candidate).resolve()
    except (OSError, ValueError) as exc:  # NUL bytes, names too long for the file system
        raise Unprocessable(f"tile file path {path!r} is not usable: {exc}", code="invalid_tile_file") from None
    try:
        relative = absolute.relative_to(root)
    except ValueError:
        raise Unprocessable(
            f"tile file {path!r} is outside the data directory {root}; copy it there first",
            code="tile_path_outside_data_dir",
        ) from None
    return absolute, PurePosixPath(*relative.parts).as_posix()


def source_file_path(settings: Settings, source: TileSource) -> Path:
    return _on_this_machine(settings, _resolved_file(str(settings.data_dir), source.path or ""), source.path or "")


def _on_this_machine(settings: Settings, absolute: Path, relative: str) -> Path:
    """A tile file missing from this machine's data directory is fetched once from the file
    store (key ``tiles/<path>``), so with object storage one upload serves every machine."""
    if not absolute.is_file():
        file_store(settings).fetch_file(f"tiles/{PurePosixPath(relative).as_posix()}", absolute)
    return absolute


@functools.lru_cache(maxsize=256)
def _resolved_file(data_dir: str, path: str) -> Path:
    # resolving walks the file system (a stat per component): once per registered file, not per tile
    return resolve_data_path(Path(data_dir), path)[0]


def _cache_dir(settings: Settings, options: TileSettings, source: TileSource) -> Path:
    base = options.cache_dir or (Path(settings.data_dir) / "tile-cache")
    # The id keeps a re-registered name from serving the old source's cached tiles.
    return Path(base).resolve() / f"{source.id}-{source.name}"


def _check_upstream_url(url: str) -> None:
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 (parses the port; raises on garbage)
    except ValueError as exc:
        raise Unprocessable(f"upstream url {url!r} is not a URL ({exc})", code="invalid_tile_url") from None
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise Unprocessable(f"upstream url {url!r} must be an absolute http(s) URL", code="invalid_tile_url")
    missing = [key for key in ("{z}", "{x}") if key not in url]
    if "{y}" not in url and "{-y}" not in url:
        missing.append("{y}")
    if missing:
        raise Unprocessable(f"upstream url {url!r} lacks {', '.join(missing)}", code="invalid_tile_url")


def _format_from_url(url: str) -> str | None:
    suffix = PurePosixPath(urlsplit(url).path).suffix.lower().lstrip(".")
    suffix = {"jpeg": "jpg", "mvt": "pbf"}.get(suffix, suffix)
    return suffix if suffix in MEDIA_TYPES else None


def create_source(session: Session, settings: Settings, body: TileSourceCreate, created_by_id: int | None) -> TileSource:
    """Validate and add a tile source; a file source is opened and must agree with the request."""
    if repo.get_source_by_name(session, body.name) is not None:
        raise Conflict(f"tile source {body.name!r} already exists", code="tile_source_exists")
    source = TileSource(
        name=body.name, title=body.title or body.name, kind=body.kind.value, attribution=body.attribution,
        tile_size=body.tile_size, created_by_id=created_by_id, vector_layers=[], style_schema="",
    )
    if body.path is not None:
        _fill_from_file(source, settings, body)
    else:
        _fill_from_upstream(source, body)
    try:
        with session.begin_nested():
            repo.add(session, source)
    except IntegrityError:
        raise Conflict(f"tile source {body.name!r} already exists", code="tile_source_exists") from None
    forget_cached_sources()
    return source


def _fill_from_file(source: TileSource, settings: Settings, body: TileSourceCreate) -> None:
    absolute, relative = resolve_data_path(settings.data_dir, body.path or "")
    try:
        info = open_tile_file(_on_this_machine(settings, absolute, relative)).info
    except TileFileError as exc:
        raise Unprocessable(str(exc), code="invalid_tile_file") from None
    if body.format is not None and body.format.value != info.format:
        raise Unprocessable(
            f"{relative} holds {info.format} tiles, not {body.format.value}", code="tile_format_mismatch"
        )
    min_zoom = info.min_zoom if body.min_zoom is None else body.min_zoom
    max_zoom = info.max_zoom if body.max_zoom is None else body.max_zoom
    # Beyond the file's own range the browser would fetch missing tiles instead of
    # over-zooming the last level it has: a blank map.
    if min_zoom < info.min_zoom or max_zoom > info.max_zoom or min_zoom > max_zoom:
        raise Unprocessable(
            f"zoom range {min_zoom}..{max_zoom} is outside {relative}'s {info.min_zoom}..{info.max_zoom}",
            code="tile_zoom_range",
        )
    source.path = relative
    source.format = info.format
    source.encoding = info.encoding
    source.min_zoom, source.max_zoom = min_zoom, max_zoom
    source.bounds = list(info.bounds_lonlat) if info.bounds_lonlat else None
    source.vector_layers = info.vector_layers
    source.style_schema = info.schema
    source.attribution = body.attribution or info.attribution


def _fill_from_upstream(source: TileSource, body: TileSourceCreate) -> None:
    url = body.url or ""
    _check_upstream_url(url)
    fmt = body.format.value if body.format is not None else _format_from_url(url)
    if fmt is None:
        raise Unprocessable(f"cannot tell the tile format from {url!r}; give 'format'", code="tile_format_unknown")
    if fmt not in RASTER_FORMATS:
        raise Unprocessable(
            "upstream vector tiles are not proxied (their layers are unknown to the style); "
            "register an MBTiles or PMTiles file instead",
            code="tile_format_unsupported",
        )
    source.url = url
    source.format = fmt
    source.encoding = None
    source.min_zoom = 0 if body.min_zoom is None else body.min_zoom
    source.max_zoom = 19 if body.max_zoom is None else body.max_zoom


def list_sources(session: Session) -> list[TileSource]:
    return repo.list_sources(session)


def get_source(session: Session, ref: str) -> TileSource:
    """A source by numeric id or by name (names start with a letter, so the two never clash)."""
    if ref.isascii() and ref.isdigit():
        # Ids beyond 64 bits exist nowhere; asking the database would overflow its integer.
        source = repo.get_source(session, int(ref)) if len(ref) <= 18 else None
    else:
        source = repo.get_source_by_name(session, ref)
    if source is None:
        raise NotFound(f"tile source {ref!r} not found", code="tile_source_not_found")
    return source


def delete_source(session: Session, settings: Settings, ref: str) -> None:
    """Forget a source; its file stays (it may be registered again), its upstream cache goes."""
    source = get_source(session, ref)
    cache_dir = _cache_dir(settings, tile_settings(), source) if source.url else None
    repo.delete(session, source)
    forget_cached_sources()
    if cache_dir is not None:
        shutil.rmtree(cache_dir, ignore_errors=True)


def open_store(settings: Settings, source: TileSource) -> MBTilesStore | PMTilesStore | UpstreamStore:
    if source.url:
        options = tile_settings()
        return UpstreamStore(source.url, source.format, _cache_dir(settings, options, source),
                             options.upstream_max_age_s, options.upstream_timeout_s,
                             allow=tuple(options.upstream_allow), max_bytes=options.upstream_max_bytes)
    try:
        return open_tile_file(source_file_path(settings, source))
    except TileFileError as exc:
        # Registered once, broken now (moved, replaced by a bad file): the server's state is wrong.
        raise TileFileUnavailable(str(exc)) from None


def read_tile(settings: Settings, source: TileSource, z: int, x: int, y: int, ext: str) -> TileBody | None:
    """The tile (z, x, y) of ``source`` or None when the source has no such tile.

    Raises 404 for a wrong extension or a zoom outside the source's range, 400 for
    coordinates outside the tile pyramid, and 502 when an upstream server fails.
    """
    ext = "jpg" if ext == "jpeg" else ext
    if ext != source.format:
        raise NotFound(f"tile source {source.name!r} serves .{source.format} tiles, not .{ext}",
                       code="tile_format_mismatch")
    if not is_valid_tile(z, x, y):
        raise BadRequest(f"no tile z={z} x={x} y={y}: x and y must be below 2**z", code="tile_out_of_range")
    if not source.min_zoom <= z <= source.max_zoom:
        raise NotFound(f"tile source {source.name!r} has zooms {source.min_zoom}..{source.max_zoom}, not {z}",
                       code="tile_zoom_out_of_range")
    store = open_store(settings, source)
    try:
        data = store.get(z, x, y)
    except UpstreamError as exc:
        # The reason (refused address, status, time-out...) would help a client map the
        # server's network, so it goes to the log only.
        log.warning("upstream tile %s/%d/%d/%d failed: %s", source.name, z, x, y, exc)
        raise BadGateway(f"tile source {source.name!r} could not deliver this tile") from None
    if data is None:
        return None
    etag = '"' + hashlib.blake2b(data, digest_size=16).hexdigest() + '"'
    return TileBody(bytes(data), MEDIA_TYPES[source.format], store.encoding, etag, tile_settings().browser_max_age_s)


def tile_url_template(source: TileSource, base_url: str) -> str:
    """Absolute XYZ template of a source on this server (MapLibre needs absolute URLs)."""
    return f"{base_url.rstrip('/')}/api/v1/tiles/{source.name}/{{z}}/{{x}}/{{y}}.{source.format}"


def to_public(source: TileSource, base_url: str) -> TileSourcePublic:
    return TileSourcePublic(
        id=source.id, name=source.name, title=source.title, kind=source.kind, attribution=source.attribution,
        min_zoom=source.min_zoom, max_zoom=source.max_zoom, format=TileFormat(source.format),
        origin="upstream" if source.url else "file", path=source.path, url=source.url,
        tile_size=source.tile_size, bounds=source.bounds, tile_url=tile_url_template(source, base_url),
        created_at=source.created_at,
    )


def etag_matches(if_none_match: str | None, etag: str) -> bool:
    """RFC 9110 weak comparison of an If-None-Match header against our strong ETag."""
    if not if_none_match:
        return False
    candidates = [part.strip() for part in if_none_match.split(",")]
    return "*" in candidates or any(c.removeprefix("W/") == etag for c in candidates)
