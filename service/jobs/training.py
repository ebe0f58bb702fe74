"""The training step of one job: claim it, train it through the mission's run with a
``JobMonitor`` as its hooks, record the result; the last job outside a chord sends the
assembly.

A job is claimed with a compare-and-set (queued -> running), so a redelivered or duplicated
task does nothing, and a finished one is never redone; a training resumes from its
checkpoints.
"""

from __future__ import annotations

from sqlalchemy.orm import Session

from service import repository
from service.jobs.common import (
    Dispatch,
    cancel_mission,
    database_for,
    fail_mission,
    failing,
    open_run,
    send,
    worker_name,
)
from service.jobs.progress import JobMonitor
from service.models import JobStatus
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
    worker = worker_name()
    with db.session() as session:
        action, detail = _claim(session, settings, mission_id, index, repair_round, worker)
        row = repository.get_job(session, mission_id, index, repair_round)
        job_id = row.id if row is not None else 0
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
    with failing(db, mission_id, what, job=(job_id, worker)):
        run = open_run(settings, mission_id, document)
        job = SubtaskJob.from_json(stored) if stored is not None else run.jobs()[index]
        monitor = JobMonitor(db, mission_id, job_id, worker, settings.heartbeat_seconds)
        with monitor.running():
            result = run.train(job, monitor)
        monitor.flush()
        with db.session() as session:
            if not repository.holds_job(session, job_id, worker):
                return "lost"
            if result.stopped == "cancelled":
                reason = "stopped: mission cancelled or ended"
                repository.finish_job(session, job_id, JobStatus.cancelled, reason=reason)
            else:
                repository.finish_job(session, job_id, JobStatus.done, result.to_json())
            all_done = _all_done(session, mission_id)
        stopped = result.stopped
    if stopped is None:  # the guard recorded a failure
        return "failed"
    if stopped == "cancelled":
        if monitor.cancelled.is_set():
            cancel_mission(db, mission_id)
        return "cancelled"
    if all_done and not in_chord:
        send(lambda: dispatch.assemble(mission_id), mission_id)
    return "done"


def _claim(
    session: Session,
    settings: Settings,
    mission_id: str,
    index: int,
    repair_round: int,
    worker: str,
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
    if job.attempts >= settings.max_attempts:
        reason = f"sub-task {index}: gave up after {job.attempts} attempts"
        repository.finish_job(session, job.id, JobStatus.failed, reason=reason)
        return "fail", reason
    if repository.claim_job(session, job.id, worker) is None:
        return "busy", ""
    return "run", ""


def _all_done(session: Session, mission_id: str) -> bool:
    jobs = repository.mission_jobs(session, mission_id)
    return bool(jobs) and all(job.status == JobStatus.done for job in jobs)
