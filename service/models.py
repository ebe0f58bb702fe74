"""The service's state: missions, their sub-task jobs, checkpoints, evaluations and events.

The database is the source of truth for mission and job state (Celery only carries work).
Artifacts live on disk under ``Settings.artifact_dir``; rows keep their paths. The schema is
created by the Alembic migrations in ``migrations/``, which must match these models exactly.
"""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Dialect,
    Enum,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}
"""Named constraints: SQLite batch migrations can only drop constraints that have a name."""

JSONDocument = JSON().with_variant(JSONB(), "postgresql")
"""JSON on SQLite, JSONB on PostgreSQL."""


def utcnow() -> datetime:
    """The current time, timezone-aware UTC."""
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """A timestamp stored in UTC and always read back timezone-aware (SQLite drops zones)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError(f"naive datetime {value!r}: pass a timezone-aware one")
        return value.astimezone(UTC)

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


class MissionStatus(StrEnum):
    """Life cycle of a mission: queued -> planning -> training -> evaluating -> done, or
    failed / cancelled from any non-final state."""

    queued = "queued"
    planning = "planning"
    training = "training"
    evaluating = "evaluating"
    done = "done"
    failed = "failed"
    cancelled = "cancelled"


class JobStatus(StrEnum):
    """Life cycle of one sub-task's training job."""

    queued = "queued"
    running = "running"
    done = "done"
    failed = "failed"
    cancelled = "cancelled"


def _enum(cls: type[StrEnum], name: str) -> Enum:
    # Stored as plain strings (no PostgreSQL enum type, no CHECK): new states need no DDL.
    return Enum(
        cls,
        name=name,
        native_enum=False,
        create_constraint=False,
        length=16,
        values_callable=lambda members: [m.value for m in members],
    )


class Base(DeclarativeBase):
    """Declarative base with the naming convention and the shared column types."""

    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map = {  # noqa: RUF012 (SQLAlchemy reads it at class creation)
        datetime: UTCDateTime(),
        dict[str, Any]: JSONDocument,
    }


class Mission(Base):
    """One submitted mission document and where it is in its life cycle."""

    __tablename__ = "missions"
    __table_args__ = (
        Index("ix_missions_owner_created", "owner", "created_at", "id"),
        Index("ix_missions_status_updated", "status", "updated_at"),
        Index("ix_missions_owner_idempotency_key", "owner", "idempotency_key"),
    )

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=lambda: str(uuid.uuid4()))
    owner: Mapped[str | None] = mapped_column(String(64))
    """SHA-256 (hex) of the API key that created it; None when the API was open."""
    name: Mapped[str] = mapped_column(String(200))
    document: Mapped[dict[str, Any]]
    """The validated mission document as submitted (JSON)."""
    status: Mapped[MissionStatus] = mapped_column(
        _enum(MissionStatus, "mission_status"), default=MissionStatus.queued
    )
    reason: Mapped[str | None] = mapped_column(Text)
    """Why the mission failed or was cancelled (or other news about its last transition)."""
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    plan: Mapped[dict[str, Any] | None]
    """Summary of the plan (automaton sizes, lasso, sub-tasks) once planned."""
    plan_image: Mapped[str | None] = mapped_column(String(1024))
    """Path of the plan picture (PNG) under the artifact directory."""
    evaluation: Mapped[dict[str, Any] | None]
    """``MissionEvaluation.to_json()`` of the whole-mission rollouts."""
    bundle_path: Mapped[str | None] = mapped_column(String(1024))
    """Path of ``bundle.zip`` once assembled."""
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    """Set by a cancel request; training hooks read it and stop cooperatively."""
    repairs: Mapped[list[Any] | None] = mapped_column(JSONDocument)
    """``RepairRound.to_json()`` of every hand-over repair round judged so far."""
    plan_attempts: Mapped[int] = mapped_column(Integer, default=0)
    """How many times a worker began planning it (a crash mid-plan counts one)."""
    assembly_attempts: Mapped[int] = mapped_column(Integer, default=0)
    """How many times a worker began assembling it (each round's assembly counts anew)."""
    idempotency_key: Mapped[str | None] = mapped_column(String(200))
    """The ``Idempotency-Key`` it was submitted with: a repeat from the same API key gets it."""

    jobs: Mapped[list[Job]] = relationship(
        back_populates="mission",
        order_by="(Job.repair_round, Job.index)",
        lazy="selectin",
        cascade="all, delete-orphan",
        passive_deletes=True,
    )


