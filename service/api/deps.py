"""What the routes depend on, as ``Annotated`` parameter types (FastAPI dependencies).

``ServicesDep`` is the app's settings, database, enqueue, examples, health monitor and
submission gate;
``Caller`` the API key of the request (missions are scoped by it); ``SessionDep`` one database
session per request; ``OwnedMission`` the caller's mission named by the path's
``mission_id``.

The dependencies that do no I/O are ``async``: FastAPI runs a plain function in a worker
thread, one more hop per request."""

from __future__ import annotations

import hmac
import re
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from service import repository as repo
from service.api.examples import ExampleCatalogue
from service.api.health import HealthMonitor
from service.api.submission_gate import SubmissionGate
from service.db import Database
from service.models import Mission
from service.settings import Settings

Enqueue = Callable[[str], None]
"""Sends a committed mission to the workers (``service.jobs.tasks.enqueue_mission``)."""


@dataclass
class Services:
    """One app's collaborators (``app.state.services``)."""

    settings: Settings
    database: Database
    enqueue: Enqueue
    examples: ExampleCatalogue = field(init=False)
    health: HealthMonitor = field(init=False)
    submissions: SubmissionGate = field(init=False)

    def __post_init__(self) -> None:
        self.examples = ExampleCatalogue(self.settings.examples_dir)
        self.health = HealthMonitor(self.settings, self.database)
        self.submissions = SubmissionGate(self.settings.submission_concurrency)


async def services(request: Request) -> Services:
    """The ``Services`` of the app serving ``request``."""
    found: Services = request.app.state.services
    return found


ServicesDep = Annotated[Services, Depends(services)]
"""The app's ``Services``."""


bearer = HTTPBearer(
    auto_error=False,
    description="One of the operator's API keys (LTLNAV_API_KEYS); not needed when none are "
    "configured.",
)


def matching_key(token: str, keys: list[str]) -> str | None:
    """The key of ``keys`` that ``token`` is, or None."""
    # Compare with every key, in constant time, so the timing does not tell which one matched.
    found = None
    for key in keys:
        if hmac.compare_digest(token.encode(), key.encode()):
            found = key
    return found


async def caller(
    deps: ServicesDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> str | None:
    """The API key of the request, None for the open API (no keys configured); 401 when keys
    are configured and the request has no valid one."""
    keys = deps.settings.api_keys
    if not keys:
        return None
    if credentials is None:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "an API key is required: send 'Authorization: Bearer <key>'",
            headers={"WWW-Authenticate": "Bearer"},
        )
    key = matching_key(credentials.credentials, keys)
    if key is None:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "invalid API key",
            headers={"WWW-Authenticate": 'Bearer error="invalid_token"'},
        )
    return key


Caller = Annotated[str | None, Depends(caller)]
"""The authenticated API key of a request (None: open API)."""


async def submission_slot(deps: ServicesDep) -> AsyncIterator[None]:
    """One of the app's submission slots (``SubmissionGate``), until the handler returns."""
    async with deps.submissions.slot():
        yield


SubmissionSlot = Annotated[None, Depends(submission_slot, scope="function")]
"""A submission slot held by the request (see ``SubmissionGate``)."""


def database_session(deps: ServicesDep) -> Iterator[Session]:
    """A session of the app's database for one request, as ``Database.session`` gives it:
    committed when the handler returns, rolled back when it raises, closed either way."""
    with deps.database.session() as session:
        yield session


SessionDep = Annotated[Session, Depends(database_session, scope="function")]
"""The request's database session. It ends with the handler (``scope="function"``), before
the response is sent: a client never gets a 2xx for a write that did not commit, and a file or
event stream is sent without holding a session."""


MISSION_ID = re.compile(
    r"[0-9a-fA-F]{8}-[0-9a-fA-F]{4}-[0-9a-fA-F]{4}-[0-9a-fA-F]{4}-[0-9a-fA-F]{12}"
)
"""What a mission id looks like (a UUID); anything else is no mission."""

MissionId = Annotated[str, Path(description="The mission's id (a UUID).")]


def owned_mission(mission_id: MissionId, session: SessionDep, api_key: Caller) -> Mission:
    """The caller's mission of the path, or 404 (unknown, malformed or another key's id
    alike, so ids of other keys cannot be probed)."""
    mission = None
    if MISSION_ID.fullmatch(mission_id):
        mission = repo.get_owned_mission(session, mission_id.lower(), api_key)
    if mission is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no mission {mission_id[:64]!r}")
    return mission


OwnedMission = Annotated[Mission, Depends(owned_mission)]
"""The caller's mission named by the path's ``mission_id``, loaded in the request's session."""
