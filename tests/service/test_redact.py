"""Passwords of URLs never reach the logs: ``redact_url`` / ``redact_urls``, and a broker probe
that fails against a password-protected URL."""

from __future__ import annotations

import logging
import socket
import threading
from pathlib import Path

import pytest

from service.jobs.celery_app import broker_ok
from service.redact import redact_url, redact_urls
from service.settings import Settings


@pytest.mark.parametrize(
    ("url", "shown"),
    [
        ("redis://:s3cret@redis:6379/0", "redis://:***@redis:6379/0"),
        (
            "postgresql+psycopg://ltlnav:pw@db:5432/ltlnav",
            "postgresql+psycopg://ltlnav:***@db:5432/ltlnav",
        ),
        ("rediss://user:p%40ss@[::1]:6380/1", "rediss://user:***@[::1]:6380/1"),
        ("redis://redis:6379/0?password=s3cret&ssl=1", "redis://redis:6379/0?password=***&ssl=1"),
        ("redis://user@redis:6379/0", "redis://user@redis:6379/0"),
        ("sqla+sqlite:////data/broker.db", "sqla+sqlite:////data/broker.db"),
        ("not a url", "not a url"),
    ],
)
def test_redact_url(url: str, shown: str) -> None:
    assert redact_url(url) == shown


def test_redact_urls_in_free_text() -> None:
    text = "Error connecting to redis://:s3cret@h:6379/0; tried amqp://guest:guest@x// too"
    redacted = redact_urls(text)
    assert "s3cret" not in redacted and "guest@" not in redacted
    assert "redis://:***@h:6379/0" in redacted
    assert "amqp://guest:***@x//" in redacted


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return port


def test_a_failing_broker_probe_logs_no_password(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    secret = "hunter2-broker-secret"
    url = f"redis://:{secret}@127.0.0.1:{_closed_port()}/0"
    settings = Settings(data_dir=tmp_path, broker_url=url, result_backend=url)
    with caplog.at_level(logging.WARNING, logger="service.jobs.celery_app"):
        assert broker_ok(settings, timeout=2.0) is False
        for thread in threading.enumerate():  # the probe may log after its timeout
            if thread.name == "ltlnav-broker-probe":
                thread.join(20)
    assert "unreachable" in caplog.text, caplog.text
    assert "127.0.0.1" in caplog.text
    assert secret not in caplog.text
