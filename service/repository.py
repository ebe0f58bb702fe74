"""Small typed operations on the service's state, shared by the API and the Celery tasks.

Each function works inside the caller's session (``Database.session()``) and flushes but does
not commit, so a caller can group several in one transaction. Missions are scoped by API key:
the API uses ``get_owned_mission`` / ``list_missions``; workers, which hold no key, use
``get_mission``. Status changes and progress also append ``Event`` rows (the SSE feed).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import delete, func, or_, select, update
from sqlalchemy.orm import Session

from planner.errors import LtlnavError
from service.models import (
    Checkpoint,
    Evaluation,
    Event,
    Job,
    JobStatus,
    Mission,
    MissionStatus,
    utcnow,
)

FINAL_STATES = frozenset({MissionStatus.done, MissionStatus.failed, MissionStatus.cancelled})
TRANSITIONS: dict[MissionStatus, frozenset[MissionStatus]] = {
    MissionStatus.queued: frozenset({MissionStatus.planning}),
    MissionStatus.planning: frozenset({MissionStatus.training}),
    MissionStatus.training: frozenset({MissionStatus.evaluating}),
    MissionStatus.evaluating: frozenset({MissionStatus.done}),
}
"""Forward moves; any non-final state may also go to failed or cancelled."""


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


@dataclass(frozen=True)
class NewJob:
    """A sub-task's training job to create."""

    index: int
    budget: int
    out_dir: str


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


def create_mission(
    session: Session, name: str, document: dict[str, Any], api_key: str | None
) -> Mission:
    """A new queued mission owned by ``api_key`` (None: the open API)."""
    mission = Mission(name=name, document=document, owner=hash_key(api_key))
    session.add(mission)
    session.flush()
    record_event(session, mission.id, "status", {"status": mission.status.value, "reason": None})
    return mission


def get_mission(session: Session, mission_id: str) -> Mission | None:
    """The mission with this id whoever owns it (for workers), with its jobs."""
    return session.get(Mission, mission_id)


def get_owned_mission(session: Session, mission_id: str, api_key: str | None) -> Mission | None:
    """The mission if ``api_key`` created it, else None (the API answers 404 alike)."""
    query = select(Mission).where(Mission.id == mission_id, _owned_by(api_key))
    return session.scalars(query).one_or_none()


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


def _locked_mission(session: Session, mission_id: str) -> Mission:
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
            .values(status=status, reason=reason)
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
    mission = _locked_mission(session, mission_id)
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


def set_plan(
    session: Session, mission_id: str, plan: dict[str, Any], plan_image: str | None = None
) -> None:
    """Store the plan summary (and the path of its picture)."""
    mission = _locked_mission(session, mission_id)
    mission.plan = plan
    mission.plan_image = plan_image
    session.flush()


def set_result(
    session: Session, mission_id: str, evaluation: dict[str, Any], bundle_path: str
) -> None:
    """Store the whole-mission evaluation (``MissionEvaluation.to_json()``) and the bundle."""
    mission = _locked_mission(session, mission_id)
    mission.evaluation = evaluation
    mission.bundle_path = bundle_path
    session.flush()


def create_jobs(session: Session, mission_id: str, jobs: Sequence[NewJob]) -> list[Job]:
    """The mission's jobs, created on the first call; a repeated call (redelivered planning
    task) returns the existing ones untouched."""
    _locked_mission(session, mission_id)
    existing = mission_jobs(session, mission_id)
    if existing:
        return existing
    rows = [
        Job(mission_id=mission_id, index=j.index, budget=j.budget, out_dir=j.out_dir) for j in jobs
    ]
    session.add_all(rows)
    session.flush()
    return sorted(rows, key=lambda job: job.index)


def mission_jobs(session: Session, mission_id: str) -> list[Job]:
    """A mission's jobs by sub-task index."""
    query = select(Job).where(Job.mission_id == mission_id).order_by(Job.index)
    return list(session.scalars(query))


def get_job(session: Session, mission_id: str, index: int) -> Job | None:
    """Sub-task ``index``'s job of a mission."""
    query = select(Job).where(Job.mission_id == mission_id, Job.index == index)
    return session.scalars(query).one_or_none()


