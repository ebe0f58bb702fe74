"""``GET /missions/{id}`` answered before FastAPI's routing and dependencies.

Pollers call this read more than every other route together, and FastAPI's per-request work
(routing, dependency solving, the response class) costs several times the read itself
(``bench/read_cost.py``). This ASGI middleware serves the common case itself: a ``GET`` of
``/missions/<uuid>`` by a caller whose key is valid (or the open API) for a mission of that
key. It reads with the route's own function (``missions.mission_json``: the same session,
query and view), so the body is the route's byte for byte. Everything else, including every
error (no or a bad key, an unknown or another key's mission, a database that fails), goes on
to the app unchanged, which answers it as before.
"""

from __future__ import annotations

from fastapi.security.utils import get_authorization_scheme_param
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from service.api.deps import MISSION_ID, Services, matching_key
from service.api.missions import mission_json

PREFIX = "/missions/"


class FastMissionRead:
    """ASGI middleware serving the caller's ``GET /missions/{id}`` (see the module)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        body = None
        if scope["type"] == "http" and scope["method"] == "GET":
            body = await self._read(scope)
        if body is None:
            await self.app(scope, receive, send)
            return
        headers = [
            (b"content-type", b"application/json"),
            (b"content-length", str(len(body)).encode()),
        ]
        await send({"type": "http.response.start", "status": 200, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    async def _read(self, scope: Scope) -> bytes | None:
        """The mission's JSON for this caller, or None for the app to answer."""
        path: str = scope["path"]
        mission_id = path[len(PREFIX) :]
        if not path.startswith(PREFIX) or not MISSION_ID.fullmatch(mission_id):
            return None
        services: Services = scope["app"].state.services
        keys = services.settings.api_keys
        api_key = None
        if keys:
            api_key = matching_key(_bearer_token(scope), keys)
            if api_key is None:
                return None
        try:
            body: bytes = await run_in_threadpool(
                mission_json, services.database, mission_id, api_key
            )
        except Exception:  # the app reads again and answers it as the route does
            return None
        return body


def _bearer_token(scope: Scope) -> str:
    """The token of the request's ``Authorization: Bearer`` header ('' when none), read as
    ``deps.bearer`` (FastAPI's ``HTTPBearer``) reads it."""
    scheme, token = get_authorization_scheme_param(Headers(scope=scope).get("authorization"))
    return token if scheme.lower() == "bearer" else ""
