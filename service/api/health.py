"""Liveness of the API's dependencies, the database and the Celery broker, probed off the
request path: ``HealthMonitor`` keeps the last probe and ``/healthz`` reads it.

A probe opens a database connection and a broker connection; answering every health check
with a fresh probe would let anyone who can reach ``/healthz`` (it needs no key) open
connections at will. The monitor's thread probes every ``Settings.health_probe_seconds``
(every ``RECHECK_SECONDS`` while a dependency is unusable);
without the thread (an app used without its lifespan) a stale result is refreshed by one
request while the others wait for it, never by several at once."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError

from service.api.schemas import ComponentState
from service.db import Database
from service.redact import redact_urls
from service.settings import Settings

log = logging.getLogger(__name__)

BROKER_TIMEOUT = 2.0

FIRST_PROBE_WAIT = 10.0
"""How long a health check waits for the first probe after start-up before answering
``unknown``."""

RECHECK_SECONDS = 1.0
"""How soon the thread probes again after a probe that found a dependency unusable (at most
``interval``): a start-up race or a blip is cleared in a second, not a whole interval."""

PROBE_THREAD = "ltlnav-health"
"""The name of the thread that refreshes the probe (``HealthMonitor.start``)."""


def database_state(database: Database) -> tuple[ComponentState, str | None]:
    """Whether ``SELECT 1`` works."""
    try:
        with database.engine.connect() as connection:
            connection.execute(text("SELECT 1"))
    except SQLAlchemyError as error:
        return "down", redact_urls(str(error).splitlines()[0])
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
        message = redact_urls(str(error))
        log.warning("broker check failed: %s", message)
        return "unknown", f"the broker check failed: {message}"
    return ("ok", None) if ok else ("down", "the broker does not answer")


@dataclass(frozen=True)
class Probe:
    """One probe of the database and the broker, and when it ended (``time.monotonic``)."""

    database: ComponentState
    broker: ComponentState
    problems: dict[str, str] = field(default_factory=dict)
    at: float = 0.0

    @property
    def ok(self) -> bool:
        """Whether both dependencies are usable."""
        return self.database == "ok" and self.broker == "ok"


def probe(settings: Settings, database: Database) -> Probe:
    """Probe the database and the broker now."""
    db, db_problem = database_state(database)
    broker, broker_problem = broker_state(settings)
    problems = {
        name: problem
        for name, problem in (("database", db_problem), ("broker", broker_problem))
        if problem
    }
    return Probe(database=db, broker=broker, problems=problems, at=time.monotonic())


class HealthMonitor:
    """The last probe of one app's database and broker, refreshed every ``interval`` seconds
    by a thread between ``start()`` and ``stop()`` (sooner while a dependency is unusable),
    else on demand once it is that old."""

    def __init__(self, settings: Settings, database: Database) -> None:
        self.settings = settings
        self.database = database
        self.interval = settings.health_probe_seconds
        self._last: Probe | None = None
        self._lock = threading.Lock()
        self._first = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def refresh(self) -> Probe:
        """Probe now (after any probe under way) and keep the result."""
        with self._lock:
            return self._store(probe(self.settings, self.database))

    def _store(self, result: Probe) -> Probe:
        self._last = result
        self._first.set()
        return result

    def current(self) -> Probe:
        """The last probe. With the thread running it is never probed here; a result older
        than two intervals plus the probe timeouts means the probe hangs, reported as
        ``unknown``. Without the thread, a result older than ``interval`` is refreshed once."""
        if self._thread is not None and self._thread.is_alive():
            return self._from_thread()
        last = self._last
        if last is not None and time.monotonic() - last.at < self.interval:
            return last
        with self._lock:  # one request probes; the others wait and read its result
            last = self._last
            if last is not None and time.monotonic() - last.at < self.interval:
                return last
            return self._store(probe(self.settings, self.database))

    def _from_thread(self) -> Probe:
        self._first.wait(FIRST_PROBE_WAIT)
        last = self._last
        if last is None:
            problem = "the first health probe has not finished yet"
            return Probe("unknown", "unknown", {"probe": problem}, time.monotonic())
        age = time.monotonic() - last.at
        if age > 2 * self.interval + 2 * BROKER_TIMEOUT + FIRST_PROBE_WAIT:
            problem = f"the health probe has not finished for {age:.0f} s"
            return Probe("unknown", "unknown", {"probe": problem}, last.at)
        return last

    def start(self) -> None:
        """Probe now and every ``interval`` seconds in a daemon thread, until ``stop()``."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True, name=PROBE_THREAD)
        self._thread.start()

    def _run(self) -> None:
        while True:
            try:
                result = self.refresh()
            except Exception as error:  # a probe must never end the monitor
                log.exception("the health probe crashed")
                problem = f"the health probe crashed: {redact_urls(str(error))}"
                result = self._store(
                    Probe("unknown", "unknown", {"probe": problem}, time.monotonic())
                )
            wait = self.interval if result.ok else min(self.interval, RECHECK_SECONDS)
            if self._stop.wait(wait):
                return

    def stop(self) -> None:
        """End the thread (it finishes a probe under way)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=2 * BROKER_TIMEOUT + 1.0)
