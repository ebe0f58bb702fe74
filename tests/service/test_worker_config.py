"""The Celery configuration for long CPU jobs, the broker health check and sending a mission,
without a worker."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from kombu.transport import sqlalchemy as kombu_sqla
from pydantic import ValidationError

from service.jobs.celery_app import broker_ok, make_celery
from service.jobs.reconcile import queue_size
from service.jobs.tasks import PLAN, app_for, enqueue_mission
from service.settings import Settings


def test_long_cpu_jobs_are_acknowledged_late_one_at_a_time(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, task_time_limit=1000, worker_concurrency=3)
    conf = make_celery(settings).conf
    assert conf.task_acks_late and conf.task_reject_on_worker_lost
    assert conf.worker_prefetch_multiplier == 1 and conf.worker_concurrency == 3
    assert conf.task_serializer == "json" and conf.accept_content == ["json"]
    assert conf.task_time_limit == 1000 and 0 < conf.task_soft_time_limit < 1000


def test_redis_redelivers_only_after_the_hard_time_limit(tmp_path: Path) -> None:
    url = "redis://127.0.0.1:6379/5"
    settings = Settings(data_dir=tmp_path, broker_url=url, result_backend=url)
    conf = make_celery(settings).conf
    limit = conf.task_time_limit
    assert limit == 6 * 3600  # training takes hours
    # the visibility timeout is set in all three places, above the hard limit
    assert conf.broker_transport_options["visibility_timeout"] > limit
    assert conf.result_backend_transport_options["visibility_timeout"] > limit
    assert conf.visibility_timeout > limit
    assert conf.broker_transport_options["unacked_restore_interval"] <= 5


def test_the_embedded_broker_polls_fast_through_the_transport_class(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, broker_polling_interval=0.07)
    conf = make_celery(settings).conf
    assert conf.broker_url.startswith("sqla+sqlite:///")
    # transport options would go to create_engine (TypeError): the class attribute is used
    assert not conf.broker_transport_options
    assert kombu_sqla.Transport.polling_interval == 0.07


def test_limits_must_be_ordered() -> None:
    with pytest.raises(ValidationError, match="visibility_timeout"):
        Settings(task_time_limit=100, visibility_timeout=100)
    with pytest.raises(ValidationError, match="task_soft_time_limit"):
        Settings(task_time_limit=100, task_soft_time_limit=150)
    assert Settings(task_time_limit=100).soft_time_limit == 95


def test_broker_health_and_sending_a_mission_on_the_embedded_broker(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "var")
    assert broker_ok(settings)
    enqueue_mission("m-1", settings)
    assert queue_size(app_for(settings)) == 1
    with app_for(settings).connection_for_read() as connection:
        message = connection.SimpleQueue("ltlnav").get(timeout=2)
        assert message.headers["task"] == PLAN and message.headers["argsrepr"] == "('m-1',)"
        message.ack()


def test_an_unreachable_broker_is_reported_within_the_timeout(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, broker_url="redis://127.0.0.1:1/0")
    started = time.monotonic()
    assert not broker_ok(settings, timeout=1.0)
    assert time.monotonic() - started < 3
