"""Settings of the web service and worker, read from the environment and ``.env``.

Every variable carries the ``POSEFIX_`` prefix (``POSEFIX_DATABASE_URL``,
``POSEFIX_SECRET_KEY``...). Outside ``development`` and ``test`` the service refuses to
start with the default secret.
"""

from __future__ import annotations

import json
import os
from functools import cached_property
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["Settings", "DEFAULT_SECRET", "get_settings", "local_origins", "origin_of", "with_listen_origins"]

DEFAULT_SECRET = "posefix-development-secret-change-me"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(
        env_prefix="POSEFIX_", env_file=".env", env_file_encoding="utf-8", extra="ignore"
    )

    environment: Literal["development", "test", "production"] = "development"
    secret_key: str = DEFAULT_SECRET
    # Empty: a SQLite file under data_dir.
    database_url: str = ""
    # Connections per process (PostgreSQL). Request threads are capped to fit in them, so a
    # burst queues for a thread instead of timing out on the pool.
    db_pool_size: int = 10
    db_max_overflow: int = 20
    data_dir: Path = Path("var")
    # Origin(s) the browser uses, for the CSRF Origin check. Empty: the origin of public_url;
    # with neither, development allows the local server (`serve`/`demo` name their own host
    # and port), test allows the test client (http(s)://testserver), production refuses (and
    # `posefix serve` will not start). Never the request's Host header, which a client forges.
    allowed_origins: list[str] = Field(default_factory=list)
    # The URL users open (e.g. https://posefix.example.org).
    public_url: str = ""
    log_level: str = "INFO"
    log_json: bool = True

    # Sessions (seconds).
    session_cookie_name: str = "posefix_session"
    session_idle_timeout_s: int = 2 * 3600
    session_absolute_timeout_s: int = 24 * 3600
    # Login throttling (users/throttle.py): failures per account and address within the window
    # that cost nothing; each further one doubles the wait, from the base up to the maximum.
    login_max_failures: int = 5
    login_window_s: int = 15 * 60
    login_delay_base_s: float = 1.0
    login_max_delay_s: float = 15 * 60.0

    # Uploads (bytes).
    max_run_bytes: int = 512 * 1024 * 1024
    max_images_bytes: int = 1024 * 1024 * 1024
    max_image_count: int = 20000
    max_image_bytes: int = 50 * 1024 * 1024
    # A zip member may expand at most this many times its compressed size.
    max_zip_ratio: float = 200.0
    # Request bodies: each piece must arrive within this many seconds, and after that long the
    # body must average at least this many bytes a second; else 408 and the connection closes.
    body_idle_timeout_s: float = 30.0
    body_min_rate_bps: float = 4096.0

    # Access before tasks exist: let operators see every run (the demo turns this on).
    operators_see_all_runs: bool = False

    # Jobs and worker.
    job_lease_s: float = 60.0
    job_heartbeat_s: float = 10.0
    job_max_attempts: int = 5
    job_backoff_base_s: float = 2.0
    job_backoff_max_s: float = 300.0
    worker_poll_s: float = 1.0
    # On SQLite `posefix serve` runs a worker thread in the server process.
    embedded_worker: bool = True

    # Where run files, images, solutions and floor plans live (posefix/filestore.py). Empty:
    # the local folder <data_dir>/files. "s3://bucket/prefix": S3-compatible object storage
    # (AWS S3, MinIO, ...), shared by API processes and workers on several machines.
    files_url: str = ""
    # The object store's endpoint (MinIO: http://minio:9000; empty: AWS) and region.
    s3_endpoint_url: str = ""
    s3_region: str = ""
    # Credentials; unset: botocore's chain (AWS_ACCESS_KEY_ID..., profiles, instance roles).
    # Secrets: never printed, logged or put in an error message.
    s3_access_key_id: SecretStr | None = None
    s3_secret_access_key: SecretStr | None = None

    # Keyframes GeoJSON: at most this many vertices in the decimated line.
    line_max_points: int = 5000
    # Engine configuration file (TOML); empty: engine defaults.
    engine_config: Path | None = None
    # OpenStreetMap extract (.osm.pbf) for map-matching suggestions; empty: data/osm/helsinki.osm.pbf.
    osm_extract: Path | None = None

    @model_validator(mode="after")
    def _refuse_default_secret(self) -> Settings:
        if self.environment == "production" and self.secret_key == DEFAULT_SECRET:
            raise ValueError(
                "POSEFIX_SECRET_KEY is the default development secret; set a random secret "
                "(e.g. `python -c 'import secrets; print(secrets.token_urlsafe(48))'`) "
                "or POSEFIX_ENVIRONMENT=development"
            )
        if self.environment == "production" and len(self.secret_key) < 32:
            raise ValueError("POSEFIX_SECRET_KEY must be at least 32 characters in production")
        return self

    @property
    def csrf_origins(self) -> frozenset[str]:
        """The origins a cookie-authenticated unsafe request may come from."""
        if self.allowed_origins:
            return frozenset(origin_of(o) for o in self.allowed_origins)
        if self.public_url:
            return frozenset({origin_of(self.public_url)})
        if self.environment == "test":
            return frozenset(TEST_CLIENT_ORIGINS)
        if self.environment == "development":
            return frozenset(local_origins("127.0.0.1", 8000))
        return frozenset()

    @cached_property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        path = (self.data_dir / "posefix.sqlite").resolve()
        return f"sqlite:///{path}"

    @property
    def is_sqlite(self) -> bool:
        return self.resolved_database_url.startswith("sqlite")

    @property
    def files_dir(self) -> Path:
        return (self.data_dir / "files").resolve()


TEST_CLIENT_ORIGINS = ("http://testserver", "https://testserver")  # Starlette's TestClient


def origin_of(url: str) -> str:
    """scheme://host[:port] of a URL, lower-case, without a trailing slash."""
    parts = urlsplit(url.strip())
    return f"{parts.scheme}://{parts.netloc}".lower() if parts.scheme and parts.netloc else url.strip().rstrip("/").lower()


def local_origins(host: str, port: int) -> list[str]:
    """The origins a browser on this machine uses for a server listening on host:port."""
    if host in ("", "0.0.0.0", "::", "127.0.0.1", "::1", "localhost"):
        return [f"http://localhost:{port}", f"http://127.0.0.1:{port}", f"http://[::1]:{port}"]
    return [f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"]


def with_listen_origins(settings: Settings, host: str, port: int) -> Settings:
    """In development with no origin configured, allow the server's own host and port
    (also for worker processes uvicorn starts, which read the environment)."""
    if settings.environment != "development" or settings.allowed_origins or settings.public_url:
        return settings
    origins = local_origins(host, port)
    os.environ["POSEFIX_ALLOWED_ORIGINS"] = json.dumps(origins)
    return settings.model_copy(update={"allowed_origins": origins})


def get_settings() -> Settings:
    return Settings()
