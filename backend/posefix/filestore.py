"""The file store: where run files, images, solutions and floor plans live, on local disk
or in S3-compatible object storage, behind one interface (fsspec; s3fs for S3).

Keys are relative paths with ``/`` (``runs/3/r1-ab12cd34.parquet``). With
``POSEFIX_FILES_URL`` unset the store is the local folder ``<data_dir>/files`` (the embedded
default: every write goes to a temporary name and is renamed into place, so a reader never
sees half a file). With ``POSEFIX_FILES_URL=s3://bucket/prefix`` it is that bucket: a PUT
is all-or-nothing, so writes go straight to their key, and API processes and workers on
several machines share the files without a network file system.

Uploads are still checked in a local staging folder (``staging()``) before anything reaches
the store. What needs a real folder (a floor plan's model build) works on a local copy
(``local_copy``) kept under ``<data_dir>/cache``.

Credentials come from ``POSEFIX_S3_ACCESS_KEY_ID`` / ``POSEFIX_S3_SECRET_ACCESS_KEY``, else
from botocore's usual chain (``AWS_*`` variables, profiles, instance roles). They are kept
as secrets: no log line, repr or error message of posefix carries them.
"""

from __future__ import annotations

import logging
import os
import shutil
import uuid
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path, PurePosixPath
from typing import IO, TYPE_CHECKING, Any

import fsspec

if TYPE_CHECKING:
    from posefix.config import Settings

log = logging.getLogger("posefix.files")
# The S3 client's debug logs print request headers (the access key id among them): whatever
# level the process logs at, they stay at warnings.
CLIENT_LOGGERS = ("botocore", "aiobotocore", "s3fs", "fsspec")


