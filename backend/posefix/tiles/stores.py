"""Where tiles come from: MBTiles and PMTiles files, and upstream XYZ servers with a disk cache.

No web or database code: a store answers ``get(z, x, y) -> bytes | None`` (None: no such
tile) and knows its ``format`` and ``encoding`` (``"gzip"`` when tiles are stored
compressed, to be forwarded as ``Content-Encoding``). Open file stores are cached per
(path, size, mtime), so replacing a file takes effect on the next request.
"""

from __future__ import annotations

import gzip
import json
import mmap
import os
import sqlite3
import tempfile
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
from pmtiles.tile import Compression, TileType, deserialize_directory, deserialize_header, find_tile, zxy_to_tileid

from posefix.basemap.tiling import flip_y
from posefix.tiles.outbound import UpstreamError, fetch

__all__ = [
    "MEDIA_TYPES", "TileFileError", "UpstreamError", "TileFileInfo", "MBTilesStore",
    "PMTilesStore", "UpstreamStore", "open_tile_file", "inspect_tile_file", "sniff_format",
    "upstream_url",
]

MEDIA_TYPES = {
    "png": "image/png",
    "jpg": "image/jpeg",
    "webp": "image/webp",
    "avif": "image/avif",
    "pbf": "application/x-protobuf",
}
RASTER_FORMATS = ("png", "jpg", "webp", "avif")
_PMTILES_FORMATS = {TileType.MVT: "pbf", TileType.PNG: "png", TileType.JPEG: "jpg", TileType.WEBP: "webp", TileType.AVIF: "avif"}
MAX_UPSTREAM_TILE_BYTES = 8 * 1024 * 1024  # a tile bigger than this is no tile


class TileFileError(ValueError):
    """A tile file that cannot be served; the message names the file."""


@dataclass(frozen=True)
class TileFileInfo:
    """What a tile file says about itself."""

    container: str  # "mbtiles" or "pmtiles"
    format: str  # a key of MEDIA_TYPES
    encoding: str | None  # "gzip" or None
    min_zoom: int
    max_zoom: int
    bounds_lonlat: tuple[float, float, float, float] | None
    attribution: str
    vector_layers: list[dict[str, Any]] = field(default_factory=list)
    schema: str = ""  # e.g. "posefix-basemap-1" when a style for it is known


def sniff_format(data: bytes) -> str:
    """A tile format from the first bytes of a tile (gzip or raw protobuf count as pbf)."""
    if data.startswith(b"\x89PNG"):
        return "png"
    if data.startswith(b"\xff\xd8"):
        return "jpg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "webp"
    if data[4:12] in (b"ftypavif", b"ftypavis"):
        return "avif"
    return "pbf"


# ---------------------------------------------------------------- MBTiles


