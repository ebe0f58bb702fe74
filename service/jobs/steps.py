"""The work of each Celery task as a plain function: plan a mission, train one sub-task,
assemble the bundle. ``service.jobs.tasks`` wraps them; tests call them directly.

The database is the source of truth. Every step first claims its piece of work with a
compare-and-set (queued -> planning, job queued -> running, training -> evaluating), so a
redelivered or duplicated task does nothing, and a finished one is never redone; a training
resumes from its checkpoints. Any error ends the mission ``failed`` with a reason (known
errors with their own message), never silently.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy.orm import Session

from planner.errors import LtlnavError, PlanningError
from planner.guidance import Guide
from planner.plan import MissionPlan
from service import repository
from service.db import Database
from service.jobs.progress import JobMonitor, mission_heartbeat
from service.models import JobStatus, MissionStatus
from service.settings import Settings
from workers.mission import MissionSpec, parse_mission
from workers.pipeline import finish, plan_for, subtask_jobs

log = logging.getLogger(__name__)


class Dispatch(Protocol):
    """Sends the follow-up tasks (Celery in production, a recorder in tests)."""

    def training(self, mission_id: str, indices: Sequence[int]) -> None:
        """Train the sub-tasks ``indices`` in parallel, then assemble the mission."""

    def train(self, mission_id: str, index: int) -> None:
        """Train one sub-task (outside a chord: it assembles when it finishes last)."""

    def assemble(self, mission_id: str) -> None:
        """Assemble the mission."""

    def plan(self, mission_id: str) -> None:
        """Plan the mission."""


_databases: dict[str, Database] = {}


def database_for(settings: Settings) -> Database:
    """One ``Database`` per URL per process."""
    db = _databases.get(settings.database_url)
    if db is None:
        db = _databases[settings.database_url] = Database(settings.database_url)
    return db


def mission_dir(settings: Settings, mission_id: str) -> Path:
    """``<artifact_dir>/<mission_id>``: plan.json, plan.png, subtask_<k>/, bundle.zip."""
    return settings.artifact_dir / mission_id


def worker_name() -> str:
    """Host and process of this worker (``Job.worker``)."""
    return f"{socket.gethostname()}:{os.getpid()}"


def plan_summary(plan: MissionPlan) -> dict[str, Any]:
    """The stored plan summary (``Mission.plan``)."""
    subtasks = []
    for sub in plan.subtasks:
        length = float(np.sum(np.linalg.norm(np.diff(sub.path, axis=0), axis=1)))
        balls = Guide.from_path(sub.path, plan.r_ball).num_balls
        subtasks.append(
            {
                "index": sub.index,
                "phase": sub.phase,
                "goal": sub.goal,
                "length": length,
                "balls": balls,
            }
        )
    return {
        "automaton_states": plan.nba.num_states,
        "pruned_states": plan.pruned.num_states,
        "prefix_length": float(plan.lasso.prefix_cost),
        "suffix_length": float(plan.lasso.suffix_cost),
        "cost": float(plan.lasso.cost),
        "seconds": float(plan.seconds),
        "subtasks": subtasks,
    }


def fail_mission(db: Database, mission_id: str, reason: str) -> None:
    """Mark the mission failed (nothing when it already ended)."""
    with db.session() as session, suppress(repository.TransitionError):
        repository.set_status(session, mission_id, MissionStatus.failed, reason)


def cancel_mission(db: Database, mission_id: str) -> None:
    """Mark the mission cancelled and its queued jobs too (nothing when it already ended)."""
    with db.session() as session:
        try:
            repository.set_status(
                session, mission_id, MissionStatus.cancelled, "cancelled on request"
            )
        except repository.TransitionError:
            return
        repository.cancel_queued_jobs(session, mission_id)


def describe(error: BaseException) -> str:
    """A user-facing reason: a known error's message, else its type and message."""
    if isinstance(error, LtlnavError):
        return str(error)
    if isinstance(error, SoftTimeLimitExceeded):
        return (
            "ran past the task time limit (LTLNAV_TASK_SOFT_TIME_LIMIT): "
            "lower the training budget or raise the limit"
        )
    return f"{type(error).__name__}: {error}"


