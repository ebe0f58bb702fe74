"""``/missions``: submit, list, read, cancel, delete, and fetch a mission's plan picture,
learning curves and bundle."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path as FilePath
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path, Query, status
from fastapi.responses import FileResponse, Response
from starlette.concurrency import run_in_threadpool

from service import repository as repo
from service.api.admission import (
    Admitted,
    idempotency_since,
    quota_refusal,
    replay_response,
    submitted,
)
from service.api.deps import (
    Caller,
    MissionId,
    OwnedMission,
    ServicesDep,
    SessionDep,
    owned_mission,
)
from service.api.json_body import JsonBodyRoute
from service.api.queries import cancel_if_queued
from service.api.schemas import (
    INVALID,
    MISSION_ERRORS,
    QUOTA_ERRORS,
    UNAUTHORIZED,
    UNSAFE_ERRORS,
    Curve,
    Message,
    MissionPageView,
    MissionView,
    Problems,
    Submitted,
)
from service.api.submission import ValidSubmission
from service.api.views import curve_point, mission_view
from service.db import Database
from service.models import JobStatus, MissionStatus

log = logging.getLogger(__name__)

router = APIRouter(prefix="/missions", tags=["missions"], route_class=JsonBodyRoute)

MAX_PAGE = 100
MAX_OFFSET = 2**31 - 1
MAX_SUBTASK = 10_000


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    response_model=Submitted,
    responses={
        200: {
            "model": Submitted,
            "description": "A repeated Idempotency-Key: nothing new was created; the first "
            "mission's submission answer (header Idempotent-Replayed: true).",
        },
        **UNAUTHORIZED,
        400: {"model": Problems, "description": "The body is not JSON."},
        **UNSAFE_ERRORS,
        413: {"model": Message, "description": "The body is larger than the limit."},
        422: {"model": Problems, "description": "The mission is invalid (field paths)."},
        **QUOTA_ERRORS,
    },
)
def submit_mission(
    api_key: Caller,
    idempotency_key: Admitted,
    submission: ValidSubmission,
    session: SessionDep,
    deps: ServicesDep,
) -> Submitted | Response:
    """Submit a mission document (the schema of the mission files) or ``{"example": name}``.

    It is validated fully (syntax, formula, world, robot) before it is stored and queued;
    planning and training happen on the workers. An infeasible mission ends ``failed`` with
    the reason. A key's quotas (missions at once, submissions per minute) are checked first
    (429); a repeated ``Idempotency-Key`` answers 200 with the first mission."""
    spec = submission.spec
    repo.serialize_submissions(session, api_key)
    mission = repo.create_mission(session, spec.name, submission.document, api_key, idempotency_key)
    # Counted again after the insert, in the transaction serialize_submissions orders: a
    # concurrent request with the same key, or one that filled the quota, is seen now.
    if idempotency_key is not None:
        since = idempotency_since(deps.settings)
        earlier = repo.find_by_idempotency_key(
            session, api_key, idempotency_key, since, other_than=mission.id
        )
        if earlier is not None:
            earlier_id = earlier.id
            session.rollback()
            return replay_response(earlier_id)
    refusal = quota_refusal(repo.quota_usage(session, api_key), deps.settings, api_key, adding=0)
    if refusal is not None:
        session.rollback()
        raise refusal
    session.commit()  # before the enqueue: the workers must find the mission
    try:
        deps.enqueue(mission.id)
    except Exception:
        # The mission is committed and queued: the workers' reconciler enqueues it later.
        log.exception("mission %s stored but not enqueued; the reconciler will retry", mission.id)
    return submitted(mission.id)


@router.get("", response_model=MissionPageView, responses={**UNAUTHORIZED, **INVALID})
def list_missions(
    session: SessionDep,
    api_key: Caller,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = 20,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
    status_filter: Annotated[MissionStatus | None, Query(alias="status")] = None,
) -> MissionPageView:
    """The caller's missions, newest first."""
    page = repo.list_missions(session, api_key, limit, offset, status_filter)
    items = [mission_view(m) for m in page.items]
    return MissionPageView(items=items, total=page.total, limit=limit, offset=offset)


@router.get("/{mission_id}", response_model=MissionView, responses=MISSION_ERRORS)
async def get_mission(mission_id: MissionId, api_key: Caller, deps: ServicesDep) -> Response:
    """A mission: status, plan summary, each sub-task's job and the mission evaluation."""
    # The read clients poll: one hop to the thread pool (the session, the query and the
    # view together) and no second validation of the view, rather than one hop per
    # dependency.
    body = await run_in_threadpool(mission_json, deps.database, mission_id, api_key)
    return Response(body, media_type="application/json")


def mission_json(database: Database, mission_id: str, api_key: str | None) -> bytes:
    """The body of ``GET /missions/{mission_id}`` for ``api_key`` (404 as ``HTTPException``)."""
    with database.read_session() as session:
        view = mission_view(owned_mission(mission_id, session, api_key))
    return view.model_dump_json(by_alias=True).encode()


