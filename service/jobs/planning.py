"""The plan step of a mission: open its run (validate, plan, store ``plan.json``), store the
plan summary, picture and job rows, then send the training of every sub-task.

The step claims the mission with a compare-and-set (queued -> planning) that counts the
attempt, so a redelivered or duplicated task does nothing, and a mission whose planning kept
dying (a crash, out of memory, a kill) fails after ``max_attempts`` with a reason that says
so. A transient error puts it back after a backoff; any other ends the mission ``failed``
with a reason.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from planner.errors import PlanningError
from planner.geometry.polyline import path_length
from planner.guidance import Guide
from planner.plan import MissionPlan
from service import repository
from service.jobs.common import (
    Dispatch,
    cancel_mission,
    database_for,
    fail_mission,
    failing,
    gave_up,
    open_run,
    retry_step,
    send,
)
from service.jobs.progress import mission_heartbeat
from service.models import MissionStatus
from service.settings import Settings
from workers.mission import MissionError
from workers.run import MissionRun

log = logging.getLogger(__name__)


def plan_summary(plan: MissionPlan, guides: Sequence[Guide]) -> dict[str, Any]:
    """The stored plan summary (``Mission.plan``); ``guides`` are the sub-tasks' trained ones."""
    subtasks = []
    for sub, guide in zip(plan.subtasks, guides, strict=True):
        subtasks.append(
            {
                "index": sub.index,
                "phase": sub.phase,
                "goal": sub.goal,
                "length": path_length(sub.path),
                "balls": guide.num_balls,
                "r_ball": guide.r,
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
        cancelled, last, document = mission.cancel_requested, mission.reason, mission.document
        claimed = None
        if not cancelled:
            claimed = repository.claim_step(
                session, mission_id, MissionStatus.queued, MissionStatus.planning, "plan_attempts"
            )
    if cancelled:
        cancel_mission(db, mission_id)
        return "cancelled"
    if claimed is None:
        return "busy"
    attempt = claimed
    if attempt > settings.max_attempts:
        fail_mission(db, mission_id, gave_up("planning", attempt - 1, last))
        return "failed"
    indices: list[int] = []

    def retry(error: BaseException) -> bool:
        back = MissionStatus.planning, MissionStatus.queued
        return retry_step(settings, mission_id, back, attempt, error, dispatch.plan)

    with (
        failing(db, mission_id, "planning", retry=retry),
        mission_heartbeat(db, mission_id, settings.heartbeat_seconds),
    ):
        try:
            run = open_run(settings, mission_id, document)
        except (MissionError, PlanningError) as error:
            fail_mission(db, mission_id, str(error))
            return "infeasible" if isinstance(error, PlanningError) else "failed"
        plan = run.plan
        if not plan.subtasks:
            fail_mission(db, mission_id, "the plan has no sub-task to train (no goal region)")
            return "failed"
        guides = run.mission.trained_guides(plan)
        image = run.folder / "plan.png"
        _plot(run, image, guides)
        jobs = [
            repository.NewJob(
                index=job.subtask,
                budget=job.training.n_timesteps,
                out_dir=str(run.job_folder(job)),
            )
            for job in run.jobs()
        ]
        with db.session() as session:
            if not repository.holds_step(
                session, mission_id, MissionStatus.planning, "plan_attempts", attempt
            ):
                return "lost"  # reclaimed while this attempt still ran: it writes nothing
            image_path = str(image) if image.is_file() else None
            repository.set_plan(session, mission_id, plan_summary(plan, guides), image_path)
            rows = repository.create_jobs(session, mission_id, jobs)
            indices = [row.index for row in rows]
            try:
                repository.set_status(session, mission_id, MissionStatus.training)
            except repository.TransitionError:  # cancelled while planning
                repository.cancel_queued_jobs(session, mission_id)
                return "final"
    if not indices:  # the guard failed the mission, or put it back for later
        with db.session() as session:
            mission = repository.get_mission(session, mission_id)
            again = mission is not None and mission.status == MissionStatus.queued
        return "retrying" if again else "failed"
    send(lambda: dispatch.training(mission_id, indices), mission_id)
    return "planned"


def _plot(run: MissionRun, out: Path, guides: Sequence[Guide]) -> None:
    """The plan picture (as ``ltlnav plan --plot``); a failure costs the picture only."""
    from planner.plot import plot_plan

    try:
        plot_plan(run.mission.build_world(), run.plan, out, title=run.mission.name, guides=guides)
    except (OSError, ValueError, RuntimeError):
        log.exception("could not draw the plan of %s", out.parent.name)