@contextmanager
def failing(
    db: Database, mission_id: str, what: str, job: tuple[int, str] | None = None
) -> Iterator[None]:
    """Turn any error of the block into a ``failed`` mission (and job ``(id, worker)``, if
    this worker still holds it) with the reason; re-raise only if that cannot be written."""
    try:
        yield
    except Exception as error:
        log.exception("%s of mission %s failed", what, mission_id)
        reason = f"{what}: {describe(error)}"
        try:
            if job is not None:
                with db.session() as session:
                    if repository.holds_job(session, job[0], job[1]):
                        repository.finish_job(session, job[0], JobStatus.failed, reason=reason)
            fail_mission(db, mission_id, reason)
        except Exception:
            log.exception("could not record the failure of mission %s", mission_id)
            raise error from None


def send(action: Callable[[], None], mission_id: str) -> None:
    """Send follow-up work; a broker outage is logged, not fatal: the state is committed and
    the reconciler sends what is still queued once the broker is back."""
    try:
        action()
    except Exception:
        log.exception("could not send the next task of mission %s; the reconciler will", mission_id)


def _spec(document: dict[str, Any]) -> MissionSpec:
    return parse_mission(document)


def plan_step(settings: Settings, mission_id: str, dispatch: Dispatch) -> str:
    """Plan a queued mission, store the summary, picture and jobs, then send the training.
    Returns what happened (``planned``, ``infeasible``, ``busy``, ...)."""
    db = database_for(settings)
    with db.session() as session:
        mission = repository.get_mission(session, mission_id)
        if mission is None:
            return "missing"
        if mission.status in repository.FINAL_STATES:
            return "final"
        if mission.cancel_requested:
            document = None
        elif mission.status != MissionStatus.queued or not repository.set_status(
            session, mission_id, MissionStatus.planning
        ):
            return "busy"
        document = mission.document
    if document is None:
        cancel_mission(db, mission_id)
        return "cancelled"
    folder = mission_dir(settings, mission_id)
    indices: list[int] = []
    with (
        failing(db, mission_id, "planning"),
        mission_heartbeat(db, mission_id, settings.heartbeat_seconds),
    ):
        spec = _spec(document)
        if spec.training.reward.mode == "g-rrt":
            fail_mission(
                db,
                mission_id,
                "reward mode g-rrt trains one agent for the whole "
                "lasso; the service trains one agent per sub-task: use rrt, "
                "rrt-paper, ned or tl",
            )
            return "failed"
        try:
            plan = plan_for(spec, folder)
        except PlanningError as error:
            fail_mission(db, mission_id, str(error))
            return "infeasible"
        if not plan.subtasks:
            fail_mission(db, mission_id, "the plan has no sub-task to train (no goal region)")
            return "failed"
        image = folder / "plan.png"
        _plot(spec, plan, image)
        jobs = [
            repository.NewJob(
                index=job.subtask,
                budget=job.training.n_timesteps,
                out_dir=str(folder / f"subtask_{job.subtask}"),
            )
            for job in subtask_jobs(spec, plan)
        ]
        with db.session() as session:
            image_path = str(image) if image.is_file() else None
            repository.set_plan(session, mission_id, plan_summary(plan), image_path)
            rows = repository.create_jobs(session, mission_id, jobs)
            indices = [row.index for row in rows]
            try:
                repository.set_status(session, mission_id, MissionStatus.training)
            except repository.TransitionError:  # cancelled while planning
                repository.cancel_queued_jobs(session, mission_id)
                return "final"
    if not indices:  # the guard recorded a failure
        return "failed"
    send(lambda: dispatch.training(mission_id, indices), mission_id)
    return "planned"


def _plot(spec: MissionSpec, plan: MissionPlan, out: Path) -> None:
    """The plan picture (as ``ltlnav plan --plot``); a failure costs the picture only."""
    from planner.plot import plot_plan

    try:
        plot_plan(spec.build_world(), plan, out, title=spec.name)
    except (OSError, ValueError, RuntimeError):
        log.exception("could not draw the plan of %s", out.parent.name)