def start_job(session: Session, job_id: int, worker: str) -> Job:
    """Mark a job running on ``worker`` (counts an attempt, starts the heartbeat)."""
    job = session.get(Job, job_id, with_for_update=True)
    if job is None:
        raise NotFoundError(f"no job {job_id}")
    now = utcnow()
    job.status = JobStatus.running
    job.worker = worker
    job.attempts = Job.attempts + 1  # in SQL: two concurrent starts both count
    job.heartbeat_at = now
    job.started_at = job.started_at or now
    job.finished_at = None
    session.flush()
    session.refresh(job, ["attempts"])
    record_event(
        session, job.mission_id, "job", {"index": job.index, "status": "running", "worker": worker}
    )
    return job


def heartbeat(session: Session, job_id: int) -> None:
    """Refresh a job's heartbeat (one UPDATE)."""
    session.execute(update(Job).where(Job.id == job_id).values(heartbeat_at=utcnow()))


def record_progress(
    session: Session,
    job_id: int,
    steps_done: int,
    success_rate: float | None = None,
    eta_seconds: float | None = None,
) -> None:
    """Progress of a running job from the (throttled) training hooks; refreshes the heartbeat
    and appends a ``progress`` event. A None rate keeps the last known one."""
    values: dict[str, Any] = {
        "steps_done": steps_done,
        "eta_seconds": eta_seconds,
        "heartbeat_at": utcnow(),
    }
    if success_rate is not None:
        values["success_rate"] = success_rate
    row = session.execute(
        update(Job).where(Job.id == job_id).values(**values).returning(Job.mission_id, Job.index)
    ).one_or_none()
    if row is None:
        raise NotFoundError(f"no job {job_id}")
    mission_id, index = row
    payload = {"index": index, "steps": steps_done, "success_rate": success_rate}
    record_event(session, mission_id, "progress", {**payload, "eta_seconds": eta_seconds})


def finish_job(
    session: Session,
    job_id: int,
    status: JobStatus,
    result: dict[str, Any] | None = None,
    reason: str | None = None,
) -> Job:
    """End a job: done (with ``TrainResult.to_json()``), failed (with a reason) or cancelled."""
    if status in (JobStatus.queued, JobStatus.running):
        raise TransitionError(f"finish_job takes a final status, not {status.value}")
    if status == JobStatus.failed and not reason:
        raise TransitionError(f"job {job_id}: a failure needs a reason")
    job = session.get(Job, job_id, with_for_update=True)
    if job is None:
        raise NotFoundError(f"no job {job_id}")
    job.status = status
    job.result = result
    job.reason = reason
    job.finished_at = utcnow()
    if result is not None and "steps" in result:
        job.steps_done = int(result["steps"])
    session.flush()
    payload = {"index": job.index, "status": status.value, "reason": reason}
    record_event(session, job.mission_id, "job", payload)
    return job


def record_checkpoint(session: Session, job_id: int, steps: int, path: str) -> Checkpoint:
    """Note a saved checkpoint; saving the same step count again updates its path."""
    query = select(Checkpoint).where(Checkpoint.job_id == job_id, Checkpoint.steps == steps)
    row = session.scalars(query).one_or_none()
    if row is None:
        row = Checkpoint(job_id=job_id, steps=steps, path=path)
        session.add(row)
    else:
        row.path = path
    session.flush()
    return row


def latest_checkpoint(session: Session, job_id: int) -> Checkpoint | None:
    """The job's checkpoint with the most steps (where a redelivered job resumes)."""
    query = (
        select(Checkpoint)
        .where(Checkpoint.job_id == job_id)
        .order_by(Checkpoint.steps.desc())
        .limit(1)
    )
    return session.scalars(query).one_or_none()


def record_evaluation(
    session: Session,
    mission_id: str,
    job_id: int | None,
    steps: int,
    episodes: int,
    success_rate: float,
    mean_return: float | None = None,
) -> Evaluation:
    """A point of a job's learning curve (``job_id``), or a whole-mission evaluation (None)."""
    row = Evaluation(
        mission_id=mission_id,
        job_id=job_id,
        steps=steps,
        episodes=episodes,
        success_rate=success_rate,
        mean_return=mean_return,
    )
    session.add(row)
    session.flush()
    return row


def learning_curve(session: Session, job_id: int) -> list[Evaluation]:
    """A job's evaluations by steps (success rate and return against steps)."""
    query = (
        select(Evaluation)
        .where(Evaluation.job_id == job_id)
        .order_by(Evaluation.steps, Evaluation.id)
    )
    return list(session.scalars(query))


