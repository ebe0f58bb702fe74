"""``GET /missions/{id}/events``: a mission's progress as Server-Sent Events.

Events come from the database feed (``repository.events_after``), so any API process can
serve any client; ``Last-Event-ID`` (or ``?after=``) resumes after a reconnect. The stream ends
with an ``end`` event once the mission is final; ``?once=1`` returns what is there and ends
(the polling form)."""

from __future__ import annotations

import json
import time
from collections.abc import AsyncIterator
from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Header, Query
from fastapi.responses import StreamingResponse
from fastapi.sse import format_sse_event
from starlette.concurrency import run_in_threadpool

from service import repository as repo
from service.api.deps import OwnedMission, Services, ServicesDep
from service.api.queries import mission_status
from service.api.schemas import MISSION_ERRORS
from service.models import Event, MissionStatus

router = APIRouter(tags=["missions"])

POLL_SECONDS = 0.5
"""How often an open stream looks for new events (no setting for it yet)."""
KEEPALIVE_SECONDS = 15.0
BATCH = 200
RETRY_MS = 2000
MAX_EVENT_ID = 2**62

Snapshot = tuple[tuple[MissionStatus, str | None] | None, list[dict[str, Any]]]


def _event_json(event: Event) -> dict[str, Any]:
    return {
        "id": event.id,
        "kind": event.kind,
        "created_at": event.created_at.isoformat(),
        "payload": event.payload,
    }


def _snapshot(deps: Services, mission_id: str, after: int) -> Snapshot:
    # Status first: a final status is committed with its event, so the events read next
    # include it.
    with deps.database.session() as session:
        state = mission_status(session, mission_id)
        events = repo.events_after(session, mission_id, after, BATCH)
        return state, [_event_json(e) for e in events]


def _sse(event: str, data: dict[str, Any], event_id: int | None = None) -> bytes:
    shown = None if event_id is None else str(event_id)
    return format_sse_event(data_str=json.dumps(data), event=event, id=shown)


async def event_stream(
    deps: Services, mission_id: str, after: int, once: bool
) -> AsyncIterator[bytes]:
    """The SSE bytes of a mission's events after ``after`` (see the module docstring)."""
    yield f"retry: {RETRY_MS}\n\n".encode()
    last_sent = time.monotonic()
    while True:
        state, events = await run_in_threadpool(_snapshot, deps, mission_id, after)
        for event in events:
            yield _sse(event["kind"], event, event["id"])
            after = event["id"]
            last_sent = time.monotonic()
        if len(events) == BATCH:
            continue
        if state is None or state[0] in repo.FINAL_STATES:
            status, reason = state if state is not None else (None, "the mission was deleted")
            yield _sse("end", {"status": status, "reason": reason})
            return
        if once:
            return
        if time.monotonic() - last_sent >= KEEPALIVE_SECONDS:
            yield b": keep-alive\n\n"
            last_sent = time.monotonic()
        await anyio.sleep(POLL_SECONDS)


@router.get(
    "/missions/{mission_id}/events",
    response_class=StreamingResponse,
    responses={
        **MISSION_ERRORS,
        200: {
            "description": "Server-Sent Events: `status`, `job`, `progress`, `cancel`, ... "
            "with the event id, then `end` when the mission is final.",
            "content": {"text/event-stream": {"schema": {"type": "string"}}},
        },
    },
)
async def mission_events(
    mission: OwnedMission,
    deps: ServicesDep,
    last_event_id: Annotated[
        int | None, Header(alias="Last-Event-ID", ge=0, le=MAX_EVENT_ID)
    ] = None,
    after: Annotated[
        int | None, Query(ge=0, le=MAX_EVENT_ID, description="Resume after this event id.")
    ] = None,
    once: Annotated[bool, Query(description="Send the events so far and end (polling).")] = False,
) -> StreamingResponse:
    """Progress of a mission as Server-Sent Events, ending when the mission is final."""
    start = max(after or 0, last_event_id or 0)
    return StreamingResponse(
        event_stream(deps, mission.id, start, once),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
