"""Errors the routes raise and how the app renders them (never a 500 for bad input)."""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence

from fastapi import FastAPI, Request, status
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError, OperationalError

from service.api.schemas import Problem

log = logging.getLogger(__name__)

_COLUMN = re.compile(r"\bcolumn (\d+)\b")


class ProblemsError(Exception):
    """A request rejected with located problems (``{"detail": [Problem, ...]}``)."""

    def __init__(self, status_code: int, problems: Sequence[Problem]) -> None:
        self.status_code = status_code
        self.problems = list(problems)
        super().__init__("; ".join(p.msg for p in self.problems))


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


async def _problems_handler(request: Request, error: Exception) -> JSONResponse:
    assert isinstance(error, ProblemsError)
    content = {"detail": [p.model_dump(exclude_none=True) for p in error.problems]}
    return JSONResponse(content, status_code=error.status_code)


_MISSING_TABLE = ("no such table", "UndefinedTable")


async def _database_handler(request: Request, error: Exception) -> JSONResponse:
    log.error("database error on %s %s: %s", request.method, request.url.path, error)
    text = f"{error} {type(getattr(error, 'orig', None)).__name__}"
    detail = "the database is unavailable; try again shortly"
    if any(marker in text for marker in _MISSING_TABLE):
        detail = "the database is not migrated: run `ltlnav migrate`"
    return JSONResponse({"detail": detail}, status_code=status.HTTP_503_SERVICE_UNAVAILABLE)


def install_handlers(app: FastAPI) -> None:
    """Render ``ProblemsError`` and database outages (503) as JSON."""
    app.add_exception_handler(ProblemsError, _problems_handler)
    app.add_exception_handler(OperationalError, _database_handler)
    app.add_exception_handler(DBAPIError, _database_handler)