class FileStore:
    """One store of files by key. ``root`` is a local folder (``Path``) or, for object
    storage, ``bucket/prefix`` on the fsspec filesystem ``fs``."""

    def __init__(self, root: Path | str, fs: fsspec.AbstractFileSystem | None = None,
                 staging_root: Path | None = None, cache_root: Path | None = None):
        self.is_local = fs is None
        self.fs = fs if fs is not None else fsspec.filesystem("file")
        self.root = Path(root).resolve() if self.is_local else str(root).strip("/")
        if self.is_local:  # staging on the store's own disk, so a checked upload is renamed into place
            staging_root, cache_root = staging_root or self.root / "staging", cache_root or self.root / "cache"
        if staging_root is None or cache_root is None:
            raise ValueError("an object store needs local staging and cache folders")
        self.staging_root, self.cache_root = Path(staging_root), Path(cache_root)

    def __repr__(self) -> str:
        return f"FileStore({self.url})"

    @property
    def url(self) -> str:
        protocol = self.fs.protocol[0] if isinstance(self.fs.protocol, tuple) else self.fs.protocol
        return str(self.root) if self.is_local else f"{protocol}://{self.root}"

    # -- keys ------------------------------------------------------------------------

    def _key(self, rel: str) -> str:
        parts = PurePosixPath(rel.replace("\\", "/")).parts
        if not parts or rel.startswith("/") or any(p in ("..", "") for p in parts):
            raise ValueError(f"path {rel!r} escapes the file store")
        return "/".join(parts)

    def _full(self, rel: str) -> str:
        key = self._key(rel)
        return str(self.root / key) if self.is_local else f"{self.root}/{key}"

    def path(self, rel: str) -> Path:
        """The local file of ``rel`` (local stores only: an object has no path)."""
        if not self.is_local:
            raise ValueError(f"{self.url} is object storage: {rel!r} has no local path")
        p = Path(self._full(rel)).resolve()
        if self.root not in p.parents:
            raise ValueError(f"path {rel!r} escapes the file store")
        return p

    def check(self) -> None:
        """Raise unless the store can be used (the folder is there, or the bucket answers)."""
        if self.is_local:
            self.root.mkdir(parents=True, exist_ok=True)
        elif not self.fs.exists(self.root.split("/", 1)[0]):
            raise FileNotFoundError(f"bucket of {self.url} not found")

    # -- reading ---------------------------------------------------------------------

    def open(self, rel: str, mode: str = "rb") -> IO[bytes]:
        if "r" not in mode:
            raise ValueError("open() reads; write with put_bytes or put_file")
        return self.path(rel).open(mode) if self.is_local else self.fs.open(self._full(rel), mode)

    def read_bytes(self, rel: str) -> bytes:
        if self.is_local:
            return self.path(rel).read_bytes()
        try:
            return self.fs.cat_file(self._full(rel))
        except FileNotFoundError:
            raise FileNotFoundError(f"{rel} is not in the file store") from None

    def exists(self, rel: str) -> bool:
        return self.path(rel).is_file() if self.is_local else self.fs.isfile(self._full(rel))

    def names(self, rel_dir: str) -> list[str]:
        """Names of the files directly in ``rel_dir`` (none when it does not exist)."""
        if self.is_local:
            d = self.path(rel_dir)
            return sorted(p.name for p in d.iterdir() if p.is_file()) if d.is_dir() else []
        try:
            entries = self.fs.ls(self._full(rel_dir), detail=True)
        except FileNotFoundError:
            return []
        return sorted(PurePosixPath(e["name"]).name for e in entries if e.get("type") == "file")

    # -- writing ---------------------------------------------------------------------

    def put_bytes(self, data: bytes, rel: str) -> str:
        if not self.is_local:
            self.fs.pipe_file(self._full(rel), data)
            return rel
        dst = self.path(rel)
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, dst)
        return rel

    def put_file(self, src: Path, rel: str) -> str:
        """Store the local file ``src`` at ``rel`` (moved when on the same local disk)."""
        if not self.is_local:
            self.fs.put_file(str(src), self._full(rel))
            return rel
        dst = self.path(rel)
        dst.parent.mkdir(parents=True, exist_ok=True)
        if Path(src).resolve() == dst:
            return rel  # already in place (a local copy of a local store is the store itself)
        if src.stat().st_dev == dst.parent.stat().st_dev:
            os.replace(src, dst)
        else:
            tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp")
            shutil.copyfile(src, tmp)
            os.replace(tmp, dst)
        return rel

    @contextmanager
    def writing(self, rel: str) -> Iterator[Path]:
        """A local file to write ``rel``'s content into; it is stored whole when the block ends.
        On disk the temporary lies beside the target (``.<name>.<uuid>.tmp``), so what a killed
        writer leaves is found with the target's other files and swept with them."""
        if not self.is_local:
            with self.staging() as d:
                tmp = d / PurePosixPath(self._key(rel)).name
                yield tmp
                self.put_file(tmp, rel)
            return
        dst = self.path(rel)
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp")
        try:
            yield tmp
            os.replace(tmp, dst)
        finally:
            tmp.unlink(missing_ok=True)

    def put_tree(self, src: Path, rel_dir: str) -> str:
        """Store every file under the local folder ``src`` below ``rel_dir``."""
        for path in sorted(p for p in Path(src).rglob("*") if p.is_file()):
            self.put_file(path, f"{rel_dir}/{path.relative_to(src).as_posix()}")
        return rel_dir

    def remove(self, rel: str) -> None:
        try:
            if self.is_local:
                self.path(rel).unlink()
            else:
                self.fs.rm_file(self._full(rel))
        except FileNotFoundError:
            pass

    def remove_tree(self, rel_dir: str) -> None:
        if self.is_local:
            shutil.rmtree(self.path(rel_dir), ignore_errors=True)
            return
        try:
            self.fs.rm(self._full(rel_dir), recursive=True)
        except FileNotFoundError:
            pass
        shutil.rmtree(self.cache_root / self._key(rel_dir), ignore_errors=True)

    # -- local folders -----------------------------------------------------------------

    @contextmanager
    def staging(self) -> Iterator[Path]:
        """A private local directory removed on exit, whatever happens."""
        d = self.staging_root / uuid.uuid4().hex
        d.mkdir(parents=True, exist_ok=False)
        try:
            yield d
        finally:
            shutil.rmtree(d, ignore_errors=True)

    def fetch_file(self, rel: str, dst: Path) -> bool:
        """Copy the object at ``rel`` to the local file ``dst`` when it is there (object stores
        only: a local store's files are already on this machine); True when copied."""
        if self.is_local or not self.fs.isfile(self._full(rel)):
            return False
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp")
        self.fs.get_file(self._full(rel), str(tmp))
        os.replace(tmp, dst)
        return True

    def local_copy(self, rel_dir: str) -> Path:
        """A local folder holding the files under ``rel_dir``: the folder itself on local
        disk; for object storage a cached copy, fetched file by file where missing."""
        if self.is_local:
            return self.path(rel_dir)
        target = self.cache_root / self._key(rel_dir)
        prefix = self._full(rel_dir)
        for name in self.fs.find(prefix):
            rel = name[len(prefix):].lstrip("/")
            dst = target / rel
            if not dst.is_file():
                dst.parent.mkdir(parents=True, exist_ok=True)
                tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp")
                self.fs.get_file(name, str(tmp))
                os.replace(tmp, dst)
        target.mkdir(parents=True, exist_ok=True)
        return target


