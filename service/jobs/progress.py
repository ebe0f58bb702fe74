"""What a training task writes to the database while it runs: heartbeats, progress, the
learning curve and checkpoints, and the cancel flag it reads.

``JobMonitor`` is the job's ``workers.hooks.TrainingHooks``: it stores what the job tells it
(it reads no file the job writes). ``progress`` is written at most every ``heartbeat_seconds``,
curve points and checkpoints as soon as they come; ``should_stop`` answers from a flag a
background thread refreshes, so training never waits on the database. The thread also keeps
the heartbeat going through the parts of a job without hooks (loading, the final evaluation)
and notices when the reconciler handed the job to another worker (then the job stops and
writes nothing more). Every write carries the attempt's fencing token (``Job.attempts`` as
the claim set it): rows through ``repository.holds_job`` in the same transaction, files through
``may_write`` right before the job writes them.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path

import numpy as np
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session

from service import repository
from service.db import Database
from workers.hooks import CurvePoint, TrainingHooks

log = logging.getLogger(__name__)


@contextmanager
def beating(every: float, beat: Callable[[], None]) -> Iterator[None]:
    """Call ``beat()`` every ``every`` seconds in a thread while the block runs (errors are
    logged: a missed beat is not worth failing the work for)."""
    stop = threading.Event()

    def loop() -> None:
        while not stop.wait(every):
            try:
                beat()
            except DBAPIError as error:
                log.warning("heartbeat not written: %s", error.orig)
            except Exception:
                log.exception("heartbeat failed")

    thread = threading.Thread(target=loop, daemon=True, name="ltlnav-heartbeat")
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def mission_heartbeat(db: Database, mission_id: str, every: float) -> AbstractContextManager[None]:
    """``beating`` that refreshes a mission's ``updated_at`` (planning, assembling)."""

    def beat() -> None:
        with db.session() as session:
            repository.touch_mission(session, mission_id)

    return beating(every, beat)


class JobMonitor(TrainingHooks):
    """Database side of one running job (see the module docstring)."""

    def __init__(
        self,
        db: Database,
        mission_id: str,
        job_id: int,
        token: int,
        heartbeat_seconds: float,
        check_seconds: float = 0.5,
    ) -> None:
        self.db, self.mission_id, self.job_id, self.token = db, mission_id, job_id, token
        self.heartbeat_seconds = heartbeat_seconds
        self.check_seconds = min(check_seconds, heartbeat_seconds)
        self.cancelled = threading.Event()
        self.lost = threading.Event()
        self._last_write = -np.inf
        self._last_beat = time.monotonic()
        self._started: tuple[float, int] | None = None
        self._drop_after: int | None = None
        self._points: list[CurvePoint] = []
        self._saved: list[tuple[int, Path]] = []
        self._latest: tuple[int, float | None, int] | None = None
        """The last progress not yet written (throttled)."""
        self._evaluating: str | None = None
        """The evaluation the job runs once its training has ended, not yet written."""
        self._trained = False
        """Whether the job's training has ended (no time left to estimate from steps)."""

    @property
    def stopping(self) -> bool:
        """Whether the job should stop (cancelled, or no longer ours)."""
        return self.cancelled.is_set() or self.lost.is_set()

    def should_stop(self) -> bool:
        return self.stopping

    def check(self) -> None:
        """One round of the background thread: read the cancel flag, beat when due."""
        with self.db.session() as session:
            if repository.halted(session, self.mission_id):
                self.cancelled.set()
            now = time.monotonic()
            if now - self._last_beat >= self.heartbeat_seconds:
                self._last_beat = now
                if not repository.holds_job(session, self.job_id, self.token):
                    self.lost.set()

    @contextmanager
    def running(self) -> Iterator[JobMonitor]:
        """Run the background thread for the block."""
        with beating(self.check_seconds, self.check):
            yield self

    def may_write(self) -> bool:
        """Whether this attempt still owns the job (its fencing token is current), asked
        before each file the job writes. A database that cannot be asked leaves the last
        known answer: the job goes on through an outage."""
        if self.lost.is_set():
            return False
        try:
            with self.db.session() as session:
                if not repository.holds_job(session, self.job_id, self.token):
                    self.lost.set()
        except DBAPIError as error:
            log.warning("job %d: ownership not checked (database): %s", self.job_id, error)
        return not self.lost.is_set()

    def resumed(self, steps: int) -> None:
        """Curve points after the resume point will be made again: drop the stored ones (a
        fresh start drops them all, its step-0 point included)."""
        self._drop_after = steps if steps > 0 else -1

    def curve_point(self, point: CurvePoint) -> None:
        self._points.append(point)
        self._write()

    def checkpoint(self, steps: int, path: Path) -> None:
        self._saved.append((steps, path))
        self._write()

    def progress(self, steps: int, success_rate: float | None, total: int) -> None:
        """Throttled progress (and the pending curve points and checkpoints). A database
        error is logged and the writes are tried again at the next call: a blip of the
        database does not end hours of training."""
        now = time.monotonic()
        first = self._started is None
        self._latest = (steps, success_rate, total)
        if first or steps >= total or now - self._last_write >= self.heartbeat_seconds:
            self._write()

    def evaluating(self, what: str) -> None:
        """Written at once: the job's reason names the evaluation, its ETA is cleared."""
        self._evaluating, self._trained = what, True
        self._write()

    def flush(self) -> None:
        """Write what is not yet recorded (at the end of a run): the last progress, curve
        points and checkpoints."""
        pending = self._latest or self._points or self._saved or self._evaluating
        if pending or self._drop_after is not None:
            self._write()

    def _record_progress(self, session: Session) -> None:
        if self._latest is None:
            return
        steps, success_rate, total = self._latest
        eta = None if self._trained else self._eta(steps, max(total - steps, 0))
        repository.record_progress(session, self.job_id, steps, success_rate, eta)

    def _write(self) -> None:
        """Write what is pending if the job is still ours."""
        now = time.monotonic()
        try:
            with self.db.session() as session:
                if not repository.holds_job(session, self.job_id, self.token):
                    self.lost.set()
                    return
                if self._drop_after is not None:
                    repository.drop_evaluations_after(session, self.job_id, self._drop_after)
                for p in self._points:
                    repository.record_evaluation(
                        session,
                        self.mission_id,
                        self.job_id,
                        p.steps,
                        p.episodes,
                        p.success_rate,
                        p.mean_return,
                    )
                for at, path in self._saved:
                    repository.record_checkpoint(session, self.job_id, at, str(path))
                self._record_progress(session)
                if self._evaluating is not None:
                    repository.record_evaluating(session, self.job_id, self._evaluating)
        except DBAPIError as error:
            log.warning("progress of job %d not written (tried again): %s", self.job_id, error)
            return
        self._drop_after = self._latest = self._evaluating = None
        self._points.clear()
        self._saved.clear()
        self._last_write = self._last_beat = now

    def _eta(self, steps: int, remaining: int) -> float | None:
        if self._started is None:
            self._started = (time.monotonic(), steps)
            return None
        t0, s0 = self._started
        rate = (steps - s0) / max(time.monotonic() - t0, 1e-9)
        return remaining / rate if rate > 0 else None
