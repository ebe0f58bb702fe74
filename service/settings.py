"""Service configuration from ``LTLNAV_...`` environment variables (pydantic-settings).

This is the only module of the project that reads the environment. Everything the service
writes (SQLite database, embedded broker and result files, artifacts) defaults to a place
under one data directory, ``LTLNAV_DATA_DIR`` (``./var``), so a fresh machine needs no
server; PostgreSQL and Redis come in through ``DATABASE_URL`` / ``LTLNAV_BROKER_URL``.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any

from pydantic import AliasChoices, Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


def _sqlite_url(scheme: str, path: Path) -> str:
    return f"{scheme}:///{path}"


def normalise_database_url(url: str) -> str:
    """SQLAlchemy URL for ``url``: the ``postgres://`` / ``postgresql://`` forms that hosting
    platforms hand out select the psycopg (v3) driver, the one the project installs."""
    for prefix in ("postgres://", "postgresql://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url[len(prefix) :]
    return url


class Settings(BaseSettings):
    """Every knob of the service. Paths default to places under ``data_dir``."""

    model_config = SettingsConfigDict(env_prefix="LTLNAV_", extra="ignore")

    data_dir: Path = Path("var")
    """Directory for everything the service writes by default (made absolute)."""

    database_url: str = Field(
        default_factory=lambda data: _sqlite_url("sqlite", data["data_dir"] / "ltlnav.db"),
        validation_alias=AliasChoices("LTLNAV_DATABASE_URL", "DATABASE_URL", "database_url"),
    )
    """SQLAlchemy URL of the state database (``LTLNAV_DATABASE_URL`` or ``DATABASE_URL``).
    Default: SQLite file ``<data_dir>/ltlnav.db``. ``postgres://`` URLs use psycopg 3."""

    broker_url: str = Field(
        default_factory=lambda data: _sqlite_url("sqla+sqlite", data["data_dir"] / "broker.db")
    )
    """Celery broker. Default: kombu's SQLAlchemy transport on ``<data_dir>/broker.db``, which
    needs no server; ``redis://host:6379/0`` for several machines."""

    result_backend: str = Field(
        default_factory=lambda data: _sqlite_url("db+sqlite", data["data_dir"] / "results.db")
    )
    """Celery result backend (chords need one). Default: SQLite ``<data_dir>/results.db``, a
    file apart from the state database so result polling does not contend with it."""

    api_keys: Annotated[list[str], NoDecode] = Field(default_factory=list)
    """Bearer tokens the API accepts, as a JSON list or comma-separated. Each mission belongs
    to the key that created it. Empty: the API is open (the local default)."""

    artifact_dir: Path = Field(default_factory=lambda data: data["data_dir"] / "artifacts")
    """Where checkpoints, curves, pictures and bundles go (their paths are stored in the
    database). Workers on several machines must share it. Default ``<data_dir>/artifacts``."""

    examples_dir: Path = Path(__file__).resolve().parents[1] / "examples"
    """Mission files offered by ``GET /examples`` and ``{"example": name}`` (file stem)."""

    host: str = "127.0.0.1"
    """Address ``ltlnav serve`` binds (``0.0.0.0`` to listen on every interface)."""

    port: int = Field(default=8000, ge=1, le=65535)
    """Port ``ltlnav serve`` listens on."""

    max_body_bytes: int = Field(default=1_000_000, gt=0)
    """Largest accepted request body; larger ones get 413."""

    heartbeat_seconds: float = Field(default=10.0, gt=0)
    """How often a running job writes its heartbeat (and at most how often its progress)."""

    stale_after_seconds: float = Field(default=60.0, gt=0)
    """A running job whose heartbeat is older than this is taken for dead and re-enqueued."""

    @field_validator("data_dir", "artifact_dir", "examples_dir")
    @classmethod
    def _absolute(cls, value: Path) -> Path:
        return value.expanduser().absolute()

    @field_validator("database_url")
    @classmethod
    def _driver(cls, value: str) -> str:
        return normalise_database_url(value)

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value: Any) -> Any:
        if isinstance(value, str):
            text = value.strip()
            if text.startswith("["):
                return json.loads(text)
            return [key.strip() for key in text.split(",") if key.strip()]
        return value

    @model_validator(mode="after")
    def _heartbeat_below_stale(self) -> Settings:
        if self.stale_after_seconds <= self.heartbeat_seconds:
            raise ValueError(
                f"stale_after_seconds ({self.stale_after_seconds}) must exceed "
                f"heartbeat_seconds ({self.heartbeat_seconds}), or live jobs look dead"
            )
        return self

    def make_dirs(self) -> None:
        """Create the data and artifact directories."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.artifact_dir.mkdir(parents=True, exist_ok=True)


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings, read once (``get_settings.cache_clear()`` to re-read)."""
    return Settings()
