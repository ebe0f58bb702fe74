"""The mission event feed (Server-Sent Events)."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from service.models import (
    Event,
)


def record_event(session: Session, mission_id: str, kind: str, payload: dict[str, Any]) -> Event:
    """Append an event to a mission's feed."""
    row = Event(mission_id=mission_id, kind=kind, payload=payload)
    session.add(row)
    session.flush()
    return row


def events_after(
    session: Session, mission_id: str, after_id: int = 0, limit: int = 100
) -> list[Event]:
    """A mission's events with id above ``after_id`` (SSE ``Last-Event-ID``), oldest first.

    Ids grow with insertion. On PostgreSQL two transactions committing out of id order can
    make a reader that already passed an id miss the later-committed lower one; status lives
    in the mission row too, so a client re-reads the mission on reconnect."""
    query = (
        select(Event)
        .where(Event.mission_id == mission_id, Event.id > after_id)
        .order_by(Event.id)
        .limit(limit)
    )
    return list(session.scalars(query))
