"""Server-Sent Events of a mission: the polling form, resuming with Last-Event-ID, and a live
stream over a real server that follows the mission until it is final and then ends."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from service.api import events
from service.api.app import create_app
from service.db import Database, upgrade
from service.models import MissionStatus
from service.settings import Settings
from tests.service.api_helpers import RecordingEnqueue, advance, served, settings_for, tiny


def parse_sse(text: str) -> list[dict[str, Any]]:
    """The events of an SSE body: ``{"event", "id", "data"}`` (comments and retry skipped)."""
    found = []
    for block in text.split("\n\n"):
        fields: dict[str, Any] = {}
        for line in block.splitlines():
            name, _, value = line.partition(": ")
            if name in ("event", "id", "data"):
                fields[name] = json.loads(value) if name == "data" else value
        if "event" in fields:
            found.append(fields)
    return found


@pytest.fixture
def stack(sqlite_url: str, tmp_path: Path) -> Iterator[tuple[Database, Settings]]:
    upgrade(sqlite_url)
    database = Database(sqlite_url)
    yield database, settings_for(tmp_path, sqlite_url)
    database.dispose()


def test_polling_form_and_resume(stack: tuple[Database, Settings]) -> None:
    database, settings = stack
    http = TestClient(create_app(settings, RecordingEnqueue(database)))
    mission_id = http.post("/missions", json=tiny()).json()["id"]
    url = f"/missions/{mission_id}/events"

    first = http.get(url, params={"once": 1})
    assert first.status_code == 200
    assert first.headers["content-type"].startswith("text/event-stream")
    (queued,) = parse_sse(first.text)
    assert queued["event"] == "status"
    assert queued["data"]["payload"] == {"status": "queued", "reason": None}

    advance(database, mission_id, settings.artifact_dir, MissionStatus.training)
    later = parse_sse(
        http.get(url, params={"once": 1}, headers={"Last-Event-ID": queued["id"]}).text
    )
    kinds = [e["event"] for e in later]
    assert kinds[:2] == ["status", "status"]
    assert {"job", "progress"} <= set(kinds)
    assert all(int(e["id"]) > int(queued["id"]) for e in later)
    assert parse_sse(http.get(url, params={"once": 1, "after": later[-1]["id"]}).text) == []
    assert http.get(url, headers={"Last-Event-ID": "abc"}).status_code == 422


def test_stream_of_a_final_mission_ends_with_end(stack: tuple[Database, Settings]) -> None:
    database, settings = stack
    http = TestClient(create_app(settings, RecordingEnqueue(database)))
    mission_id = http.post("/missions", json=tiny()).json()["id"]
    advance(database, mission_id, settings.artifact_dir, MissionStatus.failed)
    received = parse_sse(http.get(f"/missions/{mission_id}/events").text)
    assert [e["event"] for e in received] == ["status", "status", "end"]
    assert received[-1]["data"]["status"] == "failed"
    assert "unsatisfiable" in received[-1]["data"]["reason"]


@pytest.mark.timeout(60)
def test_live_stream_follows_the_mission_to_its_end(
    stack: tuple[Database, Settings], monkeypatch: pytest.MonkeyPatch
) -> None:
    database, settings = stack
    monkeypatch.setattr(events, "POLL_SECONDS", 0.05)
    app = create_app(settings, RecordingEnqueue(database))
    with served(app) as base:
        mission_id = httpx.post(f"{base}/missions", json=tiny()).json()["id"]

        first_seen = threading.Event()
        waited: list[bool] = []

        def work() -> None:
            # The mission moves on only once the client holds its first event: an API that
            # buffered the stream until the end would make this wait time out.
            waited.append(first_seen.wait(15))
            advance(database, mission_id, settings.artifact_dir, MissionStatus.training)
            time.sleep(0.3)
            advance(database, mission_id, settings.artifact_dir, MissionStatus.done)

        worker = threading.Thread(target=work)
        worker.start()
        text = ""
        with httpx.stream("GET", f"{base}/missions/{mission_id}/events", timeout=30) as response:
            assert response.status_code == 200
            for chunk in response.iter_text():
                text += chunk
                if parse_sse(text):
                    first_seen.set()
        worker.join()
    assert waited == [True], "the first event was not streamed before the mission ended"
    received = parse_sse(text)
    statuses = [e["data"]["payload"]["status"] for e in received if e["event"] == "status"]
    assert statuses == ["queued", "planning", "training", "evaluating", "done"]
    assert received[-1]["event"] == "end"
    assert received[-1]["data"]["status"] == "done"
    ids = [int(e["id"]) for e in received if "id" in e]
    assert ids == sorted(ids)
