"""Sub-task jobs: creation, claims by workers, progress, checkpoints and learning curves."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.orm import Session

from service.models import (
    Checkpoint,
    Evaluation,
    Job,
    JobStatus,
)
from service.repository.clock import db_now
from service.repository.events import record_event
from service.repository.missions import NotFoundError, TransitionError, locked_mission


@dataclass(frozen=True)
class NewJob:
    """A sub-task's training job to create (``repair_round`` > 0: a hand-over repair, with
    its ``SubtaskJob.to_json()`` as ``spec``)."""

    index: int
    budget: int
    out_dir: str
    repair_round: int = 0
    spec: dict[str, Any] | None = None


def create_jobs(
    session: Session, mission_id: str, jobs: Sequence[NewJob], repair_round: int = 0
) -> list[Job]:
    """The mission's jobs of round ``repair_round``, created on the first call; a repeated
    call (a redelivered task) returns the existing ones untouched."""
    locked_mission(session, mission_id)
    existing = mission_jobs(session, mission_id, repair_round)
    if existing:
        return existing
    rows = [
        Job(
            mission_id=mission_id,
            index=j.index,
            budget=j.budget,
            out_dir=j.out_dir,
            repair_round=repair_round,
            spec=j.spec,
        )
        for j in jobs
    ]
    session.add_all(rows)
    session.flush()
    return sorted(rows, key=lambda job: job.index)


def mission_jobs(session: Session, mission_id: str, repair_round: int | None = None) -> list[Job]:
    """A mission's jobs by round and sub-task index (only round ``repair_round`` if given)."""
    query = select(Job).where(Job.mission_id == mission_id)
    if repair_round is not None:
        query = query.where(Job.repair_round == repair_round)
    return list(session.scalars(query.order_by(Job.repair_round, Job.index)))


def get_job(session: Session, mission_id: str, index: int, repair_round: int = 0) -> Job | None:
    """Sub-task ``index``'s job of a mission in round ``repair_round``."""
    query = select(Job).where(
        Job.mission_id == mission_id, Job.index == index, Job.repair_round == repair_round
    )
    return session.scalars(query).one_or_none()


def start_job(session: Session, job_id: int, worker: str) -> Job:
    """Mark a job running on ``worker`` (counts an attempt, starts the heartbeat)."""
    job = session.get(Job, job_id, with_for_update=True)
    if job is None:
        raise NotFoundError(f"no job {job_id}")
    now = db_now(session)
    job.status = JobStatus.running
    job.worker = worker
    job.attempts = Job.attempts + 1  # in SQL: two concurrent starts both count
    job.heartbeat_at = now
    job.started_at = job.started_at or now
    job.finished_at = None
    session.flush()
    session.refresh(job, ["attempts"])
    record_event(session, job.mission_id, "job", _job_payload(job, "running", worker=worker))
    return job


def _job_payload(job: Job, status: str, **more: Any) -> dict[str, Any]:
    """A ``job`` event's payload: the job's sub-task and round, its new status, ``more``."""
    return {"index": job.index, "round": job.repair_round, "status": status, **more}


def claim_job(session: Session, job_id: int, worker: str) -> Job | None:
    """Start a queued job on ``worker`` (as ``start_job``) if it is still queued; None when
    another worker holds it or it has finished (a duplicate or redelivered task). The claim
    counts an attempt in the same compare-and-set: the returned job's ``attempts`` is this
    attempt's fencing token (``holds_job``)."""
    now = db_now(session)
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
    record_event(session, job.mission_id, "job", _job_payload(job, "running", worker=worker))
    return job


def holds_job(session: Session, job_id: int, token: int) -> bool:
    """Whether the attempt with fencing ``token`` still runs the job (no later claim, no
    reclaim by the reconciler). It refreshes the heartbeat in the same UPDATE, which also
    locks the row for the rest of the transaction: a write made after a True in the same
    transaction cannot interleave with a reclaim."""
    outcome = session.execute(
        update(Job)
        .where(Job.id == job_id, Job.status == JobStatus.running, Job.attempts == token)
        .values(heartbeat_at=db_now(session))
        .execution_options(synchronize_session=False)
    )
    return getattr(outcome, "rowcount", 0) == 1


def requeue_job(
    session: Session, job_id: int, token: int, not_before: datetime, reason: str
) -> bool:
    """Put the job attempt ``token`` holds back to queued, to start again not before
    ``not_before`` (a transient failure); False when the attempt no longer holds it."""
    outcome = session.execute(
        update(Job)
        .where(Job.id == job_id, Job.status == JobStatus.running, Job.attempts == token)
        .values(status=JobStatus.queued, worker=None, not_before=not_before, reason=reason)
        .execution_options(synchronize_session=False)
    )
    if getattr(outcome, "rowcount", 0) != 1:
        return False
    job = session.get(Job, job_id, populate_existing=True)
    assert job is not None
    record_event(session, job.mission_id, "job", _job_payload(job, "queued", reason=reason))
    return True


def heartbeat(session: Session, job_id: int) -> None:
    """Refresh a job's heartbeat (one UPDATE)."""
    session.execute(update(Job).where(Job.id == job_id).values(heartbeat_at=db_now(session)))


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
        "heartbeat_at": db_now(session),
    }
    if success_rate is not None:
        values["success_rate"] = success_rate
    row = session.execute(
        update(Job)
        .where(Job.id == job_id)
        .values(**values)
        .returning(Job.mission_id, Job.index, Job.repair_round)
    ).one_or_none()
    if row is None:
        raise NotFoundError(f"no job {job_id}")
    mission_id, index, repair_round = row
    payload = {
        "index": index,
        "round": repair_round,
        "steps": steps_done,
        "success_rate": success_rate,
    }
    record_event(session, mission_id, "progress", {**payload, "eta_seconds": eta_seconds})


def record_evaluating(session: Session, job_id: int, what: str) -> None:
    """A running job's training has ended and it runs the evaluation ``what``
    (``TrainingHooks.evaluating``): shown as its reason, its ETA cleared; refreshes the
    heartbeat and appends a ``progress`` event."""
    row = session.execute(
        update(Job)
        .where(Job.id == job_id)
        .values(reason=what, eta_seconds=None, heartbeat_at=db_now(session))
        .returning(Job.mission_id, Job.index, Job.repair_round)
    ).one_or_none()
    if row is None:
        raise NotFoundError(f"no job {job_id}")
    mission_id, index, repair_round = row
    payload = {"index": index, "round": repair_round, "evaluating": what}
    record_event(session, mission_id, "progress", payload)


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
    job.finished_at = db_now(session)
    if result is not None and "steps" in result:
        job.steps_done = int(result["steps"])
    session.flush()
    record_event(session, job.mission_id, "job", _job_payload(job, status.value, reason=reason))
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


def drop_evaluations_after(session: Session, job_id: int, steps: int) -> None:
    """Delete a job's curve points beyond ``steps`` (a resumed job redoes those steps)."""
    session.execute(delete(Evaluation).where(Evaluation.job_id == job_id, Evaluation.steps > steps))


def cancel_queued_jobs(session: Session, mission_id: str) -> None:
    """Mark a mission's queued jobs cancelled (their tasks then do nothing)."""
    for job in mission_jobs(session, mission_id):
        if job.status == JobStatus.queued:
            finish_job(session, job.id, JobStatus.cancelled, reason="mission cancelled")
