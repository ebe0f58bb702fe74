"""Admission of state-changing requests: only JSON (415; cross-site 403), per-key quotas (429
with Retry-After), and ``Idempotency-Key`` (one mission per key, also under concurrency), on
SQLite and PostgreSQL."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select, update

from service import repository as repo
from service.api.app import create_app
from service.db import Database
from service.models import Mission, utcnow
from tests.service.api_helpers import RecordingEnqueue, bearer, settings_for, tiny

ALPHA, BETA = bearer("alpha"), bearer("beta")


def _http(
    database: Database, tmp_path: Path, keys: tuple[str, ...] = ("alpha", "beta"), **quotas: Any
) -> TestClient:
    settings = settings_for(tmp_path, database.url, keys=keys).model_copy(update=quotas)
    return TestClient(create_app(settings, RecordingEnqueue(database)))


def _count(database: Database) -> int:
    with database.session() as session:
        return session.scalar(select(func.count()).select_from(Mission)) or 0


@pytest.fixture
def http(database: Database, tmp_path: Path) -> Iterator[TestClient]:
    with _http(database, tmp_path) as client:
        yield client


# --- only JSON ------------------------------------------------------------------------------

JSON_TEXT = httpx.Request("POST", "/", json=tiny()).content


@pytest.mark.parametrize(
    ("content_type", "body"),
    [
        ("text/plain", JSON_TEXT),
        ("text/plain;charset=UTF-8", JSON_TEXT),
        ("application/x-www-form-urlencoded", b"mission=" + JSON_TEXT),
        ("multipart/form-data; boundary=x", b"--x\r\n\r\n" + JSON_TEXT + b"\r\n--x--"),
        ("application/yaml", b"name: x\n"),
        ("application/json; charset=latin-1", JSON_TEXT),
        (None, JSON_TEXT),
    ],
)
def test_a_submission_that_is_not_json_is_415(
    http: TestClient, database: Database, content_type: str | None, body: bytes
) -> None:
    headers = {**ALPHA, **({"content-type": content_type} if content_type else {})}
    response = http.post("/missions", content=body, headers=headers)
    assert response.status_code == 415, response.text
    assert "application/json" in response.json()["detail"]
    assert _count(database) == 0


def test_a_form_post_is_415(http: TestClient, database: Database) -> None:
    response = http.post("/missions", data={"example": "car-phi2-fin"}, headers=ALPHA)
    assert response.status_code == 415
    assert "application/x-www-form-urlencoded" in response.json()["detail"]
    assert _count(database) == 0


def test_json_with_a_utf8_charset_is_accepted(http: TestClient) -> None:
    headers = {**ALPHA, "content-type": "Application/JSON; charset=UTF-8"}
    assert http.post("/missions", content=JSON_TEXT, headers=headers).status_code == 201


def test_cancel_and_delete_check_the_type_too(http: TestClient) -> None:
    mission_id = http.post("/missions", json=tiny(), headers=ALPHA).json()["id"]
    text_plain = {**ALPHA, "content-type": "text/plain"}
    assert http.post(f"/missions/{mission_id}/cancel", headers=text_plain).status_code == 415
    assert http.delete(f"/missions/{mission_id}", headers=text_plain).status_code == 415
    # A body-less request with no type is what the dashboard and curl -X send: accepted.
    assert http.post(f"/missions/{mission_id}/cancel", headers=ALPHA).status_code == 202
    assert http.delete(f"/missions/{mission_id}", headers=text_plain).status_code == 415
    json_type = {**ALPHA, "content-type": "application/json"}
    assert http.delete(f"/missions/{mission_id}", headers=json_type).status_code == 204


def test_a_browser_marked_cross_site_request_is_403(http: TestClient, database: Database) -> None:
    headers = {**ALPHA, "sec-fetch-site": "cross-site"}
    response = http.post("/missions", json=tiny(), headers=headers)
    assert response.status_code == 403
    assert "cross-site" in response.json()["detail"]
    same_origin = {**ALPHA, "sec-fetch-site": "same-origin"}
    assert http.post("/missions", json=tiny(), headers=same_origin).status_code == 201
    assert _count(database) == 1


def test_the_schema_states_the_type_the_quotas_and_the_idempotency_key(http: TestClient) -> None:
    schema = http.get("/openapi.json").json()
    post = schema["paths"]["/missions"]["post"]
    assert set(post["requestBody"]["content"]) == {"application/json"}
    assert {"200", "201", "403", "415", "429"} <= set(post["responses"])
    assert "Retry-After" in post["responses"]["429"]["headers"]
    (key,) = [p for p in post["parameters"] if p["name"] == "Idempotency-Key"]
    assert (key["in"], key["schema"]["anyOf"][0]["maxLength"]) == ("header", 200)
    delete = schema["paths"]["/missions/{mission_id}"]["delete"]
    assert {"204", "404", "409", "415"} <= set(delete["responses"])
    assert "415" in schema["paths"]["/missions/{mission_id}/cancel"]["post"]["responses"]


# --- quotas ---------------------------------------------------------------------------------


def test_missions_at_once_per_key(database: Database, tmp_path: Path) -> None:
    with _http(database, tmp_path, quota_active_missions=2, quota_submissions_per_minute=0) as http:
        first, _ = (http.post("/missions", json=tiny(), headers=ALPHA).json()["id"] for _ in "ab")
        refused = http.post("/missions", json=tiny(), headers=ALPHA)
        assert refused.status_code == 429
        assert refused.headers["retry-after"].isdigit()
        assert "LTLNAV_QUOTA_ACTIVE_MISSIONS=2" in refused.json()["detail"]
        assert "2 missions queued or running" in refused.json()["detail"]
        assert _count(database) == 2
        assert http.post("/missions", json=tiny(), headers=BETA).status_code == 201
        assert http.post(f"/missions/{first}/cancel", headers=ALPHA).status_code == 202
        assert http.post("/missions", json=tiny(), headers=ALPHA).status_code == 201


def test_submissions_per_minute_per_key(database: Database, tmp_path: Path) -> None:
    with _http(database, tmp_path, quota_active_missions=0, quota_submissions_per_minute=3) as http:
        for _ in range(3):
            assert http.post("/missions", json=tiny(), headers=ALPHA).status_code == 201
        refused = http.post("/missions", json={"example": "car-phi2-fin"}, headers=ALPHA)
        assert refused.status_code == 429
        assert 1 <= int(refused.headers["retry-after"]) <= 60
        assert "LTLNAV_QUOTA_SUBMISSIONS_PER_MINUTE=3" in refused.json()["detail"]
        assert _count(database) == 3
        assert http.post("/missions", json=tiny(), headers=BETA).status_code == 201
        with database.session() as session:  # a minute later the window is empty again
            earlier = utcnow() - timedelta(seconds=61)
            session.execute(update(Mission).values(created_at=earlier))
        assert http.post("/missions", json=tiny(), headers=ALPHA).status_code == 201


def test_the_open_api_counts_as_one_key(database: Database, tmp_path: Path) -> None:
    with _http(database, tmp_path, keys=(), quota_active_missions=1) as http:
        assert http.post("/missions", json=tiny()).status_code == 201
        refused = http.post("/missions", json=tiny())
        assert refused.status_code == 429
        assert "open API" in refused.json()["detail"]


def test_concurrent_submissions_do_not_overrun_the_quota(
    database: Database, tmp_path: Path
) -> None:
    with (
        _http(database, tmp_path, quota_active_missions=3) as http,
        ThreadPoolExecutor(6) as pool,
    ):
        codes = list(
            pool.map(lambda _: http.post("/missions", json=tiny(), headers=ALPHA), range(6))
        )
    assert sorted(c.status_code for c in codes) == [201] * 3 + [429] * 3
    assert _count(database) == 3


# --- Idempotency-Key ------------------------------------------------------------------------


def test_a_repeated_idempotency_key_returns_the_first_mission(
    http: TestClient, database: Database
) -> None:
    key = {"Idempotency-Key": "order-42"}
    first = http.post("/missions", json=tiny(), headers={**ALPHA, **key})
    assert first.status_code == 201
    again = http.post("/missions", json={"example": "car-phi2-fin"}, headers={**ALPHA, **key})
    assert again.status_code == 200
    assert again.json() == first.json()
    assert again.headers["idempotent-replayed"] == "true"
    other = http.post("/missions", json=tiny(), headers={**ALPHA, "Idempotency-Key": "order-43"})
    assert other.status_code == 201 and other.json()["id"] != first.json()["id"]
    theirs = http.post("/missions", json=tiny(), headers={**BETA, **key})
    assert theirs.status_code == 201 and theirs.json()["id"] != first.json()["id"]
    plain = http.post("/missions", json=tiny(), headers=ALPHA)
    assert plain.status_code == 201
    assert _count(database) == 4
    with database.session() as session:
        mission = repo.get_mission(session, first.json()["id"])
        assert mission is not None and mission.idempotency_key == "order-42"


def test_an_idempotency_key_expires_after_its_window(
    http: TestClient, database: Database, tmp_path: Path
) -> None:
    key = {**ALPHA, "Idempotency-Key": "nightly"}
    first = http.post("/missions", json=tiny(), headers=key).json()["id"]
    hours = settings_for(tmp_path, database.url).idempotency_key_hours
    with database.session() as session, session.begin():
        old = utcnow() - timedelta(hours=hours, minutes=1)
        session.execute(update(Mission).where(Mission.id == first).values(created_at=old))
    again = http.post("/missions", json=tiny(), headers=key)
    assert again.status_code == 201 and again.json()["id"] != first
    replay = http.post("/missions", json=tiny(), headers=key)
    assert (replay.status_code, replay.json()["id"]) == (200, again.json()["id"])
    assert _count(database) == 2


def test_a_replay_is_answered_even_over_the_quota(database: Database, tmp_path: Path) -> None:
    with _http(database, tmp_path, keys=(), quota_active_missions=1) as http:
        key = {"Idempotency-Key": "only-once"}
        first = http.post("/missions", json=tiny(), headers=key)
        again = http.post("/missions", json=tiny(), headers=key)
        assert (first.status_code, again.status_code) == (201, 200)
        assert again.json()["id"] == first.json()["id"]


@pytest.mark.parametrize("key", ["x" * 201, ""])
def test_an_idempotency_key_too_long_or_empty_is_422(
    http: TestClient, database: Database, key: str
) -> None:
    response = http.post("/missions", json=tiny(), headers={**ALPHA, "Idempotency-Key": key})
    assert response.status_code == 422, response.text
    assert response.json()["detail"][0]["loc"] == ["header", "Idempotency-Key"]
    assert _count(database) == 0


@pytest.mark.parametrize("keys", [("alpha", "beta"), ()], ids=["keyed", "open"])
def test_two_concurrent_requests_with_one_key_make_one_mission(
    database: Database,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    keys: tuple[str, ...],
) -> None:
    both_admitted = threading.Barrier(2, timeout=10)
    serialize = repo.serialize_submissions

    def after_both(session: Any, api_key: str | None) -> None:
        both_admitted.wait()  # both passed the early lookup: the race is on
        serialize(session, api_key)

    monkeypatch.setattr(repo, "serialize_submissions", after_both)
    headers = {**(ALPHA if keys else {}), "Idempotency-Key": "retry-me"}
    # One API process admits one submission at a time; two slots stand for two API processes.
    http_client = _http(database, tmp_path, keys=keys, submission_concurrency=2)
    with http_client as http, ThreadPoolExecutor(2) as pool:
        answers = list(
            pool.map(lambda _: http.post("/missions", json=tiny(), headers=headers), range(2))
        )
    assert sorted(a.status_code for a in answers) == [200, 201]
    assert answers[0].json() == answers[1].json()
    assert _count(database) == 1