def stale_jobs(
    session: Session, stale_after_seconds: float, now: datetime | None = None
) -> list[Job]:
    """Running jobs whose heartbeat is older than ``stale_after_seconds`` (dead workers)."""
    cutoff = (now or utcnow()) - timedelta(seconds=stale_after_seconds)
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
    cutoff = (now or utcnow()) - timedelta(seconds=stale_after_seconds)
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
            payload = {"index": job.index, "status": "queued", "reason": "stale heartbeat"}
            record_event(session, job.mission_id, "job", payload)
            claimed.append(job)
    return claimed


def missions_ready_to_assemble(session: Session, idle_seconds: float) -> list[Mission]:
    """Missions still training whose jobs are all done, the last more than ``idle_seconds``
    ago: their chord callback was lost; assemble them from database state."""
    cutoff = utcnow() - timedelta(seconds=idle_seconds)
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


def claim_job(session: Session, job_id: int, worker: str) -> Job | None:
    """Start a queued job on ``worker`` (as ``start_job``) if it is still queued; None when
    another worker holds it or it has finished (a duplicate or redelivered task)."""
    now = utcnow()
    outcome = session.execute(
        update(Job)
        .where(Job.id == job_id, Job.status == JobStatus.queued)
        .values(
            status=JobStatus.running,
            worker=worker,
            attempts=Job.attempts + 1,
            heartbeat_at=now,
            started_at=func.coalesce(Job.started_at, now),
            finished_at=None,
        )
        .execution_options(synchronize_session=False)
    )
    if getattr(outcome, "rowcount", 0) != 1:
        return None
    job = session.get(Job, job_id, populate_existing=True)
    assert job is not None
    record_event(
        session, job.mission_id, "job", {"index": job.index, "status": "running", "worker": worker}
    )
    return job


def holds_job(session: Session, job_id: int, worker: str, beat: bool = False) -> bool:
    """Whether ``worker`` still runs the job (the reconciler did not hand it to another); with
    ``beat`` its heartbeat is refreshed in the same statement."""
    condition = (Job.id == job_id, Job.status == JobStatus.running, Job.worker == worker)
    if beat:
        outcome = session.execute(
            update(Job)
            .where(*condition)
            .values(heartbeat_at=utcnow())
            .execution_options(synchronize_session=False)
        )
        return getattr(outcome, "rowcount", 0) == 1
    return session.scalar(select(func.count()).select_from(Job).where(*condition)) == 1


def drop_evaluations_after(session: Session, job_id: int, steps: int) -> None:
    """Delete a job's curve points beyond ``steps`` (a resumed job redoes those steps)."""
    session.execute(delete(Evaluation).where(Evaluation.job_id == job_id, Evaluation.steps > steps))


def touch_mission(session: Session, mission_id: str) -> None:
    """Refresh ``updated_at`` (the heartbeat of a mission being planned or assembled)."""
    session.execute(
        update(Mission)
        .where(Mission.id == mission_id)
        .values(updated_at=utcnow())
        .execution_options(synchronize_session=False)
    )


def _claim_mission(
    session: Session, mission: Mission, status: MissionStatus, to: MissionStatus | None = None
) -> bool:
    """Compare-and-set on (status, updated_at): of several reconcilers one wins. Moves the
    mission back to ``to`` when given (a reconcile-only move, not in ``TRANSITIONS``)."""
    values: dict[str, Any] = {"updated_at": utcnow()}
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
    cutoff = utcnow() - timedelta(seconds=seconds)
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
    cutoff = utcnow() - timedelta(seconds=idle_seconds)
    return [
        m
        for m in missions_ready_to_assemble(session, idle_seconds)
        if m.updated_at < cutoff and _claim_mission(session, m, MissionStatus.training)
    ]


def claim_queued_jobs(session: Session, older_than_seconds: float) -> list[Job]:
    """Queued jobs of training missions, neither the mission nor the job touched for
    ``older_than_seconds``; each claimed by refreshing its ``heartbeat_at``."""
    cutoff = utcnow() - timedelta(seconds=older_than_seconds)
    query = (
        select(Job)
        .join(Mission, Mission.id == Job.mission_id)
        .where(
            Job.status == JobStatus.queued,
            Mission.status == MissionStatus.training,
            Mission.updated_at < cutoff,
            or_(Job.heartbeat_at.is_(None), Job.heartbeat_at < cutoff),
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
            .values(heartbeat_at=utcnow())
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


def cancel_queued_jobs(session: Session, mission_id: str) -> None:
    """Mark a mission's queued jobs cancelled (their tasks then do nothing)."""
    for job in mission_jobs(session, mission_id):
        if job.status == JobStatus.queued:
            finish_job(session, job.id, JobStatus.cancelled, reason="mission cancelled")
