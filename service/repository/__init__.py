"""Small typed operations on the service's state, shared by the API and the Celery tasks.

Each function works inside the caller's session (``Database.session()``) and flushes but does
not commit, so a caller can group several in one transaction. Missions are scoped by API key:
the API uses ``get_owned_mission`` / ``list_missions``; workers, which hold no key, use
``get_mission``. Status changes and progress also append ``Event`` rows (the SSE feed).

One module per concern: ``missions``, ``jobs``, ``events``, ``quotas`` (per-key submission
limits) and ``recovery`` (the reconciler's claims); every name is importable from
``service.repository``.
"""

from __future__ import annotations

from service.repository.clock import db_now
from service.repository.events import (
    events_after,
    record_event,
)
from service.repository.jobs import (
    NewJob,
    cancel_queued_jobs,
    claim_job,
    create_jobs,
    drop_evaluations_after,
    finish_job,
    get_job,
    heartbeat,
    holds_job,
    latest_checkpoint,
    learning_curve,
    mission_jobs,
    record_checkpoint,
    record_evaluating,
    record_evaluation,
    record_progress,
    requeue_job,
    start_job,
)
from service.repository.missions import (
    FINAL_STATES,
    TRANSITIONS,
    MissionPage,
    NotFoundError,
    TransitionError,
    cancel_requested,
    claim_step,
    create_mission,
    delete_mission,
    find_by_idempotency_key,
    get_mission,
    get_owned_mission,
    halted,
    hash_key,
    holds_step,
    list_missions,
    request_cancel,
    requeue_mission,
    set_news,
    set_plan,
    set_repairs,
    set_result,
    set_status,
    touch_mission,
)
from service.repository.quotas import (
    ACTIVE_STATES,
    QuotaUsage,
    quota_usage,
    serialize_submissions,
)
from service.repository.recovery import (
    cancel_idle_missions,
    claim_assemblies,
    claim_queued_jobs,
    claim_queued_missions,
    missions_ready_to_assemble,
    reclaim_stale_jobs,
    reclaim_stalled_missions,
    stale_jobs,
)

__all__ = [
    "ACTIVE_STATES",
    "FINAL_STATES",
    "TRANSITIONS",
    "MissionPage",
    "NewJob",
    "NotFoundError",
    "QuotaUsage",
    "TransitionError",
    "cancel_idle_missions",
    "cancel_queued_jobs",
    "cancel_requested",
    "claim_assemblies",
    "claim_job",
    "claim_queued_jobs",
    "claim_queued_missions",
    "claim_step",
    "create_jobs",
    "create_mission",
    "db_now",
    "delete_mission",
    "drop_evaluations_after",
    "events_after",
    "find_by_idempotency_key",
    "finish_job",
    "get_job",
    "get_mission",
    "get_owned_mission",
    "halted",
    "hash_key",
    "heartbeat",
    "holds_job",
    "holds_step",
    "latest_checkpoint",
    "learning_curve",
    "list_missions",
    "mission_jobs",
    "missions_ready_to_assemble",
    "quota_usage",
    "reclaim_stale_jobs",
    "reclaim_stalled_missions",
    "record_checkpoint",
    "record_evaluating",
    "record_evaluation",
    "record_event",
    "record_progress",
    "request_cancel",
    "requeue_job",
    "requeue_mission",
    "serialize_submissions",
    "set_news",
    "set_plan",
    "set_repairs",
    "set_result",
    "set_status",
    "stale_jobs",
    "start_job",
    "touch_mission",
]
