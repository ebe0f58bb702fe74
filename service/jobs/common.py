"""What every Celery step shares: the dispatch of follow-up work, the database and artifact
folder of a mission, its run (opened once per process), and failing a mission with a reason.
"""

from __future__ import annotations

import errno
import logging
import os
import socket
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, Protocol

from celery.exceptions import SoftTimeLimitExceeded
from kombu.exceptions import OperationalError as KombuOperationalError
from sqlalchemy.exc import DBAPIError

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

    def train(
        self, mission_id: str, index: int, repair_round: int = 0, countdown: float = 0.0
    ) -> None:
        """Train one job (outside a chord: it assembles when it finishes last), not before
        ``countdown`` seconds."""

    def assemble(self, mission_id: str, countdown: float = 0.0) -> None:
        """Assemble the mission, not before ``countdown`` seconds."""

    def plan(self, mission_id: str, countdown: float = 0.0) -> None:
        """Plan the mission, not before ``countdown`` seconds."""


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


TRANSIENT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EAGAIN})
"""``OSError`` numbers that may pass: a full disk or quota, a flaky mount."""


def is_transient(error: BaseException) -> bool:
    """Whether ``error`` may pass if the step runs again later: a full disk, the database or
    the broker unreachable. Invalid missions, infeasible plans and bugs are permanent."""
    if isinstance(error, LtlnavError):
        return False
    if isinstance(error, OSError) and error.errno in TRANSIENT_ERRNOS:
        return True
    return isinstance(error, DBAPIError | KombuOperationalError | ConnectionError | TimeoutError)


def backoff_seconds(settings: Settings, attempts: int) -> float:
    """The wait before attempt ``attempts + 1`` after a transient failure: doubling from
    ``retry_backoff_seconds``, at most ``retry_backoff_max_seconds``."""
    doubled = settings.retry_backoff_seconds * 2.0 ** max(attempts - 1, 0)
    return float(min(doubled, settings.retry_backoff_max_seconds))


def gave_up(step: str, attempts: int, last: str | None) -> str:
    """The reason of a mission whose ``step`` began ``attempts`` times and never finished."""
    why = (
        f"; the last stopped with: {last}"
        if last
        else (
            ": each time its worker process ended before it finished (killed, out of memory or "
            "crashed)"
        )
    )
    return f"{step}: gave up after {attempts} attempts{why}. LTLNAV_MAX_ATTEMPTS sets how many"


def retry_step(
    settings: Settings,
    mission_id: str,
    moves: tuple[MissionStatus, MissionStatus],
    attempt: int,
    error: BaseException,
    send_again: Callable[..., None],
) -> bool:
    """After a transient ``error`` of a mission's step (planning or assembly), move the
    mission back (``moves``: from, to) and send the step again after a backoff; whether it
    was transient."""
    if not is_transient(error):
        return False
    wait = backoff_seconds(settings, attempt)
    reason = f"attempt {attempt} stopped ({describe(error)}); trying again in {wait:.0f} s"
    with database_for(settings).session() as session:
        if not repository.requeue_mission(session, mission_id, *moves, reason):
            return True
    send(lambda: send_again(mission_id, countdown=wait), mission_id)
    return True


@contextmanager
def failing(
    db: Database,
    mission_id: str,
    what: str,
    job: tuple[int, int] | None = None,
    retry: Callable[[BaseException], bool] | None = None,
) -> Iterator[None]:
    """Turn any error of the block into a ``failed`` mission (and job ``(id, fencing
    token)``) with the reason, unless ``retry(error)`` put the work back for a later attempt
    (it returns True then) or the attempt no longer holds the job (a stale attempt writes
    nothing: the job's current attempt decides); re-raise only if nothing can be written."""
    try:
        yield
    except Exception as error:
        log.exception("%s of mission %s failed", what, mission_id)
        try:
            if retry is not None and retry(error):
                return
            reason = f"{what}: {describe(error)}"
            if job is not None:
                with db.session() as session:
                    if not repository.holds_job(session, job[0], job[1]):
                        # a later attempt owns the job: this stale one records nothing
                        log.warning("job %d: a stale attempt's error not recorded", job[0])
                        return
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
        folder = mission_dir(settings, mission_id)
        run = MissionRun.open(document, folder, limits=settings.admission_limits())
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
