"""Service configuration from ``LTLNAV_...`` environment variables (pydantic-settings).

This is the only module of the project that reads the environment. Everything the service
writes (SQLite database, embedded broker and result files, artifacts) defaults to a place
under one data directory, ``LTLNAV_DATA_DIR`` (``./var``), so a fresh machine needs no
server; PostgreSQL and Redis come in through ``DATABASE_URL`` / ``LTLNAV_BROKER_URL``.
"""

from __future__ import annotations

import json
import os
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any

from pydantic import AliasChoices, Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from workers.limits import AdmissionLimits

_LIMITS = AdmissionLimits()


def _sqlite_url(scheme: str, path: Path) -> str:
    return f"{scheme}:///{path}"


def normalise_database_url(url: str) -> str:
    """SQLAlchemy URL for ``url``: the ``postgres://`` / ``postgresql://`` forms that hosting
    platforms hand out select the psycopg (v3) driver, the one the project installs."""
    for prefix in ("postgres://", "postgresql://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url[len(prefix) :]
    return url


class Settings(BaseSettings):
    """Every knob of the service. Paths default to places under ``data_dir``."""

    model_config = SettingsConfigDict(env_prefix="LTLNAV_", extra="ignore")

    data_dir: Path = Path("var")
    """Directory for everything the service writes by default (made absolute)."""

    database_url: str = Field(
        default_factory=lambda data: _sqlite_url("sqlite", data["data_dir"] / "ltlnav.db"),
        validation_alias=AliasChoices("LTLNAV_DATABASE_URL", "DATABASE_URL", "database_url"),
    )
    """SQLAlchemy URL of the state database (``LTLNAV_DATABASE_URL`` or ``DATABASE_URL``).
    Default: SQLite file ``<data_dir>/ltlnav.db``. ``postgres://`` URLs use psycopg 3."""

    broker_url: str = Field(
        default_factory=lambda data: _sqlite_url("sqla+sqlite", data["data_dir"] / "broker.db")
    )
    """Celery broker. Default: kombu's SQLAlchemy transport on ``<data_dir>/broker.db``, which
    needs no server; ``redis://host:6379/0`` for several machines."""

    result_backend: str = Field(
        default_factory=lambda data: _sqlite_url("db+sqlite", data["data_dir"] / "results.db")
    )
    """Celery result backend (chords need one). Default: SQLite ``<data_dir>/results.db``, a
    file apart from the state database so result polling does not contend with it."""

    api_keys: Annotated[list[str], NoDecode] = Field(default_factory=list)
    """Bearer tokens the API accepts, as a JSON list or comma-separated. Each mission belongs
    to the key that created it. Empty: the API is open (the local default)."""

    artifact_dir: Path = Field(default_factory=lambda data: data["data_dir"] / "artifacts")
    """Where checkpoints, curves, pictures and bundles go (their paths are stored in the
    database). Workers on several machines must share it. Default ``<data_dir>/artifacts``."""

    examples_dir: Path = Path(__file__).resolve().parents[1] / "examples"
    """Mission files offered by ``GET /examples`` and ``{"example": name}`` (file stem)."""

    host: str = "127.0.0.1"
    """Address ``ltlnav serve`` binds (``0.0.0.0`` to listen on every interface)."""

    port: int = Field(default=8000, ge=1, le=65535)
    """Port ``ltlnav serve`` listens on."""

    api_processes: int = Field(default=1, ge=1)
    """API processes ``ltlnav serve`` runs on its one port (uvicorn's workers), each with its
    own database pool and cached health probe. One process answers reads and validates
    submissions under one interpreter lock; more help on a machine with cores to spare. On
    2 cores shared with the workers, 2 made the reads' p99 worse during a burst of
    submissions (61 and 93 ms against 49 and 25 ms, ``bench/service.py --load
    --api-processes 1 2 1 2``)."""

    max_body_bytes: int = Field(default=1_000_000, gt=0)
    """Largest accepted request body; larger ones get 413."""

    submission_concurrency: int = Field(default=1, ge=1)
    """Submissions the API validates and stores at once; more wait their turn. Validation is
    CPU work in one Python process: running many at once does not finish them sooner but
    makes every concurrent read wait for the interpreter lock (ten at once took reads of a
    mission from 12 to over 400 ms at the 99th percentile, ``bench/service.py --load``)."""

    # Admission limits (workers.limits.AdmissionLimits): a mission over one is refused with 422
    # by the API and exit code 2 by ``ltlnav validate``/``train``, naming the setting to raise.

    max_world_vertices: int = Field(default=_LIMITS.max_world_vertices, ge=3)
    """Polygon vertices of a world, obstacles and regions together (counted before the
    polygons are built; the simplicity, collision and label tests grow with them)."""

    max_obstacles: int = Field(default=_LIMITS.max_obstacles, ge=0)
    """Obstacles of a world: listed ones plus ``random_obstacles.count``."""

    max_regions: int = Field(default=_LIMITS.max_regions, ge=1)
    """Labelled regions of a world."""

    max_formula_chars: int = Field(default=_LIMITS.max_formula_chars, ge=1)
    """Characters of a mission's task formula."""

    max_temporal_operators: int = Field(default=_LIMITS.max_temporal_operators, ge=1)
    """Temporal operators (U R W G F X) of a task formula."""

    max_automaton_states: int = Field(default=_LIMITS.max_automaton_states, ge=1)
    """States of a task's Büchi automaton pruned for its world, checked when the mission is
    planned (the plan fails with a reason naming this setting)."""

    max_subtasks: int = Field(default=_LIMITS.max_subtasks, ge=1)
    """Sub-tasks of a plan, legs of ``planner.leg_length`` included (one training job each),
    checked when the mission is planned."""

    max_timesteps: int = Field(default=_LIMITS.max_timesteps, ge=1)
    """``training.n_timesteps`` and ``training.handover_steps`` (env steps per sub-task); a
    replay buffer (``buffer_size``) or PPO rollout (``n_steps``) is at most ``n_timesteps``."""

    max_episodes: int = Field(default=_LIMITS.max_episodes, ge=1)
    """``training.eval_episodes``, ``final_eval_episodes`` and ``mission_episodes``."""

    max_evaluations: int = Field(default=_LIMITS.max_evaluations, ge=1)
    """Periodic evaluations per training run: ``eval_freq >= n_timesteps / this``."""

    max_checkpoints: int = Field(default=_LIMITS.max_checkpoints, ge=1)
    """Checkpoints per training run: ``checkpoint_freq >= n_timesteps / this``."""

    max_handover_rounds: int = Field(default=_LIMITS.max_handover_rounds, ge=0)
    """``training.handover_rounds``."""

    max_cycles: int = Field(default=_LIMITS.max_cycles, ge=1)
    """``training.cycles`` (suffix cycles of a mission rollout)."""

    max_episode_steps: int = Field(default=_LIMITS.max_episode_steps, ge=1)
    """``training.env.max_steps``."""

    max_rays: int = Field(default=_LIMITS.max_rays, ge=0)
    """``training.env.rays``."""

    max_planner_seconds: float = Field(default=_LIMITS.max_planner_seconds, gt=0)
    """``planner.time_limit`` and ``planner.refine_seconds`` (CPU seconds)."""

    max_planner_iterations: int = Field(default=_LIMITS.max_planner_iterations, ge=1)
    """``planner.max_iterations`` and ``planner.refine_iterations``."""

    max_net_width: int = Field(default=_LIMITS.max_net_width, ge=1)
    """Units of one layer of ``hyperparams.policy_kwargs.net_arch`` (list or {pi, qf, vf})."""

    max_net_depth: int = Field(default=_LIMITS.max_net_depth, ge=1)
    """Layers of one network of ``net_arch``."""

    max_critics: int = Field(default=_LIMITS.max_critics, ge=1)
    """``policy_kwargs.n_critics`` (SAC, TD3)."""

    max_batch_size: int = Field(default=_LIMITS.max_batch_size, ge=1)
    """``hyperparams.batch_size``."""

    max_gradient_steps: int = Field(default=_LIMITS.max_gradient_steps, ge=1)
    """``hyperparams.gradient_steps`` (off-policy)."""

    max_epochs: int = Field(default=_LIMITS.max_epochs, ge=1)
    """``hyperparams.n_epochs`` (PPO)."""

    heartbeat_seconds: float = Field(default=10.0, gt=0)
    """How often a running job writes its heartbeat (and at most how often its progress)."""

    stale_after_seconds: float = Field(default=60.0, gt=0)
    """A running job whose heartbeat is older than this is taken for dead and re-enqueued."""

    task_time_limit: float = Field(default=6 * 3600.0, gt=0)
    """Hard time limit of a task in seconds (its process is killed): training takes hours."""

    task_soft_time_limit: float | None = Field(default=None, gt=0)
    """Soft limit (the task is told and fails cleanly), below the hard one. None: the hard
    limit minus 5 % (at most 5 minutes less)."""

    visibility_timeout: float | None = Field(default=None, gt=0)
    """Redis redelivers a task unacknowledged this long (seconds): it must exceed the hard
    limit or a long training runs twice. None: the hard limit plus one hour."""

    unacked_restore_interval: float = Field(default=5.0, gt=0)
    """Seconds between Redis sweeps for unacknowledged messages (kombu's default waits ~100 s)."""

    worker_concurrency: int | None = Field(default=None, ge=1)
    """Training processes per worker. None: the number of cores."""

    worker_nice: int = Field(default=10, ge=0, le=19)
    """Niceness a worker adds to itself at start (Unix), and to its session's autogroup when it
    leads its own session (Linux: sessions share the CPU first; ``service.jobs.priority``):
    planning and training are batch work that uses every core, and yield it to the API, the
    dashboard and interactive use of the machine. 0 keeps the priority of the shell that
    started it."""

    broker_polling_interval: float = Field(default=0.05, gt=0)
    """Seconds between polls of the SQLAlchemy (embedded) broker; kombu's 1 s default makes
    every hop of a chord take a second."""

    reconcile_seconds: float = Field(default=5.0, gt=0)
    """How often each worker reconciles the database with the queue (stale jobs, lost
    messages, lost chord callbacks)."""

    requeue_after_seconds: float = Field(default=10.0, gt=0)
    """A mission or job still queued this long while the broker queue stays empty (two
    reconciler passes) lost its message: the reconciler sends it again."""

    broker_cleanup_seconds: float = Field(default=60.0, gt=0)
    """How often consumed messages are deleted from the SQLAlchemy broker's table (kombu keeps
    them forever)."""

    max_attempts: int = Field(default=5, ge=1)
    """A job, a planning or an assembly begun this many times without finishing (killed
    workers, time limits, transient errors) fails, with a reason that says so."""

    retry_backoff_seconds: float = Field(default=5.0, gt=0)
    """After a transient failure (full disk, database or broker unreachable, the soft time
    limit of a job with a checkpoint) the work waits this long, doubled at each attempt."""

    retry_backoff_max_seconds: float = Field(default=300.0, gt=0)
    """The longest wait between attempts after transient failures."""

    keep_failed_days: float = Field(default=7.0, ge=0)
    """Checkpoints (models and replay buffers) of failed and cancelled missions are deleted
    this many days after they ended, and progress events of every ended mission too; the
    mission, its results and ``DELETE /missions/{id}`` are unaffected."""

    idempotency_key_hours: float = Field(default=24.0, gt=0)
    """A repeated ``Idempotency-Key`` answers with its first mission for this long after that
    mission was submitted; afterwards the key makes a new mission (keys are meant for retries
    after a timeout, not as names kept forever)."""

    quota_active_missions: int = Field(default=4, ge=0)
    """Missions one API key may have queued or running (planning, training, evaluating) at
    once; one more is refused with 429 until one ends. A 2-core machine trains two sub-tasks
    at a time, so four missions already queue for a while. 0: no limit. The open API (no
    keys) counts as one key."""

    quota_submissions_per_minute: int = Field(default=10, ge=0)
    """Missions one API key may submit in any 60 seconds (429 with ``Retry-After`` beyond):
    a runaway client is stopped before it floods the queue of the workers. 0: no limit."""

    health_probe_seconds: float = Field(default=5.0, gt=0)
    """How often the API probes the database and the broker for ``/healthz``, off the request
    path (every second while one of them is unusable): a health check reads the last result
    and opens no connection."""

    def admission_limits(self) -> AdmissionLimits:
        """The admission limits (``max_*`` fields) as the workers' plain dataclass."""
        return AdmissionLimits(**{name: getattr(self, name) for name in AdmissionLimits.names()})

    @property
    def soft_time_limit(self) -> float:
        """The soft time limit in effect (see ``task_soft_time_limit``)."""
        if self.task_soft_time_limit is not None:
            return self.task_soft_time_limit
        return max(self.task_time_limit * 0.95, self.task_time_limit - 300.0)

    @property
    def redis_visibility_timeout(self) -> float:
        """The visibility timeout in effect (see ``visibility_timeout``)."""
        if self.visibility_timeout is not None:
            return self.visibility_timeout
        return self.task_time_limit + 3600.0

    @property
    def concurrency(self) -> int:
        """Worker processes in effect (see ``worker_concurrency``)."""
        return self.worker_concurrency or os.cpu_count() or 1

    @field_validator("data_dir", "artifact_dir", "examples_dir")
    @classmethod
    def _absolute(cls, value: Path) -> Path:
        return value.expanduser().absolute()

    @field_validator("database_url")
    @classmethod
    def _driver(cls, value: str) -> str:
        return normalise_database_url(value)

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value: Any) -> Any:
        if isinstance(value, str):
            text = value.strip()
            if text.startswith("["):
                return json.loads(text)
            return [key.strip() for key in text.split(",") if key.strip()]
        return value

    @model_validator(mode="after")
    def _heartbeat_below_stale(self) -> Settings:
        if self.stale_after_seconds <= self.heartbeat_seconds:
            raise ValueError(
                f"stale_after_seconds ({self.stale_after_seconds}) must exceed "
                f"heartbeat_seconds ({self.heartbeat_seconds}), or live jobs look dead"
            )
        return self

    @model_validator(mode="after")
    def _limits_ordered(self) -> Settings:
        if self.soft_time_limit >= self.task_time_limit:
            raise ValueError(
                f"task_soft_time_limit ({self.soft_time_limit}) must be below "
                f"task_time_limit ({self.task_time_limit})"
            )
        if self.redis_visibility_timeout <= self.task_time_limit:
            raise ValueError(
                f"visibility_timeout ({self.redis_visibility_timeout}) must exceed "
                f"task_time_limit ({self.task_time_limit}), or Redis runs long tasks twice"
            )
        return self

    def make_dirs(self) -> None:
        """Create the data and artifact directories."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.artifact_dir.mkdir(parents=True, exist_ok=True)


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings, read once (``get_settings.cache_clear()`` to re-read)."""
    return Settings()
