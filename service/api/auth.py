"""API keys: ``Authorization: Bearer <key>`` when the operator configured keys.

A request's caller is the key it presented (missions are scoped by it) or None when the API
is open (no keys configured)."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from service.api.state import services

bearer = HTTPBearer(
    auto_error=False,
    description="One of the operator's API keys (LTLNAV_API_KEYS); not needed when none are "
    "configured.",
)


def _matching_key(token: str, keys: list[str]) -> str | None:
    found = None
    for key in keys:
        if hmac.compare_digest(token.encode(), key.encode()):
            found = key
    return found


def caller(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> str | None:
    """The API key of the request, None for the open API; 401 when keys are configured and
    the request has no valid one."""
    keys = services(request).settings.api_keys
    if not keys:
        return None
    if credentials is None:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "an API key is required: send 'Authorization: Bearer <key>'",
            headers={"WWW-Authenticate": "Bearer"},
        )
    key = _matching_key(credentials.credentials, keys)
    if key is None:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "invalid API key",
            headers={"WWW-Authenticate": 'Bearer error="invalid_token"'},
        )
    return key


Caller = Annotated[str | None, Depends(caller)]
"""The authenticated API key of a request (None: open API)."""