class MBTilesStore:
    """An MBTiles 1.3 file: SQLite with a ``tiles`` table (TMS rows) and ``metadata``.

    One read-only connection per thread: sqlite3 connections must not be shared while in use.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self._local = threading.local()
        self.info = self._read_info()
        self.format = self.info.format
        self.encoding = self.info.encoding

    def _connection(self) -> sqlite3.Connection:
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, check_same_thread=False)
            self._local.conn = conn
        return conn

    def get(self, z: int, x: int, y: int) -> bytes | None:
        row = self._connection().execute(
            "SELECT tile_data FROM tiles WHERE zoom_level = ? AND tile_column = ? AND tile_row = ?",
            (z, x, flip_y(z, y)),
        ).fetchone()
        return bytes(row[0]) if row is not None and row[0] is not None else None

    def _read_info(self) -> TileFileInfo:
        try:
            conn = self._connection()
            metadata = dict(conn.execute("SELECT name, value FROM metadata").fetchall())
            zooms = conn.execute("SELECT min(zoom_level), max(zoom_level) FROM tiles").fetchone()
            first = conn.execute("SELECT tile_data FROM tiles LIMIT 1").fetchone()
        except sqlite3.DatabaseError as exc:
            raise TileFileError(f"{self.path}: not an MBTiles file ({exc})") from exc
        if first is None or zooms[0] is None:
            raise TileFileError(f"{self.path}: the MBTiles file holds no tiles")
        sample = bytes(first[0])
        fmt = str(metadata.get("format", "")).lower().replace("jpeg", "jpg") or sniff_format(sample)
        if fmt not in MEDIA_TYPES:
            raise TileFileError(f"{self.path}: metadata format {fmt!r} is none of {', '.join(MEDIA_TYPES)}")
        encoding = "gzip" if sample.startswith(b"\x1f\x8b") else None
        vector_layers: list[dict[str, Any]] = []
        schema = ""
        if metadata.get("json"):
            try:
                extra = json.loads(metadata["json"])
            except json.JSONDecodeError as exc:
                raise TileFileError(f"{self.path}: metadata row 'json' is not JSON ({exc})") from exc
            vector_layers = list(extra.get("vector_layers", []))
            schema = str(extra.get("posefix:schema", ""))
        schema = str(metadata.get("posefix:schema", schema))
        return TileFileInfo(
            container="mbtiles",
            format=fmt,
            encoding=encoding,
            min_zoom=_int_or(metadata.get("minzoom"), zooms[0]),
            max_zoom=_int_or(metadata.get("maxzoom"), zooms[1]),
            bounds_lonlat=_parse_bounds(metadata.get("bounds"), self.path),
            attribution=str(metadata.get("attribution", "")),
            vector_layers=vector_layers,
            schema=schema,
        )


# ---------------------------------------------------------------- PMTiles


class PMTilesStore:
    """A PMTiles v3 file, memory-mapped; directories are parsed once and kept.

    Follows the v3 spec's lookup: find the tile id in the root directory, descend into a
    leaf directory when the entry's run length is 0 (at most three levels deep).
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            self._file = open(self.path, "rb")
            self._map = mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError) as exc:
            raise TileFileError(f"{self.path}: cannot open ({exc})") from exc
        if self._map[:7] != b"PMTiles" or self._map[7] != 3:
            raise TileFileError(f"{self.path}: not a PMTiles version 3 file")
        self.header = deserialize_header(self._map[:127])
        if self.header["internal_compression"] != Compression.GZIP:
            raise TileFileError(f"{self.path}: only gzip-compressed PMTiles directories are read")
        self._directories: dict[tuple[int, int], list] = {}
        self.info = self._read_info()
        self.format = self.info.format
        self.encoding = self.info.encoding

    def _directory(self, offset: int, length: int) -> list:
        key = (offset, length)
        entries = self._directories.get(key)
        if entries is None:
            # pmtiles' deserialize_directory gunzips itself (the writer always gzips directories).
            entries = deserialize_directory(self._map[offset: offset + length])
            if len(self._directories) < 4096:  # bounded: leaf directories of a huge file
                self._directories[key] = entries
        return entries

    def get(self, z: int, x: int, y: int) -> bytes | None:
        tile_id = zxy_to_tileid(z, x, y)
        offset, length = self.header["root_offset"], self.header["root_length"]
        for _depth in range(4):
            entry = find_tile(self._directory(offset, length), tile_id)
            if entry is None:
                return None
            if entry.run_length > 0:
                start = self.header["tile_data_offset"] + entry.offset
                return self._map[start: start + entry.length]
            offset = self.header["leaf_directory_offset"] + entry.offset
            length = entry.length
        return None

    def metadata(self) -> dict[str, Any]:
        start, length = self.header["metadata_offset"], self.header["metadata_length"]
        raw = self._map[start: start + length]
        if self.header["internal_compression"] == Compression.GZIP:
            raw = gzip.decompress(raw)
        return json.loads(raw) if raw else {}

    def _read_info(self) -> TileFileInfo:
        header = self.header
        fmt = _PMTILES_FORMATS.get(header["tile_type"])
        if fmt is None:
            raise TileFileError(f"{self.path}: tile type {header['tile_type'].name} is not served")
        compression = header["tile_compression"]
        if compression not in (Compression.NONE, Compression.GZIP, Compression.UNKNOWN):
            raise TileFileError(
                f"{self.path}: tiles compressed with {compression.name} cannot be forwarded to "
                "browsers over plain HTTP; re-encode them with gzip or none"
            )
        try:
            metadata = self.metadata()
        except (OSError, ValueError) as exc:
            raise TileFileError(f"{self.path}: unreadable metadata ({exc})") from exc
        bounds = (
            header["min_lon_e7"] / 1e7, header["min_lat_e7"] / 1e7,
            header["max_lon_e7"] / 1e7, header["max_lat_e7"] / 1e7,
        )
        return TileFileInfo(
            container="pmtiles",
            format=fmt,
            encoding="gzip" if compression == Compression.GZIP else None,
            min_zoom=int(header["min_zoom"]),
            max_zoom=int(header["max_zoom"]),
            bounds_lonlat=bounds,
            attribution=str(metadata.get("attribution", "")),
            vector_layers=list(metadata.get("vector_layers", [])),
            schema=str(metadata.get("posefix:schema", "")),
        )


# ---------------------------------------------------------------- opening files

_OPEN_STORES: OrderedDict[tuple[str, int, int], MBTilesStore | PMTilesStore] = OrderedDict()
_OPEN_LOCK = threading.Lock()
_MAX_OPEN_STORES = 64


