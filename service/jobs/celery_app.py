"""The Celery application of the service, configured for long CPU-bound training tasks.

``celery -A service.jobs.celery_app worker`` runs a worker on the environment's settings;
``run_worker(settings)`` does the same from Python (``ltlnav worker``, ``ltlnav serve``). Each
worker also runs the reconciler (``service.jobs.reconcile``) in a thread of its main process.

Brokers: the default ``sqla+sqlite`` (kombu's SQLAlchemy transport, no server; polled every
``broker_polling_interval``) or Redis. Redis redelivers a task unacknowledged for
``visibility_timeout``, which is kept above the hard time limit so a long training does not
run twice. The database result backend polls ``AsyncResult.get()`` every 0.5 s unless given
``interval``; the service never waits on results (the database holds the state).
"""

from __future__ import annotations

import importlib
import logging
import os
import threading
from pathlib import Path
from typing import Any

from celery import Celery
from celery.signals import worker_init, worker_ready, worker_shutdown
from kombu import Connection
from kombu.transport import sqlalchemy as kombu_sqla

from service.jobs import embedded_broker
from service.jobs.priority import lower_priority
from service.redact import redact_url, redact_urls
from service.settings import Settings, get_settings

log = logging.getLogger(__name__)

QUEUE = "ltlnav"
"""The one queue of the service's tasks."""

TASK_MODULES = ["service.jobs.tasks"]

PRELOAD = ("workers.training", "workers.bundle", "planner.plot", "torch._dynamo")
"""Modules a worker imports before its pool forks: torch, stable-baselines3, matplotlib, and
torch._dynamo, which the first optimizer of every process would import (about 5 s)."""


class LtlnavCelery(Celery):
    """A Celery app that knows the service settings it was made from (tasks read them)."""

    settings: Settings


def is_redis(url: str) -> bool:
    """Whether ``url`` names a Redis server (``redis://``, ``rediss://``, ``redis+socket://``)."""
    return url.split("://", 1)[0].split("+", 1)[0] in ("redis", "rediss")


def is_sqla(url: str) -> bool:
    """Whether ``url`` selects kombu's SQLAlchemy transport (``sqla+...``)."""
    return url.startswith(("sqla+", "sqlalchemy+"))


def sqlite_file(url: str) -> Path | None:
    """The file of a (possibly prefixed) SQLite URL, else None."""
    scheme, _, rest = url.partition(":///")
    if scheme.split("+")[-1] != "sqlite" or not rest or rest.startswith(":memory:"):
        return None
    return Path(rest)


def prepare_dirs(settings: Settings) -> None:
    """Create the data and artifact directories and the folders of SQLite broker/result files."""
    settings.make_dirs()
    for url in (settings.broker_url, settings.result_backend):
        path = sqlite_file(url)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)


def _dispose_kombu_engines() -> None:
    # kombu caches one engine per URL at class level; a forked child must not share its pool.
    for engine, _sessions in list(kombu_sqla.Channel._engines.values()):
        engine.dispose(close=False)


os.register_at_fork(after_in_child=_dispose_kombu_engines)
embedded_broker.install()


def celery_config(settings: Settings) -> dict[str, Any]:
    """The Celery configuration for ``settings`` (see the module docstring)."""
    config: dict[str, Any] = {
        "broker_url": settings.broker_url,
        "result_backend": settings.result_backend,
        "task_default_queue": QUEUE,
        "task_serializer": "json",
        "result_serializer": "json",
        "accept_content": ["json"],
        "result_accept_content": ["json"],
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "worker_prefetch_multiplier": 1,
        "worker_concurrency": settings.concurrency,
        "task_time_limit": settings.task_time_limit,
        "task_soft_time_limit": settings.soft_time_limit,
        "broker_connection_retry_on_startup": True,
        "worker_hijack_root_logger": False,
        "visibility_timeout": settings.redis_visibility_timeout,
        "result_chord_retry_interval": 1.0,
        # A lost chord member would make chord_unlock poll forever; the reconciler assembles.
        "task_annotations": {
            "celery.chord_unlock": {"max_retries": int(4 * settings.task_time_limit)}
        },
    }
    if is_redis(settings.broker_url):
        config["broker_transport_options"] = {
            "visibility_timeout": settings.redis_visibility_timeout,
            "unacked_restore_interval": settings.unacked_restore_interval,
        }
    if is_redis(settings.result_backend):
        config["result_backend_transport_options"] = {
            "visibility_timeout": settings.redis_visibility_timeout
        }
    if sqlite_file(settings.result_backend) is not None:
        config["database_engine_options"] = {"connect_args": {"timeout": 30}}
    return config


