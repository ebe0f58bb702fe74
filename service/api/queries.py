"""Database operations the API needs beyond ``service.repository``."""

from __future__ import annotations

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from service.models import Mission, MissionStatus
from service.repository import record_event

CANCELLED_IN_QUEUE = "cancelled before planning started"


def cancel_if_queued(session: Session, mission_id: str) -> bool:
    """Move a mission that no worker has picked up yet straight to cancelled (one conditional
    UPDATE: a worker that already started planning wins and stops cooperatively)."""
    outcome = session.execute(
        update(Mission)
        .where(Mission.id == mission_id, Mission.status == MissionStatus.queued)
        .values(status=MissionStatus.cancelled, reason=CANCELLED_IN_QUEUE)
        .execution_options(synchronize_session=False)
    )
    if getattr(outcome, "rowcount", 0) != 1:
        return False
    payload = {"status": MissionStatus.cancelled.value, "reason": CANCELLED_IN_QUEUE}
    record_event(session, mission_id, "status", payload)
    return True


def mission_status(session: Session, mission_id: str) -> tuple[MissionStatus, str | None] | None:
    """A mission's status and reason (None: no such mission)."""
    query = select(Mission.status, Mission.reason).where(Mission.id == mission_id)
    row = session.execute(query).one_or_none()
    return None if row is None else (row[0], row[1])
