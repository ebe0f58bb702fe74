"""The one clock every heartbeat and staleness test reads: the database's.

Workers on several hosts write heartbeats that one reconciler compares; a host whose clock runs
ahead or behind would make live jobs look stale, or dead ones fresh. PostgreSQL's ``now()``
is the same for every host. SQLite lives on one host (it is the embedded default), so its
clock is that host's.
"""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from service.models import utcnow


def db_now(session: Session) -> datetime:
    """The current time on the database's clock, timezone-aware UTC."""
    if session.get_bind().dialect.name == "postgresql":
        value = session.scalar(select(func.clock_timestamp()))
        assert value is not None
        return value.astimezone(UTC)
    return utcnow()