def train_step(
    settings: Settings, mission_id: str, index: int, dispatch: Dispatch, in_chord: bool
) -> str:
    """Train sub-task ``index`` (resuming from its checkpoints) and record the result; a
    task outside a chord that finishes the last job sends the assembly. Returns what
    happened (``done``, ``cancelled``, ``busy``, ``lost``, ...)."""
    from workers.training import train_subtask

    db = database_for(settings)
    worker = worker_name()
    with db.session() as session:
        action, detail = _claim_training(session, settings, mission_id, index, worker)
        job = repository.get_job(session, mission_id, index)
        job_id, out_dir = (job.id, Path(job.out_dir)) if job is not None else (0, Path())
        document = job.mission.document if job is not None and action == "run" else {}
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
    stopped: str | None = None
    with failing(db, mission_id, f"sub-task {index}", job=(job_id, worker)):
        spec = _spec(document)
        job_spec = subtask_jobs(spec, plan_for(spec, mission_dir(settings, mission_id)))[index]
        monitor = JobMonitor(db, mission_id, job_id, worker, out_dir, settings.heartbeat_seconds)
        with monitor.running():
            result = train_subtask(job_spec, out_dir, monitor.on_progress, monitor.should_stop)
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


def _claim_training(
    session: Session, settings: Settings, mission_id: str, index: int, worker: str
) -> tuple[str, str]:
    """What a training task does with its job: ``run`` (claimed), ``cancel``, ``fail``
    (with the reason), ``done`` (``all`` when every job is), or skip (``missing``, ``final``,
    ``busy``)."""
    mission = repository.get_mission(session, mission_id)
    job = repository.get_job(session, mission_id, index)
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


def assemble_step(settings: Settings, mission_id: str) -> str:
    """Once every job is done: whole-mission rollouts, hand-over repair while the mission is
    below its target (``workers.handover_repair``; its jobs train here, one after the other,
    reporting in the mission's news, and a cancel stops them), ``bundle.zip``, status done.
    Returns what happened (``done``, ``waiting``, ``busy``, ``cancelled``, ...)."""
    from service.jobs.repair import RepairCancelledError, RepairMonitor
    from workers.training import TrainResult

    db = database_for(settings)
    with db.session() as session:
        mission = repository.get_mission(session, mission_id)
        if mission is None:
            return "missing"
        if mission.status in repository.FINAL_STATES:
            return "final"
        cancelled = mission.cancel_requested
        jobs = repository.mission_jobs(session, mission_id)
        if not cancelled and (not jobs or any(j.status != JobStatus.done for j in jobs)):
            return "waiting"
        if not cancelled and not (
            mission.status == MissionStatus.training
            and repository.set_status(session, mission_id, MissionStatus.evaluating)
        ):
            return "busy"
        document = mission.document
        stored = [job.result or {} for job in jobs]
    if cancelled:
        cancel_mission(db, mission_id)
        return "cancelled"
    with (
        failing(db, mission_id, "assembly"),
        mission_heartbeat(db, mission_id, settings.heartbeat_seconds),
    ):
        results = [TrainResult.from_json(doc) for doc in stored]
        spec = _spec(document)
        folder = mission_dir(settings, mission_id)
        plan = plan_for(spec, folder)
        monitor = RepairMonitor(db, mission_id, settings.heartbeat_seconds)
        try:
            out = finish(spec, plan, results, folder, monitor.run)
        except RepairCancelledError:
            cancelled = True
        else:
            evaluation = out.evaluation
            with db.session() as session:
                repository.set_result(session, mission_id, evaluation.to_json(), str(out.bundle))
                repository.record_evaluation(
                    session,
                    mission_id,
                    None,
                    steps=sum(r.steps for r in out.results),
                    episodes=evaluation.episodes,
                    success_rate=evaluation.success_rate,
                )
                repository.set_status(session, mission_id, MissionStatus.done)
            return "done"
    if cancelled:  # the repair's checkpoints stay: assembling again would resume them
        cancel_mission(db, mission_id)
        return "cancelled"
    return "failed"
