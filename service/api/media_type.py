"""Cross-site request forgery stops here: a request that changes state (POST, DELETE) must be
JSON, which a web page of another site cannot send without the browser asking first.

A page can make a browser post a form (``application/x-www-form-urlencoded``,
``multipart/form-data``), ``text/plain`` or an untyped body to any address, the API's on a
user's machine included, with no CORS preflight; ``application/json`` needs one, and the API
grants none. So a state-changing request with a body must say ``Content-Type:
application/json`` (415 otherwise), a body-less one may also say nothing, and a browser that
marks a request ``Sec-Fetch-Site: cross-site`` is refused outright (403)."""

from __future__ import annotations

from fastapi import HTTPException, Request, status

JSON_MEDIA_TYPE = "application/json"
"""The one media type of request bodies (the API parses JSON only, no YAML)."""

UNSAFE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
"""Methods that change state, and so are checked."""

ACCEPTED = f"send 'Content-Type: {JSON_MEDIA_TYPE}' (optionally '; charset=utf-8')"


def media_type_problem(content_type: str | None, has_body: bool) -> str | None:
    """Why a state-changing request with this ``Content-Type`` header (None: absent) and body
    is refused, or None when it is accepted."""
    if content_type is None:
        if has_body:
            return f"the request body has no content type: {ACCEPTED}"
        return None
    media_type, *parameters = (part.strip() for part in content_type.split(";"))
    if media_type.lower() != JSON_MEDIA_TYPE:
        shown = media_type[:80] or "empty"
        return f"unsupported content type '{shown}': the API accepts only JSON; {ACCEPTED}"
    for parameter in parameters:
        name, _, value = parameter.partition("=")
        charset = value.strip().strip('"').lower()
        if name.strip().lower() == "charset" and charset not in ("utf-8", "utf8"):
            return f"unsupported charset '{charset[:40]}': JSON is read as UTF-8; {ACCEPTED}"
    return None


def check_unsafe_request(request: Request, body: bytes) -> None:
    """403 for a request a browser marks cross-site, 415 for one that is not JSON (see the
    module docstring); nothing for an accepted one."""
    if request.headers.get("sec-fetch-site", "").lower() == "cross-site":
        detail = (
            "a web page of another site sent this request (Sec-Fetch-Site: cross-site): refused "
            "so that visiting a page cannot change missions; call the API directly"
        )
        raise HTTPException(status.HTTP_403_FORBIDDEN, detail)
    problem = media_type_problem(request.headers.get("content-type"), bool(body))
    if problem is not None:
        raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE, problem)
