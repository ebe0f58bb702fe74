"""``/healthz`` answers from the health monitor's last probe: health checks open no
connections, the probe runs off the request path, and no password reaches the answer."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.api import health
from service.api.app import create_app
from service.db import Database, upgrade
from service.jobs import celery_app
from tests.service.api_helpers import RecordingEnqueue, settings_for


class CountingProbe:
    """Stands in for ``broker_ok``: counts the broker connections it would open."""

    def __init__(self, answer: bool = True, error: Exception | None = None) -> None:
        self.calls = 0
        self.answer = answer
        self.error = error
        self._lock = threading.Lock()

    def __call__(self, settings: object, timeout: float = 2.0) -> bool:
        with self._lock:
            self.calls += 1
        if self.error is not None:
            raise self.error
        return self.answer


@pytest.fixture
def sqlite_db(sqlite_url: str) -> Database:
    upgrade(sqlite_url)
    return Database(sqlite_url)


def _app(tmp_path: Path, database: Database, probe_seconds: float = 60.0) -> TestClient:
    settings = settings_for(tmp_path, database.url).model_copy(
        update={"health_probe_seconds": probe_seconds}
    )
    return TestClient(create_app(settings, RecordingEnqueue(database)))


def test_fifty_health_checks_open_at_most_one_broker_connection(
    tmp_path: Path, sqlite_db: Database, monkeypatch: pytest.MonkeyPatch
) -> None:
    probe = CountingProbe()
    monkeypatch.setattr(celery_app, "broker_ok", probe)
    with _app(tmp_path, sqlite_db) as http:  # the lifespan starts the monitor's thread
        with ThreadPoolExecutor(8) as pool:
            answers = list(pool.map(lambda _: http.get("/healthz"), range(50)))
        assert {a.status_code for a in answers} == {200}
        assert {a.json()["broker"] for a in answers} == {"ok"}
    assert probe.calls <= 1


def test_without_the_thread_one_request_probes_for_all(
    tmp_path: Path, sqlite_db: Database, monkeypatch: pytest.MonkeyPatch
) -> None:
    probe = CountingProbe()
    monkeypatch.setattr(celery_app, "broker_ok", probe)
    http = _app(tmp_path, sqlite_db)  # no lifespan: the cache is refreshed on demand
    with ThreadPoolExecutor(8) as pool:
        answers = list(pool.map(lambda _: http.get("/healthz"), range(50)))
    assert {a.status_code for a in answers} == {200}
    assert probe.calls == 1


def test_the_thread_probes_every_interval(
    tmp_path: Path, sqlite_db: Database, monkeypatch: pytest.MonkeyPatch
) -> None:
    probe = CountingProbe()
    monkeypatch.setattr(celery_app, "broker_ok", probe)
    with _app(tmp_path, sqlite_db, probe_seconds=0.1) as http:
        assert http.get("/healthz").status_code == 200
        probe.answer = False
        for _ in range(100):
            if http.get("/healthz").status_code == 503:
                break
            time.sleep(0.05)
        down = http.get("/healthz")
        assert down.status_code == 503
        assert down.json()["broker"] == "down"
    assert probe.calls >= 2


def test_a_failed_probe_is_checked_again_within_seconds_not_a_whole_interval(
    tmp_path: Path, sqlite_db: Database, monkeypatch: pytest.MonkeyPatch
) -> None:
    probe = CountingProbe(answer=False)  # e.g. a cold broker that misses the first timeout
    monkeypatch.setattr(celery_app, "broker_ok", probe)
    with _app(tmp_path, sqlite_db, probe_seconds=60.0) as http:
        assert http.get("/healthz").status_code == 503
        probe.answer = True
        deadline = time.monotonic() + 5 * health.RECHECK_SECONDS
        while http.get("/healthz").status_code != 200:
            assert time.monotonic() < deadline, "still 503 after the re-check"
            time.sleep(0.05)
        calls = probe.calls
        time.sleep(2 * health.RECHECK_SECONDS)
        assert probe.calls == calls  # healthy again: back to one probe per interval


def test_no_password_in_the_health_report(
    tmp_path: Path, sqlite_db: Database, monkeypatch: pytest.MonkeyPatch
) -> None:
    error = ConnectionError("cannot reach redis://:hunter2@redis:6379/0")
    monkeypatch.setattr(celery_app, "broker_ok", CountingProbe(error=error))
    answer = _app(tmp_path, sqlite_db).get("/healthz")
    assert answer.status_code == 503
    assert "hunter2" not in answer.text
    assert "redis://:***@redis:6379/0" in answer.json()["problems"]["broker"]
