"""The training step of one job: claim it, train it through the mission's run with a
``JobMonitor`` as its hooks, record the result; the last job outside a chord sends the
assembly.

A job is claimed with a compare-and-set (queued -> running) that counts the attempt, so a
redelivered or duplicated task does nothing, a finished one is never redone, and the attempt
number fences every write of this attempt; a training resumes from its checkpoints. A
transient failure (full disk, database or broker gone, the soft time limit of a job with a
checkpoint) puts the job back after a backoff; a permanent one fails the mission at once.
"""

from __future__ import annotations

from datetime import timedelta

from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy.orm import Session

from service import repository
from service.db import Database
from service.jobs.common import (
    Dispatch,
    backoff_seconds,
    cancel_mission,
    database_for,
    describe,
    fail_mission,
    failing,
    is_transient,
    open_run,
    send,
    worker_name,
)
from service.jobs.progress import JobMonitor
from service.models import JobStatus, MissionStatus
from service.settings import Settings
from workers.jobs import SubtaskJob


def train_step(
    settings: Settings,
    mission_id: str,
    index: int,
    dispatch: Dispatch,
    in_chord: bool,
    repair_round: int = 0,
) -> str:
    """Train sub-task ``index`` in round ``repair_round`` (resuming from its checkpoints) and
    record the result; a task outside a chord that finishes the last job sends the assembly.
    Returns what happened (``done``, ``cancelled``, ``busy``, ``lost``, ...)."""
    db = database_for(settings)
    with db.session() as session:
        action, detail = _claim(session, settings, mission_id, index, repair_round)
        row = repository.get_job(session, mission_id, index, repair_round)
        job_id, token = (row.id, row.attempts) if row is not None else (0, 0)
        stored = row.spec if row is not None else None
        document = row.mission.document if row is not None and action == "run" else {}
    if action == "cancel":
        cancel_mission(db, mission_id)
        return "cancelled"
    if action == "fail":
        fail_mission(db, mission_id, detail)
        return "failed"
    if action == "done":
        if detail == "all" and not in_chord:
            send(lambda: dispatch.assemble(mission_id), mission_id)
        return "done"
    if action != "run":
        return action
    what = f"sub-task {index}" + (f" (hand-over repair {repair_round})" if repair_round else "")
    stopped: str | None = None

    def retry(error: BaseException) -> bool:
        again = (mission_id, index, repair_round)
        return _retry_later(settings, dispatch, job_id, token, again, error)

    with failing(db, mission_id, what, job=(job_id, token), retry=retry):
        run = open_run(settings, mission_id, document)
        job = SubtaskJob.from_json(stored) if stored is not None else run.jobs()[index]
        monitor = JobMonitor(db, mission_id, job_id, token, settings.heartbeat_seconds)
        with monitor.running():
            result = run.train(job, monitor)
        monitor.flush()
        with db.session() as session:
            if not repository.holds_job(session, job_id, token):
                return "lost"
            if result.stopped == "cancelled":
                reason = "stopped: mission cancelled or ended"
                repository.finish_job(session, job_id, JobStatus.cancelled, reason=reason)
            else:
                repository.finish_job(session, job_id, JobStatus.done, result.to_json())
            all_done = _all_done(session, mission_id)
        stopped = result.stopped
    if stopped is None:  # the guard recorded a failure, or put the job back for later
        return "failed" if _failed(db, mission_id) else "retrying"
    if stopped == "cancelled":
        if monitor.cancelled.is_set():
            cancel_mission(db, mission_id)
        return "cancelled"
    if all_done and not in_chord:
        send(lambda: dispatch.assemble(mission_id), mission_id)
    return "done"


def _retry_later(
    settings: Settings,
    dispatch: Dispatch,
    job_id: int,
    token: int,
    again: tuple[str, int, int],
    error: BaseException,
) -> bool:
    """Put the job back after a transient failure, to start again after a backoff; whether
    the failure was transient (the job's attempt cap still ends a job that keeps failing)."""
    db = database_for(settings)
    with db.session() as session:
        timed_out = isinstance(error, SoftTimeLimitExceeded)
        if timed_out and repository.latest_checkpoint(session, job_id) is None:
            return False  # nothing to resume from: the same run would time out again
        if not (timed_out or is_transient(error)):
            return False
        wait = backoff_seconds(settings, token)
        reason = f"attempt {token} stopped ({describe(error)}); trying again in {wait:.0f} s"
        not_before = repository.db_now(session) + timedelta(seconds=wait)
        if not repository.requeue_job(session, job_id, token, not_before, reason):
            return True  # another attempt owns it now
    mission_id, index, repair_round = again
    send(lambda: dispatch.train(mission_id, index, repair_round, countdown=wait), mission_id)
    return True


def _failed(db: Database, mission_id: str) -> bool:
    with db.session() as session:
        mission = repository.get_mission(session, mission_id)
        return mission is None or mission.status == MissionStatus.failed


def _claim(
    session: Session,
    settings: Settings,
    mission_id: str,
    index: int,
    repair_round: int,
) -> tuple[str, str]:
    """What a training task does with its job: ``run`` (claimed), ``cancel``, ``fail``
    (with the reason), ``done`` (``all`` when every job is), or skip (``missing``, ``final``,
    ``busy``)."""
    mission = repository.get_mission(session, mission_id)
    job = repository.get_job(session, mission_id, index, repair_round)
    if mission is None or job is None:
        return "missing", ""
    if mission.status in repository.FINAL_STATES:
        return "final", ""
    if mission.cancel_requested:
        return "cancel", ""
    if job.status == JobStatus.done:
        return "done", "all" if _all_done(session, mission_id) else ""
    if job.status != JobStatus.queued:
        return "busy", ""
    if job.not_before is not None and job.not_before > repository.db_now(session):
        return "busy", ""  # backing off after a transient failure: its own message comes
    if job.attempts >= settings.max_attempts:
        last = f" (the last: {job.reason})" if job.reason else ""
        reason = (
            f"sub-task {index}: gave up after {job.attempts} attempts{last}; "
            "LTLNAV_MAX_ATTEMPTS sets how many"
        )
        repository.finish_job(session, job.id, JobStatus.failed, reason=reason)
        return "fail", reason
    if repository.claim_job(session, job.id, worker_name()) is None:
        return "busy", ""
    return "run", ""


def _all_done(session: Session, mission_id: str) -> bool:
    jobs = repository.mission_jobs(session, mission_id)
    return bool(jobs) and all(job.status == JobStatus.done for job in jobs)