def file_response(store: FileStore, rel: str, media_type: str, headers: dict[str, str] | None = None,
                  filename: str | None = None) -> Any:
    """An HTTP response with the file at ``rel``: sent from disk, or read from the object store."""
    from starlette.responses import FileResponse, Response

    if store.is_local:
        return FileResponse(store.path(rel), media_type=media_type, headers=headers, filename=filename)
    headers = dict(headers or {})
    if filename is not None:
        headers["Content-Disposition"] = f'attachment; filename="{filename}"'
    return Response(store.read_bytes(rel), media_type=media_type, headers=headers)


def object_filesystem(url: str, options: Mapping[str, Any]) -> tuple[fsspec.AbstractFileSystem, str]:
    """The fsspec filesystem and ``bucket/prefix`` of an object-store URL (``s3://bucket/prefix``)."""
    protocol, _, rest = url.partition("://")
    if not rest or protocol not in ("s3", "s3a"):
        raise ValueError(f"POSEFIX_FILES_URL must be s3://bucket[/prefix], got {url!r}")
    # Listings are not cached: another process may have written since.
    fs = fsspec.filesystem("s3", use_listings_cache=False, skip_instance_cache=True, **options)
    return fs, rest.strip("/")


@lru_cache(maxsize=8)
def _object_store(url: str, endpoint: str, region: str, key_id: str, secret: str, data_dir: str) -> FileStore:
    options: dict[str, Any] = {}
    client = {k: v for k, v in (("endpoint_url", endpoint), ("region_name", region)) if v}
    if client:
        options["client_kwargs"] = client
    if key_id and secret:
        options["key"], options["secret"] = key_id, secret
    for name in CLIENT_LOGGERS:
        logging.getLogger(name).setLevel(max(logging.WARNING, logging.getLogger(name).level))
    fs, root = object_filesystem(url, options)
    local = Path(data_dir).resolve()
    log.info("files in object storage %s (endpoint %s)", url, endpoint or "default")
    return FileStore(root, fs, staging_root=local / "staging", cache_root=local / "cache")


def file_store(settings: Settings) -> FileStore:
    """The store the settings name: ``POSEFIX_FILES_URL``, else ``<data_dir>/files``."""
    if not settings.files_url:
        return FileStore(settings.files_dir)
    secret = settings.s3_secret_access_key.get_secret_value() if settings.s3_secret_access_key else ""
    key_id = settings.s3_access_key_id.get_secret_value() if settings.s3_access_key_id else ""
    return _object_store(settings.files_url, settings.s3_endpoint_url, settings.s3_region, key_id, secret,
                         str(settings.data_dir))
