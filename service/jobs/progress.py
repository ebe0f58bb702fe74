"""What a training task writes to the database while it runs: heartbeats, progress, the
learning curve and checkpoints, and the cancel flag it reads.

``JobMonitor`` supplies the hooks of ``workers.training.train_subtask``: ``on_progress`` writes
progress at most every ``heartbeat_seconds`` (curve points and checkpoints as soon as they
appear) and ``should_stop`` answers from a flag a background thread refreshes, so training never
waits on the database. The thread also keeps the heartbeat going through the parts of a job
without hooks (loading, the final evaluation) and notices when the reconciler handed the job
to another worker (then the job stops and writes nothing more).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, suppress
from pathlib import Path

import numpy as np
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session

from service import repository
from service.db import Database
from workers.callbacks import checkpoints
from workers.residual import recorded_start

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


class JobMonitor:
    """Database side of one running job (see the module docstring)."""

    def __init__(
        self,
        db: Database,
        mission_id: str,
        job_id: int,
        worker: str,
        out_dir: Path,
        heartbeat_seconds: float,
        check_seconds: float = 0.5,
    ) -> None:
        self.db, self.mission_id, self.job_id, self.worker = db, mission_id, job_id, worker
        self.out_dir = out_dir
        self.heartbeat_seconds = heartbeat_seconds
        self.check_seconds = min(check_seconds, heartbeat_seconds)
        self.cancelled = threading.Event()
        self.lost = threading.Event()
        self._last_write = -np.inf
        self._last_beat = time.monotonic()
        self._curve_upto: int | None = None
        self._checkpoints: set[int] = set()
        self._npz_mtime = 0.0
        self._started: tuple[float, int] | None = None
        self._drop_after: int | None = None
        self._points: list[tuple[int, int, float, float | None]] = []
        self._saved: list[tuple[int, Path]] = []

    @property
    def stopping(self) -> bool:
        """Whether the job should stop (cancelled, or no longer ours)."""
        return self.cancelled.is_set() or self.lost.is_set()

    def should_stop(self) -> bool:
        """The ``should_stop`` hook."""
        return self.stopping

    def check(self) -> None:
        """One round of the background thread: read the cancel flag, beat when due."""
        with self.db.session() as session:
            if repository.halted(session, self.mission_id):
                self.cancelled.set()
            now = time.monotonic()
            if now - self._last_beat >= self.heartbeat_seconds:
                self._last_beat = now
                if not repository.holds_job(session, self.job_id, self.worker, beat=True):
                    self.lost.set()

    @contextmanager
    def running(self) -> Iterator[JobMonitor]:
        """Run the background thread for the block."""
        with beating(self.check_seconds, self.check):
            yield self

    def on_progress(self, steps: int, success_rate: float | None, total: int) -> None:
        """The ``on_progress`` hook: throttled progress, new curve points and checkpoints.
        A database error is logged and the writes are tried again at the next call: a blip
        of the database does not end hours of training."""
        first = self._curve_upto is None
        if first:
            # The resume point: later points will be redone, and the evaluations file still
            # holds those of the run that died: wait for this run to rewrite it. A fresh run
            # redoes its step-0 point too.
            self._curve_upto = steps if steps > 0 else -1
            self._drop_after = self._curve_upto
            with suppress(FileNotFoundError):
                self._npz_mtime = (self.out_dir / "evaluations.npz").stat().st_mtime
            start = recorded_start(self.out_dir) if steps == 0 else None
            if start is not None:  # written by this run before its first progress call
                self._points.append((0, start.episodes, start.success_rate, None))
        now = time.monotonic()
        fresh = self._collect()
        if not (
            first or fresh or steps >= total or now - self._last_write >= self.heartbeat_seconds
        ):
            return
        self._last_write = now
        try:
            with self.db.session() as session:
                if not repository.holds_job(session, self.job_id, self.worker):
                    self.lost.set()
                    return
                self._write_pending(session)
                remaining = max(total - steps, 0)
                repository.record_progress(
                    session, self.job_id, steps, success_rate, self._eta(steps, remaining)
                )
        except DBAPIError as error:
            log.warning("progress of job %d not written (tried again): %s", self.job_id, error)
            return
        self._clear_pending()
        self._last_beat = now

    def flush(self) -> None:
        """Write the curve points and checkpoints not yet recorded (at the end of a run)."""
        if not self._collect() and self._drop_after is None:
            return
        with self.db.session() as session:
            self._write_pending(session)
        self._clear_pending()

    def _collect(self) -> bool:
        """Add new curve points and checkpoints to the pending writes; whether any."""
        points, saved = self._new_curve_points(), self._new_checkpoints()
        self._points.extend(points)
        self._saved.extend(saved)
        return bool(points or saved)

    def _write_pending(self, session: Session) -> None:
        if self._drop_after is not None:
            repository.drop_evaluations_after(session, self.job_id, self._drop_after)
        for point in self._points:
            repository.record_evaluation(session, self.mission_id, self.job_id, *point)
        for at, path in self._saved:
            repository.record_checkpoint(session, self.job_id, at, str(path))

    def _clear_pending(self) -> None:
        self._drop_after = None
        self._points.clear()
        self._saved.clear()

    def _eta(self, steps: int, remaining: int) -> float | None:
        if self._started is None:
            self._started = (time.monotonic(), steps)
            return None
        t0, s0 = self._started
        rate = (steps - s0) / max(time.monotonic() - t0, 1e-9)
        return remaining / rate if rate > 0 else None

    def _new_curve_points(self) -> list[tuple[int, int, float, float | None]]:
        """``(steps, episodes, success_rate, mean_return)`` of evaluations not yet written."""
        path = self.out_dir / "evaluations.npz"
        try:
            mtime = path.stat().st_mtime
        except FileNotFoundError:
            return []
        if mtime == self._npz_mtime:
            return []
        try:
            with np.load(path) as data:
                steps = data["timesteps"].tolist()
                results = data["results"]
                successes = data.get("successes", None)
        except (OSError, ValueError, KeyError, EOFError):
            return []  # being rewritten: read it next time
        self._npz_mtime = mtime
        upto = self._curve_upto if self._curve_upto is not None else -1
        out: list[tuple[int, int, float, float | None]] = []
        for k, at in enumerate(steps):
            if at <= upto:
                continue
            returns = np.asarray(results[k], dtype=float)
            rate = float(np.mean(successes[k])) if successes is not None else 0.0
            mean_return = float(np.mean(returns)) if returns.size else None
            out.append((int(at), int(returns.size), rate, mean_return))
        if out:
            self._curve_upto = out[-1][0]
        return out

    def _new_checkpoints(self) -> list[tuple[int, Path]]:
        found = [
            (steps, path)
            for path, _buffer, steps in checkpoints(self.out_dir / "checkpoints")
            if steps not in self._checkpoints
        ]
        self._checkpoints.update(steps for steps, _ in found)
        return sorted(found)
