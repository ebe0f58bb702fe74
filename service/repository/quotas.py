"""Per-key submission quotas, counted from the missions table: how many missions a key has
queued or running, and how many it submitted in the last minute.

The counts use ``ix_missions_owner_created`` (owner, created_at). ``serialize_submissions``
makes the count-then-insert of one key's submissions exact under concurrency: on PostgreSQL a
transaction-scoped advisory lock per key; SQLite serializes every write transaction already,
so a count taken after the insert, in the same transaction, sees every other submission."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import ColumnElement, case, func, select, text
from sqlalchemy.orm import Session

from service.models import Mission, MissionStatus, utcnow
from service.repository.missions import hash_key

ACTIVE_STATES = frozenset(
    {MissionStatus.queued, MissionStatus.planning, MissionStatus.training, MissionStatus.evaluating}
)
"""A mission in one of these counts against its key's quota of missions at once."""

RATE_WINDOW = timedelta(seconds=60)
"""The window of the submissions-per-minute quota."""


@dataclass(frozen=True)
class QuotaUsage:
    """What one key uses now: missions queued or running, submissions in the last
    ``RATE_WINDOW`` and when the oldest of those was made (None: none)."""

    active: int
    recent: int
    oldest_recent: datetime | None


def _owner_condition(api_key: str | None) -> ColumnElement[bool]:
    owner = hash_key(api_key)
    return Mission.owner.is_(None) if owner is None else Mission.owner == owner


def quota_usage(session: Session, api_key: str | None, now: datetime | None = None) -> QuotaUsage:
    """The usage of ``api_key`` (None: the open API) at ``now`` (default: the clock that
    stamps ``created_at``)."""
    since = (now or utcnow()) - RATE_WINDOW
    is_active = Mission.status.in_(ACTIVE_STATES)
    is_recent = Mission.created_at > since
    active, recent, oldest = session.execute(
        select(
            func.sum(case((is_active, 1), else_=0)),
            func.sum(case((is_recent, 1), else_=0)),
            func.min(case((is_recent, Mission.created_at))),
        ).where(_owner_condition(api_key))
    ).one()
    return QuotaUsage(active=int(active or 0), recent=int(recent or 0), oldest_recent=oldest)


def _lock_id(api_key: str | None) -> int:
    digest = hashlib.sha256(b"ltlnav-submissions:" + (hash_key(api_key) or "").encode()).digest()
    return int.from_bytes(digest[:8], "big", signed=True)


def serialize_submissions(session: Session, api_key: str | None) -> None:
    """Hold, until the transaction ends, the lock that orders the submissions of
    ``api_key``: counts and idempotency lookups made after it see every earlier submission of
    the key. PostgreSQL: an advisory transaction lock; SQLite: nothing (see the module)."""
    if session.get_bind().dialect.name == "postgresql":
        session.execute(text("SELECT pg_advisory_xact_lock(:id)"), {"id": _lock_id(api_key)})
