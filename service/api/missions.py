"""``/missions``: submit, list, read, cancel, and fetch a mission's plan picture, learning
curves and bundle."""

from __future__ import annotations

import logging
import re
from pathlib import Path as FilePath
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query, Request, status
from fastapi.responses import FileResponse
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from service import repository as repo
from service.api.auth import Caller
from service.api.queries import cancel_if_queued
from service.api.schemas import (
    Curve,
    Message,
    MissionPageView,
    MissionView,
    Problems,
    Submitted,
)
from service.api.state import Deps, Services
from service.api.submission import submission
from service.api.views import curve_point, mission_links, mission_view
from service.models import Mission, MissionStatus

log = logging.getLogger(__name__)

router = APIRouter(prefix="/missions", tags=["missions"])

MAX_PAGE = 100
MAX_OFFSET = 2**31 - 1
MAX_SUBTASK = 10_000
_ID = re.compile(r"[0-9a-fA-F]{8}-[0-9a-fA-F]{4}-[0-9a-fA-F]{4}-[0-9a-fA-F]{4}-[0-9a-fA-F]{12}")

MissionId = Annotated[str, Path(description="The mission's id (a UUID).")]

NOT_FOUND: dict[int | str, dict[str, Any]] = {
    401: {"model": Message, "description": "Missing or invalid API key."},
    404: {"model": Message, "description": "No such mission for this API key."},
}

SUBMIT_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {
                "schema": {
                    "oneOf": [
                        {"$ref": "#/components/schemas/MissionSpec"},
                        {"$ref": "#/components/schemas/ExampleRequest"},
                    ]
                }
            }
        },
    }
}
"""The submission body; its schemas join the OpenAPI components (see ``app.openapi_schema``)."""


def owned_mission(session: Session, mission_id: str, api_key: str | None) -> Mission:
    """The caller's mission, or 404 (unknown, malformed or another key's id alike)."""
    mission = None
    if _ID.fullmatch(mission_id):
        mission = repo.get_owned_mission(session, mission_id.lower(), api_key)
    if mission is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no mission {mission_id[:64]!r}")
    return mission


def _create(deps: Services, raw: bytes, api_key: str | None) -> Submitted:
    sub = submission(raw, deps.examples)
    with deps.database.session() as session:
        mission = repo.create_mission(session, sub.spec.name, sub.document, api_key)
        mission_id, mission_status = mission.id, mission.status
    try:
        deps.enqueue(mission_id)
    except Exception:
        # The mission is committed and queued: the workers' reconciler enqueues it later.
        log.exception("mission %s stored but not enqueued; the reconciler will retry", mission_id)
    return Submitted(id=mission_id, status=mission_status, links=mission_links(mission_id, []))


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    responses={
        400: {"model": Problems, "description": "The body is not JSON."},
        401: NOT_FOUND[401],
        413: {"model": Message, "description": "The body is larger than the limit."},
        422: {"model": Problems, "description": "The mission is invalid (field paths)."},
    },
    openapi_extra=SUBMIT_BODY,
)
async def submit_mission(request: Request, deps: Deps, api_key: Caller) -> Submitted:
    """Submit a mission document (the schema of the mission files) or ``{"example": name}``.

    It is validated fully (syntax, formula, world, robot) before it is queued; planning and
    training happen on the workers. An infeasible mission ends ``failed`` with the reason."""
    raw = await request.body()
    return await run_in_threadpool(_create, deps, raw, api_key)


@router.get("", responses={401: NOT_FOUND[401]})
def list_missions(
    deps: Deps,
    api_key: Caller,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = 20,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET)] = 0,
    status_filter: Annotated[MissionStatus | None, Query(alias="status")] = None,
) -> MissionPageView:
    """The caller's missions, newest first."""
    with deps.database.session() as session:
        page = repo.list_missions(session, api_key, limit, offset, status_filter)
        items = [mission_view(m) for m in page.items]
    return MissionPageView(items=items, total=page.total, limit=limit, offset=offset)


@router.get("/{mission_id}", responses=NOT_FOUND)
def get_mission(mission_id: MissionId, deps: Deps, api_key: Caller) -> MissionView:
    """A mission: status, plan summary, each sub-task's job and the mission evaluation."""
    with deps.database.session() as session:
        return mission_view(owned_mission(session, mission_id, api_key))


@router.get(
    "/{mission_id}/plan.png",
    response_class=FileResponse,
    responses={**NOT_FOUND, 200: {"content": {"image/png": {}}, "description": "The plan."}},
)
def plan_picture(mission_id: MissionId, deps: Deps, api_key: Caller) -> FileResponse:
    """The picture of the planned path (404 until the mission is planned)."""
    with deps.database.session() as session:
        mission = owned_mission(session, mission_id, api_key)
        image, mission_status = mission.plan_image, mission.status
    if image is None or not FilePath(image).is_file():
        detail = f"no plan picture (the mission is {mission_status.value})"
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail)
    return FileResponse(image, media_type="image/png")


@router.get("/{mission_id}/subtasks/{index}/curve", responses=NOT_FOUND)
def learning_curve(
    mission_id: MissionId,
    index: Annotated[int, Path(ge=0, le=MAX_SUBTASK, description="Sub-task index.")],
    deps: Deps,
    api_key: Caller,
) -> Curve:
    """A sub-task's learning curve: success rate and mean return against training steps."""
    with deps.database.session() as session:
        mission = owned_mission(session, mission_id, api_key)
        job = repo.get_job(session, mission.id, index)
        if job is None:
            count = len(mission.jobs)
            detail = f"no sub-task {index}: the mission has {count} training jobs"
            raise HTTPException(status.HTTP_404_NOT_FOUND, detail)
        points = [curve_point(row) for row in repo.learning_curve(session, job.id)]
    return Curve(index=index, points=points)


@router.post(
    "/{mission_id}/cancel",
    status_code=status.HTTP_202_ACCEPTED,
    responses={**NOT_FOUND, 409: {"model": Message, "description": "Already final."}},
)
def cancel_mission(mission_id: MissionId, deps: Deps, api_key: Caller) -> MissionView:
    """Cooperative cancel: running jobs stop at their next check, finished checkpoints stay.
    A mission no worker has started is cancelled at once."""
    with deps.database.session() as session:
        mission = owned_mission(session, mission_id, api_key)
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
        **NOT_FOUND,
        200: {"content": {"application/zip": {}}, "description": "The policy bundle."},
        409: {"model": Message, "description": "The mission is not done."},
    },
)
def download_bundle(mission_id: MissionId, deps: Deps, api_key: Caller) -> FileResponse:
    """The policy bundle (zip: concatenated policy, plan, model card, pictures); 409 until
    the mission is done."""
    with deps.database.session() as session:
        mission = owned_mission(session, mission_id, api_key)
        path, name, mission_status = mission.bundle_path, mission.name, mission.status
    if mission_status != MissionStatus.done or path is None:
        detail = f"the bundle is not ready: the mission is {mission_status.value}"
        raise HTTPException(status.HTTP_409_CONFLICT, detail)
    if not FilePath(path).is_file():
        log.error("mission %s: its bundle %s is missing on disk", mission_id, path)
        raise HTTPException(status.HTTP_404_NOT_FOUND, "the bundle file is missing on the server")
    return FileResponse(path, media_type="application/zip", filename=f"{name}-bundle.zip")
