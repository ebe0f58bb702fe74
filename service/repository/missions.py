"""Missions: creation, key-scoped reads, the status life cycle, plan and result."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Literal

from sqlalchemy import delete, func, select, update
from sqlalchemy.orm import Session, joinedload

from planner.errors import LtlnavError
from service.models import (
    Job,
    JobStatus,
    Mission,
    MissionStatus,
)
from service.repository.clock import db_now
from service.repository.events import record_event

FINAL_STATES = frozenset({MissionStatus.done, MissionStatus.failed, MissionStatus.cancelled})


TRANSITIONS: dict[MissionStatus, frozenset[MissionStatus]] = {
    MissionStatus.queued: frozenset({MissionStatus.planning}),
    MissionStatus.planning: frozenset({MissionStatus.training}),
    MissionStatus.training: frozenset({MissionStatus.evaluating}),
    MissionStatus.evaluating: frozenset({MissionStatus.done, MissionStatus.training}),
}
"""Forward moves (evaluating -> training: a round of hand-over repair jobs); any non-final
state may also go to failed or cancelled."""


class TransitionError(LtlnavError):
    """A status change the life cycle does not allow (e.g. out of a final state)."""


class NotFoundError(LtlnavError):
    """No mission or job with that id."""


def hash_key(api_key: str | None) -> str | None:
    """What ``Mission.owner`` stores for ``api_key``: its SHA-256 hex (None for the open API)."""
    return None if api_key is None else hashlib.sha256(api_key.encode()).hexdigest()


@dataclass(frozen=True)
class MissionPage:
    """One page of missions, newest first, and how many the key owns in all."""

    items: list[Mission]
    total: int
    limit: int
    offset: int


def create_mission(
    session: Session,
    name: str,
    document: dict[str, Any],
    api_key: str | None,
    idempotency_key: str | None = None,
) -> Mission:
    """A new queued mission owned by ``api_key`` (None: the open API), submitted with
    ``idempotency_key`` (see ``find_by_idempotency_key``)."""
    mission = Mission(
        name=name, document=document, owner=hash_key(api_key), idempotency_key=idempotency_key
    )
    session.add(mission)
    session.flush()
    record_event(session, mission.id, "status", {"status": mission.status.value, "reason": None})
    return mission


def get_mission(session: Session, mission_id: str) -> Mission | None:
    """The mission with this id whoever owns it (for workers), with its jobs."""
    return session.get(Mission, mission_id)


def get_owned_mission(session: Session, mission_id: str, api_key: str | None) -> Mission | None:
    """The mission if ``api_key`` created it, else None (the API answers 404 alike). Its jobs
    come in the same query (one round trip per read of the polled ``GET /missions/{id}``)."""
    query = (
        select(Mission)
        .options(joinedload(Mission.jobs))
        .where(Mission.id == mission_id, _owned_by(api_key))
    )
    return session.scalars(query).unique().one_or_none()


def find_by_idempotency_key(
    session: Session,
    api_key: str | None,
    idempotency_key: str,
    since: datetime,
    other_than: str | None = None,
) -> Mission | None:
    """The first mission ``api_key`` submitted with ``idempotency_key`` after ``since``
    (oldest; besides ``other_than`` when given), or None. Keys are per API key: another key's
    missions never match, and in the open API the owner matches with IS NULL."""
    conditions = [
        _owned_by(api_key),
        Mission.idempotency_key == idempotency_key,
        Mission.created_at > since,
    ]
    if other_than is not None:
        conditions.append(Mission.id != other_than)
    query = select(Mission).where(*conditions).order_by(Mission.created_at, Mission.id).limit(1)
    return session.scalars(query).first()


def delete_mission(session: Session, mission_id: str) -> bool:
    """Delete a mission that has ended (done, failed, cancelled) and has no job still
    running, with its jobs, checkpoints, evaluations and events (the foreign keys cascade).
    False when it is not there or not in that state. Its artifact folder is the caller's."""
    running = select(Job.id).where(Job.mission_id == Mission.id, Job.status == JobStatus.running)
    outcome = session.execute(
        delete(Mission)
        .where(Mission.id == mission_id, Mission.status.in_(FINAL_STATES), ~running.exists())
        .execution_options(synchronize_session=False)
    )
    return getattr(outcome, "rowcount", 0) == 1


