"""The hand-over repair jobs of the assemble step (``workers.handover_repair``), run one after
the other in the assembling worker: their progress goes to the mission's news (``reason``
while evaluating, and a ``news`` event), and a cancelled or ended mission stops them."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from sqlalchemy.exc import DBAPIError

from service import repository
from service.db import Database
from workers.training import TrainResult, train_subtask
from workers.training_spec import SubtaskJob

log = logging.getLogger(__name__)


class RepairCancelledError(Exception):
    """A repair job stopped: the mission was cancelled (or ended) meanwhile."""


class RepairMonitor:
    """``run`` for ``workers.pipeline.finish``: trains a round's repair jobs with progress
    news at most every ``news_seconds`` and the mission's cancel flag as their stop hook."""

    def __init__(self, db: Database, mission_id: str, news_seconds: float) -> None:
        self.db, self.mission_id, self.news_seconds = db, mission_id, news_seconds
        self._last_news = -float("inf")
        self._doing = ""

    def run(self, batch: list[tuple[SubtaskJob, Path, int]]) -> list[TrainResult]:
        """Train the round's jobs; ``RepairCancelledError`` when one of them was stopped."""
        results = []
        for position, (job, target, _) in enumerate(batch, 1):
            self._doing = f"sub-task {job.subtask} ({position} of {len(batch)})"
            self._last_news = -float("inf")
            result = train_subtask(job, target, self.on_progress, self.should_stop)
            if result.stopped == "cancelled":
                raise RepairCancelledError(f"hand-over repair of {self._doing} stopped")
            results.append(result)
        return results

    def on_progress(self, steps: int, success_rate: float | None, total: int) -> None:
        """News of the running repair job; a database error only delays it."""
        now = time.monotonic()
        if steps < total and now - self._last_news < self.news_seconds:
            return
        success = "" if success_rate is None else f", success {success_rate:.0%}"
        news = f"hand-over repair of {self._doing}: {steps} of {total} steps{success}"
        try:
            with self.db.session() as session:
                repository.set_news(session, self.mission_id, news)
        except DBAPIError as error:
            log.warning("repair news of mission %s not written: %s", self.mission_id, error)
            return
        self._last_news = now

    def should_stop(self) -> bool:
        """Whether the mission was cancelled or ended (the training's ``StopOnRequest`` asks
        at most twice a second); a database error reads as not yet."""
        try:
            with self.db.session() as session:
                return repository.halted(session, self.mission_id)
        except DBAPIError as error:
            log.warning("cancel flag of mission %s not read: %s", self.mission_id, error)
            return False
