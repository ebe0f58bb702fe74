"""Reconcile the database (the truth) with the queue (which can lose messages).

The embedded brokers lose the messages a worker held when its main process dies (SIGKILL),
Redis gives them back only after the visibility timeout (hours), and a chord callback is lost
with its worker. Every worker therefore runs ``reconcile_forever`` in a thread; each pass:

- cancels missions with a cancel request and no running job;
- re-queues jobs marked running whose heartbeat is stale and sends them again (they resume
  from their checkpoints), except right after the database was unreachable, when every
  heartbeat is stale (``OutageWatch``);
- sends planning / assembly again for missions whose planner or assembler stopped beating;
- when the broker queue was empty at two passes in a row, sends again missions and jobs
  still queued for a while (their messages were lost), and assembles missions whose jobs
  are all done but which are still training (a lost callback: while the queue holds work,
  the callback may be waiting behind it, and sending another every pass under a backlog
  piled up duplicate assemblies in the broker faster than the workers drained them);
- every ``broker_cleanup_seconds``, deletes consumed rows of the SQLAlchemy broker, expired
  results, and what ``service.jobs.retention`` says has expired.

Every claim is a compare-and-set in the database, so several workers reconciling at once
send each piece of work once.
"""

from __future__ import annotations

import logging
import random
import threading
import time
from dataclasses import dataclass, field

from celery import Celery
from sqlalchemy import Engine, inspect, text
from sqlalchemy.exc import DBAPIError

from service import repository
from service.db import make_engine
from service.jobs.celery_app import QUEUE, LtlnavCelery, is_sqla
from service.jobs.common import Dispatch, database_for
from service.jobs.retention import prune_expired
from service.models import MissionStatus
from service.redact import redact_urls
from service.settings import Settings

log = logging.getLogger(__name__)


@dataclass
class Reconciled:
    """What one pass sent again."""

    cancelled: list[str] = field(default_factory=list)
    jobs: list[tuple[str, int, int]] = field(default_factory=list)
    """``(mission id, sub-task index, repair round)`` of the jobs sent again."""
    plans: list[str] = field(default_factory=list)
    assemblies: list[str] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.cancelled or self.jobs or self.plans or self.assemblies)


def reconcile_once(
    settings: Settings, dispatch: Dispatch, drained: bool = False, reclaim: bool = True
) -> Reconciled:
    """One reconciliation pass (see the module docstring). ``drained``: the broker queue was
    found empty (long enough that queued work without a message is lost, not in flight).
    ``reclaim`` False: stale heartbeats are not trusted yet (``OutageWatch``), so no running
    job and no planning or assembling mission is taken back."""
    db = database_for(settings)
    out = Reconciled()
    # First, while the jobs re-queued below are not yet sent: queued work whose message is
    # gone (nothing waits in the broker).
    if drained:
        with db.session() as session:
            queued = repository.claim_queued_missions(session, settings.requeue_after_seconds)
            out.plans = [m.id for m in queued]
            lost = repository.claim_queued_jobs(session, settings.requeue_after_seconds)
            out.jobs = [(job.mission_id, job.index, job.repair_round) for job in lost]
    with db.session() as session:
        out.cancelled = repository.cancel_idle_missions(session)
    if reclaim:
        with db.session() as session:
            stale = repository.reclaim_stale_jobs(session, settings.stale_after_seconds)
            out.jobs.extend((job.mission_id, job.index, job.repair_round) for job in stale)
        with db.session() as session:
            stalled = repository.reclaim_stalled_missions(session, settings.stale_after_seconds)
            for mission in stalled:  # planning -> queued, evaluating -> training
                stage = out.plans if mission.status == MissionStatus.queued else out.assemblies
                stage.append(mission.id)
    if drained:  # a callback behind a backlog is not lost (see the module docstring)
        with db.session() as session:
            ready = repository.claim_assemblies(session, settings.requeue_after_seconds)
            out.assemblies.extend(m.id for m in ready)
    for mission_id, index, repair_round in out.jobs:
        dispatch.train(mission_id, index, repair_round)
    for mission_id in out.plans:
        dispatch.plan(mission_id)
    for mission_id in out.assemblies:
        dispatch.assemble(mission_id)
    if out:
        log.info("reconciled: %s", out)
    return out