def open_tile_file(path: Path) -> MBTilesStore | PMTilesStore:
    """The store for an .mbtiles or .pmtiles file, reusing an open one while the file is unchanged."""
    path = Path(path)
    try:
        stat = path.stat()
    except OSError as exc:
        raise TileFileError(f"{path}: no such tile file") from exc
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    with _OPEN_LOCK:
        store = _OPEN_STORES.get(key)
        if store is not None:
            _OPEN_STORES.move_to_end(key)
            return store
    suffix = path.suffix.lower()
    if suffix == ".mbtiles":
        store = MBTilesStore(path)
    elif suffix == ".pmtiles":
        store = PMTilesStore(path)
    else:
        raise TileFileError(f"{path}: tile files must end in .mbtiles or .pmtiles")
    with _OPEN_LOCK:
        _OPEN_STORES[key] = store
        while len(_OPEN_STORES) > _MAX_OPEN_STORES:
            _OPEN_STORES.popitem(last=False)
    return store


def inspect_tile_file(path: Path) -> TileFileInfo:
    """Validate a tile file and return what it declares (format, zooms, attribution...)."""
    return open_tile_file(path).info


# ---------------------------------------------------------------- upstream XYZ


def upstream_url(template: str, z: int, x: int, y: int) -> str:
    """Fill an XYZ URL template: ``{z}``, ``{x}``, ``{y}``, and ``{-y}`` for TMS servers."""
    return (
        template.replace("{z}", str(z)).replace("{x}", str(x))
        .replace("{-y}", str(flip_y(z, y))).replace("{y}", str(y))
    )


class UpstreamStore:
    """Tiles fetched from an XYZ server and kept under ``cache_dir/z/x/y.ext``.

    A cached tile younger than ``max_age_s`` is served without asking upstream. When
    upstream fails, an older cached copy is served rather than an error (a stale map
    beats a blank one); with no copy the failure is raised as :class:`UpstreamError`.
    Fetches go through :mod:`posefix.tiles.outbound` (no inward addresses, no redirects,
    bounded time and size); ``allow`` lists the networks and hosts allowed all the same.
    """

    def __init__(self, template: str, fmt: str, cache_dir: Path, max_age_s: float,
                 timeout_s: float = 10.0, allow: tuple[str, ...] = (), max_bytes: int = MAX_UPSTREAM_TILE_BYTES):
        self.template = template
        self.timeout_s = timeout_s
        self.format = fmt
        self.encoding = None  # asked for identity: stored and served as sent
        self.cache_dir = Path(cache_dir)
        self.max_age_s = max_age_s
        self.allow = allow
        self.max_bytes = max_bytes

    def cache_path(self, z: int, x: int, y: int) -> Path:
        return self.cache_dir / str(z) / str(x) / f"{y}.{self.format}"

    def get(self, z: int, x: int, y: int) -> bytes | None:
        path = self.cache_path(z, x, y)
        cached_age_s = _age_s(path)
        if cached_age_s is not None and cached_age_s < self.max_age_s:
            return path.read_bytes()
        try:
            data = self._fetch(z, x, y)
        except UpstreamError:
            if cached_age_s is not None:
                return path.read_bytes()
            raise
        if data is not None:
            _write_atomically(path, data)
        return data

    def _fetch(self, z: int, x: int, y: int) -> bytes | None:
        url = upstream_url(self.template, z, x, y)
        host = httpx.URL(url).host
        status, data, content_type = fetch(url, allow=self.allow, timeout_s=self.timeout_s, max_bytes=self.max_bytes)
        if status in (204, 404):
            return None
        if status != 200:
            raise UpstreamError(f"tile server {host} answered HTTP {status} for z={z} x={x} y={y}")
        if not data:
            raise UpstreamError(f"tile server {host} sent an empty tile for z={z} x={x} y={y}")
        if self.format in RASTER_FORMATS and sniff_format(data) != self.format:
            raise UpstreamError(f"tile server {host} sent {content_type or 'unknown content'}, not a {self.format} image")
        return data


def _age_s(path: Path) -> float | None:
    try:
        return time.time() - path.stat().st_mtime
    except OSError:
        return None


def _write_atomically(path: Path, data: bytes) -> None:
    # Several API processes may fetch the same tile at once: each writes its own temporary
    # file and renames it into place, so readers never see half a tile.
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=".tile-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise


def _int_or(value: Any, default: int) -> int:
    try:
        return int(value)
    except (TypeError, ValueError):
        return int(default)


def _parse_bounds(value: Any, path: Path) -> tuple[float, float, float, float] | None:
    if not value:
        return None
    try:
        parts = tuple(float(part) for part in str(value).split(","))
    except ValueError as exc:
        raise TileFileError(f"{path}: metadata row 'bounds' is not four numbers: {value!r}") from exc
    if len(parts) != 4:
        raise TileFileError(f"{path}: metadata row 'bounds' is not four numbers: {value!r}")
    return parts  # type: ignore[return-value]
