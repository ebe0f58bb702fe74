"""What the service deletes by itself after ``keep_failed_days``: the checkpoints (models and
replay buffers, the bulk of the disk) of failed and cancelled missions, and the progress
events of every ended mission (the status, job and news events stay). A mission's record,
results and bundle stay until its owner deletes it (``DELETE /missions/{id}``)."""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

from sqlalchemy import delete, select

from service import repository
from service.jobs.common import database_for
from service.models import Checkpoint, Event, Job, Mission, MissionStatus
from service.settings import Settings

log = logging.getLogger(__name__)

PRUNED_EVENTS = ("progress",)
"""Event kinds deleted from ended missions: the many throttled progress writes."""


@dataclass(frozen=True)
class Pruned:
    """What one pass deleted."""

    checkpoint_folders: int
    events: int


def prune_expired(settings: Settings) -> Pruned:
    """Delete the expired checkpoints and events (see the module docstring)."""
    db = database_for(settings)
    with db.session() as session:
        cutoff = repository.db_now(session) - timedelta(days=settings.keep_failed_days)
        ended = select(Mission.id).where(
            Mission.status.in_([MissionStatus.failed, MissionStatus.cancelled]),
            Mission.updated_at < cutoff,
        )
        jobs = list(
            session.execute(
                select(Job.id, Job.out_dir)
                .where(Job.mission_id.in_(ended))
                .where(select(Checkpoint.id).where(Checkpoint.job_id == Job.id).exists())
            )
        )
        for _, out_dir in jobs:
            shutil.rmtree(Path(out_dir) / "checkpoints", ignore_errors=True)
        if jobs:
            job_ids = [job_id for job_id, _ in jobs]
            session.execute(delete(Checkpoint).where(Checkpoint.job_id.in_(job_ids)))
        final = select(Mission.id).where(
            Mission.status.in_(list(repository.FINAL_STATES)), Mission.updated_at < cutoff
        )
        events = session.execute(
            delete(Event).where(Event.mission_id.in_(final), Event.kind.in_(PRUNED_EVENTS))
        )
        pruned = Pruned(len(jobs), int(getattr(events, "rowcount", 0) or 0))
    if pruned.checkpoint_folders or pruned.events:
        log.info("retention: %s", pruned)
    return pruned
