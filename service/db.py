"""Database engines, sessions and migrations, from ``Settings``.

SQLite (the default) runs in WAL mode with a busy timeout so the API and the workers can
share the file; PostgreSQL connections are pinged before use. A forked worker process drops
the pooled connections it inherited (SQLAlchemy's advice for multiprocessing).
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy import Engine, create_engine, event, make_url
from sqlalchemy.orm import Session, sessionmaker

from service.settings import Settings, get_settings, normalise_database_url

if TYPE_CHECKING:
    from alembic.config import Config

SQLITE_BUSY_TIMEOUT_MS = 30_000
"""How long a SQLite writer waits for the lock before failing."""

SERVER_POOL_SIZE = 20
SERVER_MAX_OVERFLOW = 20
"""Connections a database server's pool keeps open, and may open beyond that at once. The API
serves its sync routes from AnyIO's 40 threads: a pool smaller than the usual concurrency
closes every connection it cannot keep on its return and opens a new one (a server process
forked and authenticated) for the next burst, which under load cost the polled read more than
its query."""

MIGRATIONS_DIR = Path(__file__).resolve().parent.parent / "migrations"

_engines: weakref.WeakSet[Engine] = weakref.WeakSet()


def _dispose_inherited_pools() -> None:
    for engine in list(_engines):
        engine.dispose(close=False)


os.register_at_fork(after_in_child=_dispose_inherited_pools)


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    try:
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute("PRAGMA synchronous=NORMAL")
    finally:
        cursor.close()


def make_engine(url: str, echo: bool = False) -> Engine:
    """An engine for ``url`` set up for the service (see the module docstring). The folder of
    a SQLite file is created."""
    parsed = make_url(normalise_database_url(url))
    if parsed.get_backend_name() == "sqlite":
        database = parsed.database
        if database and database != ":memory:" and not database.startswith("file:"):
            Path(database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(
            parsed,
            echo=echo,
            connect_args={"check_same_thread": False, "timeout": SQLITE_BUSY_TIMEOUT_MS / 1000},
        )
        event.listen(engine, "connect", _sqlite_pragmas)
    else:
        engine = create_engine(
            parsed,
            echo=echo,
            pool_pre_ping=True,
            pool_size=SERVER_POOL_SIZE,
            max_overflow=SERVER_MAX_OVERFLOW,
        )
    _engines.add(engine)
    return engine


def make_sessions(engine: Engine) -> sessionmaker[Session]:
    """Session factory; objects stay readable after commit (the API returns them)."""
    return sessionmaker(bind=engine, expire_on_commit=False)


@contextmanager
def session_scope(sessions: sessionmaker[Session]) -> Iterator[Session]:
    """One unit of work: commit on success, roll back on error, always close."""
    session = sessions()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


class Database:
    """An engine and its session factory for one database URL."""

    def __init__(self, url: str, echo: bool = False) -> None:
        self.url = normalise_database_url(url)
        self.engine = make_engine(self.url, echo=echo)
        self.sessions = make_sessions(self.engine)
        reads = self.engine
        if self.engine.dialect.name != "sqlite":
            reads = reads.execution_options(isolation_level="AUTOCOMMIT")
        self.read_sessions = make_sessions(reads)

    @classmethod
    def from_settings(cls, settings: Settings | None = None) -> Database:
        """The database of ``settings`` (default: the process settings)."""
        return cls((settings or get_settings()).database_url)

    @contextmanager
    def session(self) -> Iterator[Session]:
        """``session_scope`` on this database."""
        with session_scope(self.sessions) as session:
            yield session

    @contextmanager
    def read_session(self) -> Iterator[Session]:
        """A session for a read of one statement (one consistent snapshot by itself). On a
        database server it runs in autocommit, so that no BEGIN and COMMIT are sent around the
        statement (two round trips of the polled read's four, with the pool's ping). On SQLite,
        where they cost no round trip, switching the connection's mode cost more than it saved
        (``bench/read_cost.py``): an ordinary session. It must not write."""
        session = self.read_sessions()
        try:
            yield session
        finally:
            session.close()

    def dispose(self) -> None:
        """Close every pooled connection."""
        self.engine.dispose()


@lru_cache(maxsize=1)
def get_database() -> Database:
    """The process-wide database of ``get_settings()`` (one engine and pool per process)."""
    return Database.from_settings()


def alembic_config(url: str) -> Config:
    """Alembic configuration for ``url`` that works from any working directory."""
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.attributes["database_url"] = normalise_database_url(url)
    return config


def upgrade(url: str, revision: str = "head") -> None:
    """Apply the migrations to ``url`` up to ``revision``."""
    from alembic import command

    command.upgrade(alembic_config(url), revision)


def downgrade(url: str, revision: str) -> None:
    """Revert the migrations of ``url`` down to ``revision`` (``base``: an empty database)."""
    from alembic import command

    command.downgrade(alembic_config(url), revision)


def current_revision(url: str) -> str | None:
    """The revision the database at ``url`` is at (None: never migrated)."""
    from alembic.migration import MigrationContext

    engine = make_engine(url)
    try:
        with engine.connect() as connection:
            return MigrationContext.configure(connection).get_current_revision()
    finally:
        engine.dispose()
