"""Admission of ``POST /missions``: a repeated ``Idempotency-Key`` gets its first mission back,
and a key over one of its quotas gets 429, both before the body is validated (CPU work) and
before anything is stored.

The checks run twice: here, cheaply, so that a replay or a refusal costs no validation; and
in the handler after the insert, inside the transaction that ``serialize_submissions`` orders
per key, so that two concurrent requests with one ``Idempotency-Key`` make one mission and
concurrent submissions cannot overrun a quota."""

from __future__ import annotations

import math
from datetime import datetime, timedelta
from typing import Annotated

from fastapi import Depends, FastAPI, Header, HTTPException, Request, status
from fastapi.responses import JSONResponse

from service import repository as repo
from service.api.deps import Caller, ServicesDep, SessionDep, SubmissionSlot
from service.api.schemas import Submitted
from service.api.views import mission_links
from service.models import MissionStatus, utcnow
from service.repository.quotas import RATE_WINDOW
from service.settings import Settings

IDEMPOTENCY_KEY_MAX = 200
"""Longest ``Idempotency-Key`` (the length of ``missions.idempotency_key``)."""

ACTIVE_RETRY_SECONDS = 30
"""``Retry-After`` when a key has too many missions at once (when one ends is unknown)."""

REPLAYED_HEADER = "Idempotent-Replayed"
"""Set to ``true`` on the answer to a repeated ``Idempotency-Key``."""

IdempotencyKey = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        min_length=1,
        max_length=IDEMPOTENCY_KEY_MAX,
        description="Any unique string (a UUID, say) of at most 200 characters. A request that "
        "repeats one the same API key used in the last LTLNAV_IDEMPOTENCY_KEY_HOURS (24) "
        "creates nothing: it answers 200 with the first mission's submission answer (the body "
        "that request got with its 201), so a client may retry after a timeout without making "
        "duplicates. After that window the key makes a new mission.",
    ),
]


def idempotency_since(settings: Settings) -> datetime:
    """The oldest submission a repeated ``Idempotency-Key`` still answers with (on the clock
    that stamps ``created_at``)."""
    return utcnow() - timedelta(hours=settings.idempotency_key_hours)


def submitted(mission_id: str) -> Submitted:
    """The answer to an accepted submission (a new mission is ``queued``); a replay of its
    ``Idempotency-Key`` answers the same."""
    return Submitted(
        id=mission_id, status=MissionStatus.queued, links=mission_links(mission_id, [])
    )


class ReplayedError(Exception):
    """Raised by ``admit`` to answer a repeated ``Idempotency-Key`` with its first mission
    (rendered by the handler ``install_replay`` adds) without validating the body."""

    def __init__(self, mission_id: str) -> None:
        super().__init__(mission_id)
        self.mission_id = mission_id


def replay_response(mission_id: str) -> JSONResponse:
    """200 with the first mission's submission answer, marked as a replay."""
    body = submitted(mission_id).model_dump(mode="json", by_alias=True)
    return JSONResponse(body, status_code=status.HTTP_200_OK, headers={REPLAYED_HEADER: "true"})


async def _replayed_handler(request: Request, error: Exception) -> JSONResponse:
    assert isinstance(error, ReplayedError)
    return replay_response(error.mission_id)


def install_replay(app: FastAPI) -> None:
    """Answer ``ReplayedError`` with ``replay_response``."""
    app.add_exception_handler(ReplayedError, _replayed_handler)


def _retry_after(oldest: datetime | None, now: datetime) -> int:
    if oldest is None:
        return 1
    return max(1, math.ceil((oldest + RATE_WINDOW - now).total_seconds()))


def quota_refusal(
    usage: repo.QuotaUsage, settings: Settings, api_key: str | None, adding: int
) -> HTTPException | None:
    """429 (with ``Retry-After``) when ``usage`` plus ``adding`` more missions goes over a quota
    of the key; None when it fits."""
    who = "this API key" if api_key is not None else "the open API (all callers together)"
    active_limit = settings.quota_active_missions
    if active_limit and usage.active + adding > active_limit:
        detail = (
            f"{who} already has {usage.active - (1 - adding)} missions queued or running, the "
            f"most allowed at once (LTLNAV_QUOTA_ACTIVE_MISSIONS={active_limit}): wait until one "
            "ends or cancel one, then submit again"
        )
        headers = {"Retry-After": str(ACTIVE_RETRY_SECONDS)}
        return HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, detail, headers=headers)
    rate_limit = settings.quota_submissions_per_minute
    if rate_limit and usage.recent + adding > rate_limit:
        retry = _retry_after(usage.oldest_recent, utcnow())
        detail = (
            f"{who} submitted {usage.recent - (1 - adding)} missions in the last minute, the "
            f"most allowed (LTLNAV_QUOTA_SUBMISSIONS_PER_MINUTE={rate_limit}): retry in {retry} s"
        )
        headers = {"Retry-After": str(retry)}
        return HTTPException(status.HTTP_429_TOO_MANY_REQUESTS, detail, headers=headers)
    return None


def admit(
    api_key: Caller,
    _slot: SubmissionSlot,
    session: SessionDep,
    deps: ServicesDep,
    idempotency_key: IdempotencyKey = None,
) -> str | None:
    """The request's ``Idempotency-Key`` once the submission may go on: a repeated key raises
    ``ReplayedError`` (200, its first mission), a key over a quota 429. The submission slot is
    taken first: a submission waiting for one holds no database connection, which the reads
    served meanwhile would otherwise wait for."""
    if idempotency_key is not None:
        since = idempotency_since(deps.settings)
        earlier = repo.find_by_idempotency_key(session, api_key, idempotency_key, since)
        if earlier is not None:
            raise ReplayedError(earlier.id)
    refusal = quota_refusal(repo.quota_usage(session, api_key), deps.settings, api_key, adding=1)
    if refusal is not None:
        raise refusal
    return idempotency_key


Admitted = Annotated[str | None, Depends(admit)]
"""The ``Idempotency-Key`` of a submission that passed admission (None: sent without one)."""