class DrainWatch:
    """Whether the broker queue was empty at two looks in a row: only then is queued work
    without a message lost (a message a worker has just taken is not yet claimed)."""

    def __init__(self) -> None:
        self._empty_before = False

    def drained(self, size: int | None) -> bool:
        """Take one look (``size`` None: the broker could not be asked)."""
        empty = size == 0
        drained = empty and self._empty_before
        self._empty_before = empty
        return drained


class OutageWatch:
    """Whether stale heartbeats can be trusted. While the database was unreachable no live job
    could write its heartbeat either: right after an outage longer than
    ``stale_after_seconds`` every running job looks dead. So after a pass that could not reach
    the database, the reconciler reclaims nothing until ``grace`` seconds (the staleness
    limit: every live job has beaten by then) after it reached the database again."""

    def __init__(self, grace: float) -> None:
        self.grace = grace
        self._regained: float | None = -float("inf")
        """When the database answered again after a failed pass (None: it has not yet)."""

    def failed(self) -> None:
        """A pass could not reach the database."""
        self._regained = None

    def may_reclaim(self) -> bool:
        """Whether this pass may take back jobs and missions with stale heartbeats."""
        now = time.monotonic()
        if self._regained is None:
            self._regained = now
        return now - self._regained >= self.grace


def queue_size(app: Celery) -> int | None:
    """Messages waiting in the service's queue (None when the broker cannot be asked)."""
    try:
        with app.connection_for_write() as connection:
            declared = connection.default_channel.queue_declare(queue=QUEUE, passive=False)
            return int(declared.message_count)
    except Exception as error:
        log.warning("cannot read the broker queue size: %s", redact_urls(str(error)))
        return None


_broker_engines: dict[str, Engine] = {}


def clean_broker(settings: Settings) -> int:
    """Delete the consumed messages kombu's SQLAlchemy transport keeps (``visible`` false);
    returns how many. Nothing to do on other brokers."""
    if not is_sqla(settings.broker_url):
        return 0
    url = settings.broker_url.split("+", 1)[1]
    engine = _broker_engines.get(url)
    if engine is None:
        engine = _broker_engines[url] = make_engine(url)
    with engine.begin() as connection:
        if not inspect(connection).has_table("kombu_message"):
            return 0
        outcome = connection.execute(
            text("DELETE FROM kombu_message WHERE visible = :no"), {"no": False}
        )
        return int(outcome.rowcount or 0)


def reconcile_forever(app: LtlnavCelery, stop: threading.Event) -> None:
    """Reconcile every ``reconcile_seconds`` until ``stop`` is set (a worker's thread)."""
    from service.jobs.tasks import CeleryDispatch

    settings = app.settings
    dispatch = CeleryDispatch(app)
    last_cleanup = -float("inf")
    # Workers started together should not reconcile in lockstep.
    stop.wait(random.uniform(0, min(1.0, settings.reconcile_seconds)))
    watch = DrainWatch()
    outages = OutageWatch(settings.stale_after_seconds)
    while not stop.is_set():
        try:
            drained = watch.drained(queue_size(app))
            reconcile_once(settings, dispatch, drained, reclaim=outages.may_reclaim())
            if time.monotonic() - last_cleanup >= settings.broker_cleanup_seconds:
                last_cleanup = time.monotonic()
                removed = clean_broker(settings)
                app.backend.cleanup()
                if removed:
                    log.info("deleted %d consumed broker messages", removed)
                prune_expired(settings)
        except DBAPIError as error:  # database down or not migrated: no traceback each pass
            outages.failed()
            log.warning("reconciliation failed (database): %s", error.orig)
        except Exception:
            log.exception(
                "reconciliation failed; trying again in %.0f s", settings.reconcile_seconds
            )
        stop.wait(settings.reconcile_seconds)
