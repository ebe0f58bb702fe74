"""What every Celery step shares: the dispatch of follow-up work, the database and artifact
folder of a mission, its run (opened once per process), and failing a mission with a reason.
"""

from __future__ import annotations

import logging
import os
import socket
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, Protocol

from celery.exceptions import SoftTimeLimitExceeded

from planner.errors import LtlnavError
from service import repository
from service.db import Database
from service.models import JobStatus, MissionStatus
from service.settings import Settings
from workers.run import MissionRun

log = logging.getLogger(__name__)

OPEN_RUNS = 8
"""Mission runs a worker process keeps open (each holds a parsed mission and its plan)."""


class Dispatch(Protocol):
    """Sends the follow-up tasks (Celery in production, a recorder in tests)."""

    def training(self, mission_id: str, indices: Sequence[int], repair_round: int = 0) -> None:
        """Train the sub-tasks ``indices`` of round ``repair_round`` in parallel, then
        assemble the mission."""

    def train(self, mission_id: str, index: int, repair_round: int = 0) -> None:
        """Train one job (outside a chord: it assembles when it finishes last)."""

    def assemble(self, mission_id: str) -> None:
        """Assemble the mission."""

    def plan(self, mission_id: str) -> None:
        """Plan the mission."""


_databases: dict[str, Database] = {}


def database_for(settings: Settings) -> Database:
    """One ``Database`` per URL per process."""
    db = _databases.get(settings.database_url)
    if db is None:
        db = _databases[settings.database_url] = Database(settings.database_url)
    return db


def mission_dir(settings: Settings, mission_id: str) -> Path:
    """``<artifact_dir>/<mission_id>``: plan.json, plan.png, subtask_<k>/, bundle.zip."""
    return settings.artifact_dir / mission_id


def worker_name() -> str:
    """Host and process of this worker (``Job.worker``)."""
    return f"{socket.gethostname()}:{os.getpid()}"


def fail_mission(db: Database, mission_id: str, reason: str) -> None:
    """Mark the mission failed (nothing when it already ended)."""
    with db.session() as session, suppress(repository.TransitionError):
        repository.set_status(session, mission_id, MissionStatus.failed, reason)


def cancel_mission(db: Database, mission_id: str) -> None:
    """Mark the mission cancelled and its queued jobs too (nothing when it already ended)."""
    with db.session() as session:
        try:
            repository.set_status(
                session, mission_id, MissionStatus.cancelled, "cancelled on request"
            )
        except repository.TransitionError:
            return
        repository.cancel_queued_jobs(session, mission_id)


def describe(error: BaseException) -> str:
    """A user-facing reason: a known error's message, else its type and message."""
    if isinstance(error, LtlnavError):
        return str(error)
    if isinstance(error, SoftTimeLimitExceeded):
        return (
            "ran past the task time limit (LTLNAV_TASK_SOFT_TIME_LIMIT): "
            "lower the training budget or raise the limit"
        )
    return f"{type(error).__name__}: {error}"


@contextmanager
def failing(
    db: Database, mission_id: str, what: str, job: tuple[int, str] | None = None
) -> Iterator[None]:
    """Turn any error of the block into a ``failed`` mission (and job ``(id, worker)``, if
    this worker still holds it) with the reason; re-raise only if that cannot be written."""
    try:
        yield
    except Exception as error:
        log.exception("%s of mission %s failed", what, mission_id)
        reason = f"{what}: {describe(error)}"
        try:
            if job is not None:
                with db.session() as session:
                    if repository.holds_job(session, job[0], job[1]):
                        repository.finish_job(session, job[0], JobStatus.failed, reason=reason)
            fail_mission(db, mission_id, reason)
        except Exception:
            log.exception("could not record the failure of mission %s", mission_id)
            raise error from None


def send(action: Callable[[], None], mission_id: str) -> None:
    """Send follow-up work; a broker outage is logged, not fatal: the state is committed and
    the reconciler sends what is still queued once the broker is back."""
    try:
        action()
    except Exception:
        log.exception("could not send the next task of mission %s; the reconciler will", mission_id)


_runs: OrderedDict[tuple[str, str], MissionRun] = OrderedDict()


def open_run(settings: Settings, mission_id: str, document: Mapping[str, Any]) -> MissionRun:
    """The mission's run: validated and planned (or its plan loaded) once per process, then
    reused by every later step of the mission in this process."""
    key = (str(settings.artifact_dir), mission_id)
    run = _runs.get(key)
    if run is None:
        run = MissionRun.open(document, mission_dir(settings, mission_id))
        _runs[key] = run
        while len(_runs) > OPEN_RUNS:
            _runs.popitem(last=False)
    else:
        _runs.move_to_end(key)
    return run


def forget_open_runs() -> None:
    """Close every open run: the next step reads its mission's plan anew, as a fresh worker
    process does."""
    _runs.clear()