def list_missions(
    session: Session,
    api_key: str | None,
    limit: int = 20,
    offset: int = 0,
    status: MissionStatus | None = None,
) -> MissionPage:
    """The key's missions, newest first, ``limit`` from ``offset``; optionally one status."""
    conditions = [_owned_by(api_key)]
    if status is not None:
        conditions.append(Mission.status == status)
    query = (
        select(Mission)
        .where(*conditions)
        .order_by(Mission.created_at.desc(), Mission.id.desc())
        .limit(limit)
        .offset(offset)
    )
    total = session.scalar(select(func.count()).select_from(Mission).where(*conditions)) or 0
    return MissionPage(items=list(session.scalars(query)), total=total, limit=limit, offset=offset)


def _owned_by(api_key: str | None) -> Any:
    owner = hash_key(api_key)
    return Mission.owner.is_(None) if owner is None else Mission.owner == owner


def locked_mission(session: Session, mission_id: str) -> Mission:
    """The mission, its row locked for the transaction (NotFoundError when there is none)."""
    query = select(Mission).where(Mission.id == mission_id).with_for_update()
    mission = session.scalars(query).one_or_none()
    if mission is None:
        raise NotFoundError(f"no mission {mission_id}")
    return mission


def set_status(
    session: Session, mission_id: str, status: MissionStatus, reason: str | None = None
) -> bool:
    """Move a mission to ``status`` (with ``reason``; required for failed). Returns False when
    it is already there (a redelivered task), raises ``TransitionError`` for a move the life
    cycle forbids, e.g. out of done/failed/cancelled. Atomic on SQLite and PostgreSQL alike:
    of two workers racing to move the same mission, one wins and the other sees its result."""
    for _ in range(5):
        current = session.scalar(select(Mission.status).where(Mission.id == mission_id))
        if current is None:
            raise NotFoundError(f"no mission {mission_id}")
        if current == status:
            return False
        _check_transition(mission_id, current, status, reason)
        # Compare-and-set: a concurrent change of status makes this match no row.
        outcome = session.execute(
            update(Mission)
            .where(Mission.id == mission_id, Mission.status == current)
            .values(status=status, reason=reason, updated_at=db_now(session))
        )
        if getattr(outcome, "rowcount", 0) == 1:
            record_event(session, mission_id, "status", {"status": status.value, "reason": reason})
            return True
    raise TransitionError(f"mission {mission_id}: its status keeps changing concurrently")


def _check_transition(
    mission_id: str, current: MissionStatus, status: MissionStatus, reason: str | None
) -> None:
    allowed = TRANSITIONS.get(current, frozenset())
    if current not in FINAL_STATES:
        allowed = allowed | {MissionStatus.failed, MissionStatus.cancelled}
    if status not in allowed:
        raise TransitionError(
            f"mission {mission_id} cannot go from {current.value} to {status.value}"
        )
    if status == MissionStatus.failed and not reason:
        raise TransitionError(f"mission {mission_id}: a failure needs a reason")


def request_cancel(session: Session, mission_id: str) -> Mission:
    """Raise the cancel flag the training hooks read (cooperative cancel). A mission in a
    final state is returned unchanged."""
    mission = locked_mission(session, mission_id)
    if mission.status not in FINAL_STATES and not mission.cancel_requested:
        mission.cancel_requested = True
        session.flush()
        record_event(session, mission_id, "cancel", {"requested": True})
    return mission


def cancel_requested(session: Session, mission_id: str) -> bool:
    """Whether a cancel was requested (one cheap query, for the training hooks)."""
    query = select(Mission.cancel_requested).where(Mission.id == mission_id)
    return bool(session.scalar(query))


def halted(session: Session, mission_id: str) -> bool:
    """Whether a mission's running jobs should stop: cancel requested, or it already ended
    (another job failed), or it is gone."""
    query = select(Mission.cancel_requested, Mission.status).where(Mission.id == mission_id)
    row = session.execute(query).one_or_none()
    return row is None or bool(row[0]) or row[1] in FINAL_STATES


