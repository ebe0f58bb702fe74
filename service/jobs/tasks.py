"""The Celery tasks of a mission: ``plan_mission`` -> chord(group(``train_subtask`` per
sub-task), ``assemble_mission``), and the functions that send them.

The tasks are thin: their work lives in ``service.jobs.planning``, ``.training`` and
``.assembly`` (idempotent, database first). Tasks
are sent by name so the API process needs neither torch nor the task code; ``train_subtask``
messages carry a task id fixed per job so that a resent one stands in for a lost chord
member in the result backend.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from celery import Celery, Task, chord, group, shared_task
from celery.canvas import Signature

from service.jobs.celery_app import LtlnavCelery, make_celery
from service.settings import Settings, get_settings

log = logging.getLogger(__name__)

PLAN = "ltlnav.plan_mission"
TRAIN = "ltlnav.train_subtask"
ASSEMBLE = "ltlnav.assemble_mission"

_apps: dict[str, LtlnavCelery] = {}


def app_for(settings: Settings | None = None) -> LtlnavCelery:
    """The Celery app of ``settings`` (default: the process settings), one per settings."""
    settings = settings or get_settings()
    key = settings.model_dump_json()
    app = _apps.get(key)
    if app is None:
        app = _apps[key] = make_celery(settings)
    return app


def train_task_id(mission_id: str, index: int, repair_round: int = 0) -> str:
    """The fixed Celery task id of a job's training."""
    suffix = f"-repair-{repair_round}" if repair_round else ""
    return f"{mission_id}-train-{index}{suffix}"


class CeleryDispatch:
    """``service.jobs.common.Dispatch`` through a Celery app."""

    def __init__(self, app: Celery) -> None:
        self.app = app

    def _train(self, mission_id: str, index: int, repair_round: int) -> Signature:
        return self.app.signature(
            TRAIN,
            args=(mission_id, index, repair_round),
            immutable=True,
            task_id=train_task_id(mission_id, index, repair_round),
        )

    def training(self, mission_id: str, indices: Sequence[int], repair_round: int = 0) -> None:
        header = group([self._train(mission_id, k, repair_round) for k in indices], app=self.app)
        body = self.app.signature(ASSEMBLE, args=(mission_id,), immutable=True)
        chord(header, body, app=self.app).apply_async()

    def train(
        self, mission_id: str, index: int, repair_round: int = 0, countdown: float = 0.0
    ) -> None:
        self._train(mission_id, index, repair_round).apply_async(countdown=countdown or None)

    def assemble(self, mission_id: str, countdown: float = 0.0) -> None:
        self.app.send_task(ASSEMBLE, args=(mission_id,), countdown=countdown or None)

    def plan(self, mission_id: str, countdown: float = 0.0) -> None:
        self.app.send_task(PLAN, args=(mission_id,), countdown=countdown or None)


def enqueue_mission(mission_id: str, settings: Settings | None = None) -> None:
    """Send ``plan_mission`` for a committed, queued mission. If this raises (broker down),
    the mission stays queued and a worker's reconciler sends it later."""
    CeleryDispatch(app_for(settings)).plan(mission_id)


def _settings(task: Task[Any, Any]) -> Settings:
    app = task.app
    return app.settings if isinstance(app, LtlnavCelery) else get_settings()


@shared_task(bind=True, name=PLAN)
def plan_mission(self: Task[Any, Any], mission_id: str) -> str:
    """Plan the mission, store the plan and its jobs, send the training chord."""
    from service.jobs.planning import plan_step  # the planner and torch: workers only

    outcome = plan_step(_settings(self), mission_id, CeleryDispatch(self.app))
    log.info("plan_mission %s: %s", mission_id, outcome)
    return outcome


@shared_task(bind=True, name=TRAIN)
def train_subtask(self: Task[Any, Any], mission_id: str, index: int, repair_round: int = 0) -> str:
    """Train one sub-task in one round (resuming from its checkpoints), record the result."""
    from service.jobs.training import train_step

    in_chord = self.request.chord is not None
    dispatch = CeleryDispatch(self.app)
    settings = _settings(self)
    outcome = train_step(settings, mission_id, index, dispatch, in_chord, repair_round)
    log.info("train_subtask %s/%d/%d: %s", mission_id, index, repair_round, outcome)
    return outcome


@shared_task(bind=True, name=ASSEMBLE)
def assemble_mission(self: Task[Any, Any], mission_id: str) -> str:
    """Evaluate the whole mission and write its bundle once every job is done."""
    from service.jobs.assembly import assemble_step

    outcome = assemble_step(_settings(self), mission_id, CeleryDispatch(self.app))
    log.info("assemble_mission %s: %s", mission_id, outcome)
    return outcome
