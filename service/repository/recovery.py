"""What the reconciler claims: stale jobs, stalled missions, lost messages and callbacks.

Every claim is a compare-and-set, so of several reconcilers one wins each piece of work."""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session

from service.models import (
    Job,
    JobStatus,
    Mission,
    MissionStatus,
)
from service.repository.clock import db_now
from service.repository.events import record_event
from service.repository.jobs import cancel_queued_jobs
from service.repository.missions import FINAL_STATES, TransitionError, set_status


def stale_jobs(
    session: Session, stale_after_seconds: float, now: datetime | None = None
) -> list[Job]:
    """Running jobs whose heartbeat is older than ``stale_after_seconds`` (dead workers)."""
    cutoff = (now or db_now(session)) - timedelta(seconds=stale_after_seconds)
    query = (
        select(Job)
        .where(Job.status == JobStatus.running, Job.heartbeat_at < cutoff)
        .order_by(Job.heartbeat_at)
    )
    return list(session.scalars(query))


def reclaim_stale_jobs(
    session: Session, stale_after_seconds: float, now: datetime | None = None
) -> list[Job]:
    """Put stale jobs back to queued, each claimed by a conditional UPDATE so that of two
    reconcilers only one re-enqueues a job. Returns the jobs this call claimed."""
    cutoff = (now or db_now(session)) - timedelta(seconds=stale_after_seconds)
    claimed: list[Job] = []
    for job in stale_jobs(session, stale_after_seconds, now):
        outcome = session.execute(
            update(Job)
            .where(Job.id == job.id, Job.status == JobStatus.running, Job.heartbeat_at < cutoff)
            .values(status=JobStatus.queued, worker=None)
            .execution_options(synchronize_session=False)
        )
        if getattr(outcome, "rowcount", 0) == 1:
            session.refresh(job)
            payload = {
                "index": job.index,
                "round": job.repair_round,
                "status": "queued",
                "reason": "stale heartbeat",
            }
            record_event(session, job.mission_id, "job", payload)
            claimed.append(job)
    return claimed


def missions_ready_to_assemble(session: Session, idle_seconds: float) -> list[Mission]:
    """Missions still training whose jobs are all done, the last more than ``idle_seconds``
    ago: their chord callback was lost; assemble them from database state."""
    cutoff = db_now(session) - timedelta(seconds=idle_seconds)
    jobs = select(Job.id).where(Job.mission_id == Mission.id)
    unfinished = jobs.where(Job.status != JobStatus.done)
    recent = jobs.where(Job.finished_at >= cutoff)
    query = (
        select(Mission)
        .where(
            Mission.status == MissionStatus.training,
            jobs.exists(),
            ~unfinished.exists(),
            ~recent.exists(),
        )
        .order_by(Mission.updated_at)
    )
    return list(session.scalars(query))


def _claim_mission(
    session: Session, mission: Mission, status: MissionStatus, to: MissionStatus | None = None
) -> bool:
    """Compare-and-set on (status, updated_at): of several reconcilers one wins. Moves the
    mission back to ``to`` when given (a reconcile-only move, not in ``TRANSITIONS``)."""
    values: dict[str, Any] = {"updated_at": db_now(session)}
    if to is not None:
        values["status"] = to
    outcome = session.execute(
        update(Mission)
        .where(
            Mission.id == mission.id,
            Mission.status == status,
            Mission.updated_at == mission.updated_at,
        )
        .values(**values)
        .execution_options(synchronize_session=False)
    )
    won = getattr(outcome, "rowcount", 0) == 1
    if won:
        session.refresh(mission)
    if won and to is not None:
        reason = f"{status.value} stalled: its worker stopped"
        record_event(session, mission.id, "status", {"status": to.value, "reason": reason})
    return won


def _older(session: Session, status: MissionStatus, seconds: float) -> list[Mission]:
    cutoff = db_now(session) - timedelta(seconds=seconds)
    query = select(Mission).where(Mission.status == status, Mission.updated_at < cutoff)
    return list(session.scalars(query.order_by(Mission.updated_at)))


def reclaim_stalled_missions(session: Session, stale_after_seconds: float) -> list[Mission]:
    """Missions planning or evaluating whose heartbeat (``updated_at``) is older than
    ``stale_after_seconds``: moved back to queued / training, claimed by compare-and-set.
    Returns those this call claimed (their task must be sent again)."""
    moves = {
        MissionStatus.planning: MissionStatus.queued,
        MissionStatus.evaluating: MissionStatus.training,
    }
    claimed: list[Mission] = []
    for status, back in moves.items():
        for mission in _older(session, status, stale_after_seconds):
            if _claim_mission(session, mission, status, back):
                claimed.append(mission)
    return claimed


def claim_queued_missions(session: Session, older_than_seconds: float) -> list[Mission]:
    """Queued missions untouched for ``older_than_seconds``, each claimed (its ``updated_at``
    refreshed) so that one reconciler sends it again and not before that long again."""
    return [
        m
        for m in _older(session, MissionStatus.queued, older_than_seconds)
        if _claim_mission(session, m, MissionStatus.queued)
    ]


def claim_assemblies(session: Session, idle_seconds: float) -> list[Mission]:
    """``missions_ready_to_assemble`` untouched for ``idle_seconds``, each claimed for one
    reconciler (as above): sent once per ``idle_seconds`` at most."""
    cutoff = db_now(session) - timedelta(seconds=idle_seconds)
    return [
        m
        for m in missions_ready_to_assemble(session, idle_seconds)
        if m.updated_at < cutoff and _claim_mission(session, m, MissionStatus.training)
    ]


def claim_queued_jobs(session: Session, older_than_seconds: float) -> list[Job]:
    """Queued jobs of training missions, neither the mission nor the job touched for
    ``older_than_seconds``; each claimed by refreshing its ``heartbeat_at``."""
    age = timedelta(seconds=older_than_seconds)
    cutoff = db_now(session) - age
    query = (
        select(Job)
        .join(Mission, Mission.id == Job.mission_id)
        .where(
            Job.status == JobStatus.queued,
            Mission.status == MissionStatus.training,
            Mission.updated_at < cutoff,
            or_(Job.heartbeat_at.is_(None), Job.heartbeat_at < cutoff),
            or_(Job.not_before.is_(None), Job.not_before <= cutoff + age),
        )
        .order_by(Job.id)
    )
    claimed: list[Job] = []
    for job in session.scalars(query):
        seen = job.heartbeat_at
        same = Job.heartbeat_at.is_(None) if seen is None else Job.heartbeat_at == seen
        outcome = session.execute(
            update(Job)
            .where(Job.id == job.id, Job.status == JobStatus.queued, same)
            .values(heartbeat_at=db_now(session))
            .execution_options(synchronize_session=False)
        )
        if getattr(outcome, "rowcount", 0) == 1:
            claimed.append(job)
    return claimed


def cancel_idle_missions(session: Session) -> list[str]:
    """Missions with a cancel request and no running job: cancelled now, their queued jobs
    too (a running job's own hook cancels its mission when it stops)."""
    running = select(Job.id).where(Job.mission_id == Mission.id, Job.status == JobStatus.running)
    query = select(Mission.id).where(
        Mission.cancel_requested.is_(True),
        Mission.status.not_in(list(FINAL_STATES)),
        ~running.exists(),
    )
    done: list[str] = []
    for mission_id in list(session.scalars(query)):
        try:
            set_status(session, mission_id, MissionStatus.cancelled, "cancelled on request")
        except TransitionError:
            continue
        cancel_queued_jobs(session, mission_id)
        done.append(mission_id)
    return done
