"""ORM rows of ``service.models`` turned into the API's response models."""

from __future__ import annotations

from typing import Any

from service.api.schemas import CurvePoint, JobView, MissionLinks, MissionView
from service.models import Evaluation, Job, Mission


def mission_links(mission_id: str, indices: list[int]) -> MissionLinks:
    """The links of a mission with sub-tasks ``indices``."""
    base = f"/missions/{mission_id}"
    return MissionLinks.model_validate(
        {
            "self": base,
            "plan_png": f"{base}/plan.png",
            "events": f"{base}/events",
            "cancel": f"{base}/cancel",
            "bundle": f"{base}/bundle",
            "curves": [f"{base}/subtasks/{k}/curve" for k in indices],
        }
    )


def _subtask_indices(mission: Mission) -> list[int]:
    if mission.jobs:
        return [job.index for job in mission.jobs if job.repair_round == 0]
    subtasks = (mission.plan or {}).get("subtasks")
    if isinstance(subtasks, list):
        return [s["index"] for s in subtasks if isinstance(s, dict) and "index" in s]
    return []


def job_view(job: Job) -> JobView:
    """A job as the API shows it."""
    result = job.result or {}
    final: Any = result.get("final")
    seconds: Any = result.get("seconds")
    parts: Any = result.get("parts")
    return JobView(
        index=job.index,
        round=job.repair_round,
        status=job.status,
        steps_done=job.steps_done,
        budget=job.budget,
        success_rate=job.success_rate,
        eta_seconds=job.eta_seconds,
        attempts=job.attempts,
        reason=job.reason,
        final=final if isinstance(final, dict) else None,
        seconds=seconds if isinstance(seconds, int | float) else None,
        time_by_part=parts if isinstance(parts, dict) and parts else None,
    )


def mission_view(mission: Mission) -> MissionView:
    """A mission with its jobs, as the API shows it."""
    document = mission.document or {}
    robot = document.get("robot")
    return MissionView(
        id=mission.id,
        name=mission.name,
        status=mission.status,
        reason=mission.reason,
        cancel_requested=bool(mission.cancel_requested),
        created_at=mission.created_at,
        updated_at=mission.updated_at,
        task=str(document.get("task", "")),
        robot=str(robot.get("model")) if isinstance(robot, dict) else None,
        plan=mission.plan,
        jobs=[job_view(job) for job in mission.jobs if job.repair_round == 0],
        repairs=[job_view(job) for job in mission.jobs if job.repair_round > 0],
        repair_rounds=list(mission.repairs or []),
        evaluation=mission.evaluation,
        links=mission_links(mission.id, _subtask_indices(mission)),
    )


def curve_point(row: Evaluation) -> CurvePoint:
    """One learning-curve point."""
    return CurvePoint(
        steps=row.steps,
        success_rate=row.success_rate,
        mean_return=row.mean_return,
        episodes=row.episodes,
    )