class Job(Base):
    """Training of one sub-task of a mission in one round (one Celery ``train_subtask``
    task): round 0 is the sub-task's own training, round ``r > 0`` its ``r``-th hand-over
    repair (``workers.handover_repair``)."""

    __tablename__ = "jobs"
    __table_args__ = (
        UniqueConstraint(
            "mission_id", "index", "repair_round", name="uq_jobs_mission_id_index_round"
        ),
        Index("ix_jobs_status_heartbeat", "status", "heartbeat_at"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    mission_id: Mapped[str] = mapped_column(ForeignKey("missions.id", ondelete="CASCADE"))
    index: Mapped[int] = mapped_column(Integer)
    """Sub-task index in the plan (0-based)."""
    repair_round: Mapped[int] = mapped_column(Integer, default=0)
    """0: the sub-task's training; r > 0: its hand-over repair in round r."""
    spec: Mapped[dict[str, Any] | None]
    """``SubtaskJob.to_json()`` of a repair job (its starts and warm start); None in round 0,
    whose job the mission run derives from the plan."""
    status: Mapped[JobStatus] = mapped_column(
        _enum(JobStatus, "job_status"), default=JobStatus.queued
    )
    reason: Mapped[str | None] = mapped_column(Text)
    budget: Mapped[int] = mapped_column(Integer)
    """Training budget in environment steps."""
    steps_done: Mapped[int] = mapped_column(Integer, default=0)
    success_rate: Mapped[float | None] = mapped_column(Float)
    """Latest periodic evaluation's success rate."""
    eta_seconds: Mapped[float | None] = mapped_column(Float)
    heartbeat_at: Mapped[datetime | None]
    """Last sign of life of the worker running it (None before it started)."""
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    """How many times a worker started it (above 1: redelivered or reconciled). The value a
    claim set is that attempt's fencing token: every write of the attempt requires it."""
    not_before: Mapped[datetime | None]
    """A job put back after a transient failure waits until then (backoff)."""
    worker: Mapped[str | None] = mapped_column(String(255))
    """Hostname / process of the worker that runs or ran it."""
    result: Mapped[dict[str, Any] | None]
    """``TrainResult.to_json()`` once finished."""
    out_dir: Mapped[str] = mapped_column(String(1024))
    """Its folder under the artifact directory (checkpoints, model, curves)."""

    mission: Mapped[Mission] = relationship(back_populates="jobs")


class Checkpoint(Base):
    """A saved model of a job after ``steps`` environment steps (resume point)."""

    __tablename__ = "checkpoints"
    __table_args__ = (UniqueConstraint("job_id", "steps", name="uq_checkpoints_job_id_steps"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"))
    steps: Mapped[int] = mapped_column(Integer)
    path: Mapped[str] = mapped_column(String(1024))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Evaluation(Base):
    """One evaluation point: of a job during training (``job_id`` set; the learning curve)
    or of the whole mission (``job_id`` None)."""

    __tablename__ = "evaluations"
    __table_args__ = (
        Index("ix_evaluations_job_steps", "job_id", "steps"),
        Index("ix_evaluations_mission_id", "mission_id"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    mission_id: Mapped[str] = mapped_column(ForeignKey("missions.id", ondelete="CASCADE"))
    job_id: Mapped[int | None] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"))
    steps: Mapped[int] = mapped_column(Integer)
    episodes: Mapped[int] = mapped_column(Integer)
    success_rate: Mapped[float] = mapped_column(Float)
    mean_return: Mapped[float | None] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Event(Base):
    """Something that happened to a mission, in order (the Server-Sent Events feed)."""

    __tablename__ = "events"
    __table_args__ = (Index("ix_events_mission_id_id", "mission_id", "id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    mission_id: Mapped[str] = mapped_column(ForeignKey("missions.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(32))
    """``status``, ``progress``, ``checkpoint``, ``evaluation``, ``cancel``, ..."""
    payload: Mapped[dict[str, Any]]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
