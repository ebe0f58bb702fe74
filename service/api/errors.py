"""How the app renders errors (never a 500 for bad input): located problems as
``{"detail": [Problem, ...]}``, database outages as 503.

Every validation problem, FastAPI's own (parameters) and the mission checks alike, is a
``RequestValidationError`` rendered by one handler: 400 when the body is not JSON at all, else
422."""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError, OperationalError

from service.api.schemas import Problem

log = logging.getLogger(__name__)

JSON_INVALID = "json_invalid"
"""The ``type`` of a problem saying the body is not JSON (answered 400)."""

_COLUMN = re.compile(r"\bcolumn (\d+)\b")


def _loc_part(part: str) -> str | int:
    return int(part) if part.isascii() and part.isdigit() else part


def body_problem(path: str, message: str, kind: str = "mission") -> Problem:
    """A problem at dotted ``path`` of the request body; a task problem carries the column
    of the formula it points at."""
    parts = [p for p in path.split(".") if p] if path and path != "mission" else []
    match = _COLUMN.search(message) if parts[:1] == ["task"] else None
    return Problem(
        loc=["body", *(_loc_part(p) for p in parts)],
        msg=message,
        type=kind,
        field=".".join(parts) or None,
        column=int(match.group(1)) if match else None,
    )


def invalid(problems: Sequence[Problem]) -> RequestValidationError:
    """The error that answers ``problems`` through the app's validation handler."""
    return RequestValidationError([p.model_dump(exclude_none=True) for p in problems])


def _problem(error: Any) -> Problem:
    # FastAPI's errors are pydantic's dicts (loc, msg, type, input, ctx); ours are dumped
    # ``Problem``s, with their field and formula column.
    return Problem(
        loc=list(error.get("loc", ())),
        msg=str(error.get("msg", "")),
        type=str(error.get("type", "")),
        field=error.get("field"),
        column=error.get("column"),
    )


async def _validation_handler(request: Request, error: Exception) -> JSONResponse:
    assert isinstance(error, RequestValidationError)
    problems = [_problem(e) for e in error.errors()]
    syntax = bool(problems) and all(p.type == JSON_INVALID for p in problems)
    code = status.HTTP_400_BAD_REQUEST if syntax else status.HTTP_422_UNPROCESSABLE_CONTENT
    content = {"detail": [p.model_dump(exclude_none=True) for p in problems]}
    return JSONResponse(content, status_code=code)


_MISSING_TABLE = ("no such table", "UndefinedTable")


async def _database_handler(request: Request, error: Exception) -> JSONResponse:
    log.error("database error on %s %s: %s", request.method, request.url.path, error)
    text = f"{error} {type(getattr(error, 'orig', None)).__name__}"
    detail = "the database is unavailable; try again shortly"
    if any(marker in text for marker in _MISSING_TABLE):
        detail = "the database is not migrated: run `ltlnav migrate`"
    return JSONResponse({"detail": detail}, status_code=status.HTTP_503_SERVICE_UNAVAILABLE)


def install_handlers(app: FastAPI) -> None:
    """Render validation problems (400/422) and database outages (503) as JSON."""
    app.add_exception_handler(RequestValidationError, _validation_handler)
    app.add_exception_handler(OperationalError, _database_handler)
    app.add_exception_handler(DBAPIError, _database_handler)
