"""Liveness of the API's dependencies: the database and the Celery broker."""

from __future__ import annotations

import logging

from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError

from service.api.schemas import ComponentState
from service.db import Database
from service.settings import Settings

log = logging.getLogger(__name__)

BROKER_TIMEOUT = 2.0


def database_state(database: Database) -> tuple[ComponentState, str | None]:
    """Whether ``SELECT 1`` works."""
    try:
        with database.engine.connect() as connection:
            connection.execute(text("SELECT 1"))
    except SQLAlchemyError as error:
        return "down", str(error).splitlines()[0]
    return "ok", None


def broker_state(settings: Settings) -> tuple[ComponentState, str | None]:
    """Whether the broker answers (``service.jobs.celery_app.broker_ok``); unknown when the
    worker code cannot be imported or the check itself fails."""
    try:
        from service.jobs.celery_app import broker_ok
    except Exception as error:
        return "unknown", f"cannot load the worker code: {error}"
    try:
        ok = broker_ok(settings, timeout=BROKER_TIMEOUT)
    except Exception as error:
        log.warning("broker check failed: %s", error)
        return "unknown", f"the broker check failed: {error}"
    return ("ok", None) if ok else ("down", "the broker does not answer")