def set_news(session: Session, mission_id: str, news: str) -> None:
    """Progress of a mission between its transitions (the hand-over repair's), in its
    ``reason`` and the event feed; nothing once it ended."""
    changed = session.execute(
        update(Mission)
        .where(Mission.id == mission_id, Mission.status.not_in(FINAL_STATES))
        .values(reason=news)
    )
    if getattr(changed, "rowcount", 0):
        record_event(session, mission_id, "news", {"reason": news})


def set_plan(
    session: Session, mission_id: str, plan: dict[str, Any], plan_image: str | None = None
) -> None:
    """Store the plan summary (and the path of its picture)."""
    mission = locked_mission(session, mission_id)
    mission.plan = plan
    mission.plan_image = plan_image
    session.flush()


def set_result(
    session: Session, mission_id: str, evaluation: dict[str, Any], bundle_path: str
) -> None:
    """Store the whole-mission evaluation (``MissionEvaluation.to_json()``) and the bundle."""
    mission = locked_mission(session, mission_id)
    mission.evaluation = evaluation
    mission.bundle_path = bundle_path
    session.flush()


def claim_step(
    session: Session,
    mission_id: str,
    current: MissionStatus,
    to: MissionStatus,
    counter: Literal["plan_attempts", "assembly_attempts"],
) -> int | None:
    """Move the mission from ``current`` to ``to`` and count an attempt of the step in the
    same compare-and-set; the attempt number, or None when the mission was not ``current``
    (another worker has it, or it moved on)."""
    column = getattr(Mission, counter)
    row = session.execute(
        update(Mission)
        .where(Mission.id == mission_id, Mission.status == current)
        .values({"status": to, "updated_at": db_now(session), counter: column + 1})
        .returning(column)
    ).one_or_none()
    if row is None:
        return None
    record_event(session, mission_id, "status", {"status": to.value, "reason": None})
    return int(row[0])


def holds_step(
    session: Session,
    mission_id: str,
    status: MissionStatus,
    counter: Literal["plan_attempts", "assembly_attempts"],
    attempt: int,
) -> bool:
    """Whether attempt ``attempt`` of the step still owns the mission (still ``status``, no
    later attempt claimed it); refreshes its heartbeat in the same UPDATE, which locks the row
    for the rest of the transaction, so the writes that follow are fenced."""
    outcome = session.execute(
        update(Mission)
        .where(
            Mission.id == mission_id,
            Mission.status == status,
            getattr(Mission, counter) == attempt,
        )
        .values(updated_at=db_now(session))
        .execution_options(synchronize_session=False)
    )
    return getattr(outcome, "rowcount", 0) == 1


def requeue_mission(
    session: Session, mission_id: str, current: MissionStatus, back: MissionStatus, reason: str
) -> bool:
    """Put a mission whose step failed for a passing reason back to ``back`` (planning ->
    queued, evaluating -> training) to be tried again; False when it is no longer
    ``current``."""
    outcome = session.execute(
        update(Mission)
        .where(Mission.id == mission_id, Mission.status == current)
        .values(status=back, reason=reason, updated_at=db_now(session))
    )
    if getattr(outcome, "rowcount", 0) != 1:
        return False
    record_event(session, mission_id, "status", {"status": back.value, "reason": reason})
    return True


def set_repairs(
    session: Session, mission_id: str, evaluation: dict[str, Any], repairs: list[dict[str, Any]]
) -> None:
    """Store the evaluation of the results kept so far and the repair rounds judged so far
    (``RepairRound.to_json()``), between rounds of hand-over repair."""
    mission = locked_mission(session, mission_id)
    mission.evaluation = evaluation
    mission.repairs = repairs
    mission.assembly_attempts = 0  # the next round's assembly counts its own attempts
    session.flush()


def touch_mission(session: Session, mission_id: str) -> None:
    """Refresh ``updated_at`` (the heartbeat of a mission being planned or assembled)."""
    session.execute(
        update(Mission)
        .where(Mission.id == mission_id)
        .values(updated_at=db_now(session))
        .execution_options(synchronize_session=False)
    )