@router.get(
    "/{mission_id}/plan.png",
    response_class=FileResponse,
    responses={**MISSION_ERRORS, 200: {"content": {"image/png": {}}, "description": "The plan."}},
)
def plan_picture(mission: OwnedMission) -> FileResponse:
    """The picture of the planned path (404 until the mission is planned)."""
    image = mission.plan_image
    if image is None or not FilePath(image).is_file():
        detail = f"no plan picture (the mission is {mission.status.value})"
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail)
    return FileResponse(image, media_type="image/png")


@router.get(
    "/{mission_id}/subtasks/{index}/curve",
    response_model=Curve,
    responses=MISSION_ERRORS,
)
def learning_curve(
    mission: OwnedMission,
    index: Annotated[int, Path(ge=0, le=MAX_SUBTASK, description="Sub-task index.")],
    session: SessionDep,
) -> Curve:
    """A sub-task's learning curve: success rate and mean return against training steps."""
    job = repo.get_job(session, mission.id, index)
    if job is None:
        detail = f"no sub-task {index}: the mission has {len(mission.jobs)} training jobs"
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail)
    points = [curve_point(row) for row in repo.learning_curve(session, job.id)]
    return Curve(index=index, points=points)


@router.post(
    "/{mission_id}/cancel",
    status_code=status.HTTP_202_ACCEPTED,
    response_model=MissionView,
    responses={
        **MISSION_ERRORS,
        **UNSAFE_ERRORS,
        409: {"model": Message, "description": "Already final."},
    },
)
def cancel_mission(mission: OwnedMission, session: SessionDep) -> MissionView:
    """Cooperative cancel: running jobs stop at their next check, finished checkpoints stay.
    A mission no worker has started is cancelled at once."""
    if mission.status in repo.FINAL_STATES:
        detail = f"the mission is already {mission.status.value}"
        raise HTTPException(status.HTTP_409_CONFLICT, detail)
    if mission.cancel_requested:
        detail = "a cancel was already requested; the workers are stopping the mission"
        raise HTTPException(status.HTTP_409_CONFLICT, detail)
    repo.request_cancel(session, mission.id)
    cancel_if_queued(session, mission.id)
    session.refresh(mission)
    return mission_view(mission)


@router.get(
    "/{mission_id}/bundle",
    response_class=FileResponse,
    responses={
        **MISSION_ERRORS,
        200: {"content": {"application/zip": {}}, "description": "The policy bundle."},
        409: {"model": Message, "description": "The mission is not done."},
    },
)
def download_bundle(mission: OwnedMission) -> FileResponse:
    """The policy bundle (zip: concatenated policy, plan, model card, pictures); 409 until
    the mission is done."""
    path = mission.bundle_path
    if mission.status != MissionStatus.done or path is None:
        detail = f"the bundle is not ready: the mission is {mission.status.value}"
        raise HTTPException(status.HTTP_409_CONFLICT, detail)
    if not FilePath(path).is_file():
        log.error("mission %s: its bundle %s is missing on disk", mission.id, path)
        raise HTTPException(status.HTTP_404_NOT_FOUND, "the bundle file is missing on the server")
    return FileResponse(path, media_type="application/zip", filename=f"{mission.name}-bundle.zip")


@router.delete(
    "/{mission_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    response_class=Response,
    responses={
        **MISSION_ERRORS,
        **UNSAFE_ERRORS,
        409: {"model": Message, "description": "The mission has not ended: cancel it first."},
    },
)
def delete_mission(mission: OwnedMission, session: SessionDep, deps: ServicesDep) -> Response:
    """Delete an ended mission (done, failed or cancelled): its rows (jobs, checkpoints,
    evaluations, events) and its artifact folder (plan, models, bundle). 409 while it runs:
    cancel it first. A repeat of its ``Idempotency-Key`` creates a new mission afterwards."""
    mission_id = mission.id
    if mission.status not in repo.FINAL_STATES:
        detail = (
            f"the mission is {mission.status.value}: cancel it first "
            f"(POST /missions/{mission_id}/cancel), then delete it once it has ended"
        )
        raise HTTPException(status.HTTP_409_CONFLICT, detail)
    if any(job.status == JobStatus.running for job in mission.jobs):
        detail = "the mission's training jobs are still stopping: try again in a few seconds"
        raise HTTPException(status.HTTP_409_CONFLICT, detail)
    if not repo.delete_mission(session, mission_id):
        detail = "the mission changed while it was being deleted: read it and try again"
        raise HTTPException(status.HTTP_409_CONFLICT, detail)
    session.commit()  # the rows go first: a folder without rows is only disk space
    remove_artifacts(deps.settings.artifact_dir, mission_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


def remove_artifacts(artifact_dir: FilePath, mission_id: str) -> None:
    """Delete ``<artifact_dir>/<mission_id>`` (plan, checkpoints, models, bundle), logging
    rather than failing: the mission's rows are already gone."""
    root = artifact_dir.resolve()
    folder = (root / mission_id).resolve()
    if folder.parent != root or not folder.is_dir():
        return
    try:
        shutil.rmtree(folder)
    except OSError as error:
        log.warning("mission %s deleted, but not its folder %s: %s", mission_id, folder, error)
