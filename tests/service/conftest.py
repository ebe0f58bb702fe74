"""Database fixtures: a migrated SQLite file per test, and a throwaway PostgreSQL database per
test session on 127.0.0.1:5432 (user postgres, trust auth), started when it is not running
and dropped afterwards. ``database`` runs a test on both."""

from __future__ import annotations

import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine, create_engine, text
from sqlalchemy.exc import OperationalError

from service.db import Database, upgrade
from service.models import Base

PG_SERVER = "postgresql+psycopg://postgres@127.0.0.1:5432"


def _admin_engine() -> Engine:
    return create_engine(f"{PG_SERVER}/postgres", isolation_level="AUTOCOMMIT")


def _postgres_reachable() -> bool:
    engine = _admin_engine()
    try:
        with engine.connect() as connection:
            connection.execute(text("SELECT 1"))
        return True
    except OperationalError:
        return False
    finally:
        engine.dispose()


def _start_postgres() -> str:
    """Try to start the local cluster; returns what went wrong ("" on success)."""
    config = Path("/etc/postgresql")
    versions = sorted(p.name for p in config.iterdir()) if config.is_dir() else []
    if not versions:
        return "no PostgreSQL cluster configured under /etc/postgresql"
    command = ["pg_ctlcluster", "--skip-systemctl-redirect", versions[-1], "main", "start"]
    try:
        run = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
    except (OSError, subprocess.TimeoutExpired) as error:
        return f"{' '.join(command)}: {error}"
    for _ in range(50):
        if _postgres_reachable():
            return ""
        time.sleep(0.2)
    return f"{' '.join(command)} exited {run.returncode}: {run.stderr.strip()}"


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    """URL of a fresh, uniquely named PostgreSQL database, dropped at the end of the session."""
    pytest.importorskip(
        "psycopg", reason="the PostgreSQL driver psycopg is not installed (psycopg[binary])"
    )
    if not _postgres_reachable():
        problem = _start_postgres()
        if problem:
            pytest.skip(f"PostgreSQL on 127.0.0.1:5432 is not running and did not start: {problem}")
    name = f"ltlnav_test_{uuid.uuid4().hex[:12]}"
    admin = _admin_engine()
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield f"{PG_SERVER}/{name}"
    finally:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


@pytest.fixture(scope="session")
def migrated_postgres(postgres_url: str) -> str:
    """The session's PostgreSQL database, migrated to head once."""
    upgrade(postgres_url)
    return postgres_url


@pytest.fixture
def sqlite_url(tmp_path: Path) -> str:
    """URL of a SQLite file in the test's temporary folder (not yet migrated)."""
    return f"sqlite:///{tmp_path / 'state' / 'ltlnav.db'}"


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request: pytest.FixtureRequest, sqlite_url: str) -> Iterator[Database]:
    """A migrated, empty database: SQLite, then PostgreSQL."""
    if request.param == "sqlite":
        upgrade(sqlite_url)
        url = sqlite_url
    else:
        url = request.getfixturevalue("migrated_postgres")
    db = Database(url)
    try:
        yield db
    finally:
        if request.param == "postgresql":
            tables = ", ".join(t.name for t in Base.metadata.sorted_tables)
            with db.engine.begin() as connection:
                connection.execute(text(f"TRUNCATE {tables} RESTART IDENTITY CASCADE"))
        db.dispose()