def make_celery(settings: Settings | None = None) -> LtlnavCelery:
    """A Celery app for ``settings`` (default: the process settings) with the service's tasks."""
    settings = settings or get_settings()
    if is_sqla(settings.broker_url):
        # Must be the class attribute: broker_transport_options go to create_engine.
        kombu_sqla.Transport.polling_interval = settings.broker_polling_interval
    app = LtlnavCelery("ltlnav", set_as_current=False)
    app.settings = settings
    app.config_from_object(celery_config(settings))
    app.conf.include = TASK_MODULES
    return app


app = make_celery()


def run_worker(
    settings: Settings | None = None, concurrency: int | None = None, loglevel: str = "INFO"
) -> None:
    """Run a worker until it is stopped (``concurrency`` processes, default the cores); its
    main process also reconciles the database with the queue every ``reconcile_seconds``."""
    settings = settings or get_settings()
    lower_priority(settings.worker_nice)
    worker_app = make_celery(settings)
    prepare_dirs(settings)
    argv = [
        "worker",
        f"--concurrency={concurrency or settings.concurrency}",
        f"--loglevel={loglevel}",
        "--pool=prefork",
        f"--hostname=ltlnav-{os.getpid()}@%h",
        f"--queues={QUEUE}",
    ]
    worker_app.worker_main(argv)


def broker_ok(settings: Settings, timeout: float = 2.0) -> bool:
    """Whether the broker answers within ``timeout`` seconds (for ``/healthz``)."""
    outcome: list[bool] = []

    def probe() -> None:
        try:
            if is_sqla(settings.broker_url):
                prepare_dirs(settings)
            with Connection(settings.broker_url, connect_timeout=timeout) as connection:
                connection.ensure_connection(max_retries=1, timeout=timeout)
                connection.default_channel.queue_declare(queue=QUEUE, passive=False)
            outcome.append(True)
        except Exception as error:  # any failure means "not healthy"
            # Both may quote the URL, whose password must not reach the log.
            log.warning(
                "broker %s unreachable: %s",
                redact_url(settings.broker_url),
                redact_urls(str(error)),
            )

    thread = threading.Thread(target=probe, daemon=True, name="ltlnav-broker-probe")
    thread.start()
    thread.join(timeout)
    return bool(outcome)


_reconcilers: dict[int, threading.Event] = {}


@worker_init.connect
def _on_worker_init(sender: Any = None, **_: Any) -> None:
    worker_app = getattr(sender, "app", None)
    if isinstance(worker_app, LtlnavCelery):
        prepare_dirs(worker_app.settings)
        # Import torch and stable-baselines3 once, before the pool forks: a training task
        # then starts at once instead of after seconds of imports in every process.
        for module in PRELOAD:
            importlib.import_module(module)


@worker_ready.connect
def _start_reconciler(sender: Any = None, **_: Any) -> None:
    worker_app = getattr(sender, "app", None)
    if not isinstance(worker_app, LtlnavCelery) or id(worker_app) in _reconcilers:
        return
    from service.jobs.reconcile import reconcile_forever

    stop = threading.Event()
    _reconcilers[id(worker_app)] = stop
    thread = threading.Thread(
        target=reconcile_forever, args=(worker_app, stop), daemon=True, name="ltlnav-reconciler"
    )
    thread.start()


@worker_shutdown.connect
def _stop_reconcilers(**_: Any) -> None:
    for stop in _reconcilers.values():
        stop.set()
