"""Settings of the web service and worker, read from the environment and ``.env``.

Every variable carries the ``POSEFIX_`` prefix (``POSEFIX_DATABASE_URL``,
``POSEFIX_SECRET_KEY``...). Outside ``development`` and ``test`` the service refuses to
start with the default secret.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["Settings", "DEFAULT_SECRET", "get_settings"]

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
    # Public origin(s) the browser uses, for the CSRF Origin check; empty: the request's Host.
    allowed_origins: list[str] = Field(default_factory=list)
    log_level: str = "INFO"
    log_json: bool = True

    # Sessions (seconds).
    session_cookie_name: str = "posefix_session"
    session_idle_timeout_s: int = 2 * 3600
    session_absolute_timeout_s: int = 24 * 3600
    # Login throttling: this many failures per username or client address within the window.
    login_max_failures: int = 5
    login_window_s: int = 15 * 60

    # Uploads (bytes).
    max_run_bytes: int = 512 * 1024 * 1024
    max_images_bytes: int = 1024 * 1024 * 1024
    max_image_count: int = 20000
    max_image_bytes: int = 50 * 1024 * 1024
    # A zip member may expand at most this many times its compressed size.
    max_zip_ratio: float = 200.0

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


def get_settings() -> Settings:
    return Settings()
