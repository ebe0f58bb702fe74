"""The JSON API on SQLite and PostgreSQL: submission, reads, cancel, artefacts, auth, paging.

A recording enqueue stands in for Celery; ``advance`` moves missions as the workers would."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from starlette.types import Message, Receive, Scope, Send

from service.api import health, system
from service.db import Database
from service.models import MissionStatus
from tests.service.api_helpers import (
    PARTS,
    PLAN,
    RecordingEnqueue,
    advance,
    bearer,
    client,
    settings_for,
    tiny,
)


@dataclass
class Api:
    app: FastAPI
    http: TestClient
    enqueue: RecordingEnqueue
    database: Database
    artifacts: Path

    def submit(self, **headers: str) -> str:
        response = self.http.post("/missions", json=tiny(), headers=headers or None)
        assert response.status_code == 201, response.text
        mission_id: str = response.json()["id"]
        return mission_id


@pytest.fixture
def api(database: Database, tmp_path: Path) -> Iterator[Api]:
    """The open API on each database."""
    enqueue = RecordingEnqueue(database)
    settings = settings_for(tmp_path, database.url)
    from service.api.app import create_app

    app = create_app(settings, enqueue)
    with TestClient(app) as http:
        yield Api(app, http, enqueue, database, settings.artifact_dir)


@pytest.fixture
def keyed(database: Database, tmp_path: Path) -> Iterator[Api]:
    """The API with two keys, alpha and beta; its client sends none."""
    enqueue = RecordingEnqueue(database)
    settings = settings_for(tmp_path, database.url, keys=["alpha", "beta"])
    from service.api.app import create_app

    app = create_app(settings, enqueue)
    with TestClient(app) as http:
        yield Api(app, http, enqueue, database, settings.artifact_dir)


def test_submit_commits_then_enqueues_and_reads_back(api: Api) -> None:
    response = api.http.post("/missions", json=tiny())
    assert response.status_code == 201
    body = response.json()
    mission_id = body["id"]
    assert body["status"] == "queued"
    assert body["links"]["self"] == f"/missions/{mission_id}"
    assert body["links"]["bundle"] == f"/missions/{mission_id}/bundle"
    assert api.enqueue.calls == [mission_id]
    assert api.enqueue.committed == [True]
    mission = api.http.get(f"/missions/{mission_id}").json()
    assert mission["name"] == "tiny-gf2"
    assert mission["task"] == tiny()["task"]
    assert mission["robot"] == "point"
    assert (mission["status"], mission["plan"], mission["jobs"], mission["evaluation"]) == (
        "queued",
        None,
        [],
        None,
    )


def test_submit_example_by_name(api: Api) -> None:
    response = api.http.post("/missions", json={"example": "car-phi2-fin"})
    assert response.status_code == 201
    mission = api.http.get(response.json()["links"]["self"]).json()
    assert (mission["name"], mission["robot"]) == ("car-phi2-fin", "unicycle")
    examples = api.http.get("/examples").json()["examples"]
    assert {"name": "car-phi2-fin", "task": mission["task"], "robot": "unicycle"} in examples


def test_enqueue_failure_still_answers_201_and_keeps_the_mission(
    api: Api, caplog: pytest.LogCaptureFixture
) -> None:
    api.enqueue.fail = True
    with caplog.at_level(logging.ERROR):
        response = api.http.post("/missions", json=tiny())
    assert response.status_code == 201
    mission_id = response.json()["id"]
    assert api.http.get(f"/missions/{mission_id}").json()["status"] == "queued"
    assert "reconciler" in caplog.text


def test_progress_plan_curve_and_bundle(api: Api) -> None:
    mission_id = api.submit()
    base = f"/missions/{mission_id}"
    assert api.http.get(f"{base}/plan.png").status_code == 404
    assert api.http.get(f"{base}/subtasks/0/curve").status_code == 404
    assert api.http.get(f"{base}/bundle").status_code == 409

    advance(api.database, mission_id, api.artifacts, MissionStatus.training)
    mission = api.http.get(base).json()
    assert mission["status"] == "training"
    assert mission["plan"] == PLAN
    assert [(j["index"], j["status"], j["steps_done"]) for j in mission["jobs"]] == [
        (0, "running", 100),
        (1, "running", 100),
    ]
    assert mission["jobs"][0]["success_rate"] == 0.5
    assert mission["jobs"][0]["eta_seconds"] == 3.0
    assert mission["jobs"][0]["seconds"] is None and mission["jobs"][0]["time_by_part"] is None
    assert mission["jobs"][0]["attempts"] == 1
    assert mission["links"]["curves"] == [f"{base}/subtasks/0/curve", f"{base}/subtasks/1/curve"]
    picture = api.http.get(f"{base}/plan.png")
    assert (picture.status_code, picture.headers["content-type"]) == (200, "image/png")
    assert picture.content.startswith(b"\x89PNG")
    curve = api.http.get(f"{base}/subtasks/0/curve").json()
    assert curve == {
        "index": 0,
        "points": [
            {"steps": 100, "success_rate": 0.0, "mean_return": None, "episodes": 1},
            {"steps": 200, "success_rate": 0.5, "mean_return": None, "episodes": 1},
        ],
    }
    assert api.http.get(f"{base}/subtasks/1/curve").json()["points"] == []
    assert api.http.get(f"{base}/subtasks/2/curve").status_code == 404
    conflict = api.http.get(f"{base}/bundle")
    assert conflict.status_code == 409
    assert "training" in conflict.json()["detail"]

    advance(api.database, mission_id, api.artifacts, MissionStatus.done)
    mission = api.http.get(base).json()
    assert mission["status"] == "done"
    assert mission["evaluation"] == {"episodes": 2, "success_rate": 1.0}
    assert mission["jobs"][1]["final"] == {"success_rate": 1.0, "episodes": 2}
    assert mission["jobs"][1]["seconds"] == 12.5 and mission["jobs"][1]["time_by_part"] == PARTS
    bundle = api.http.get(f"{base}/bundle")
    assert bundle.status_code == 200
    assert bundle.headers["content-type"] == "application/zip"
    assert "tiny-gf2-bundle.zip" in bundle.headers["content-disposition"]
    assert bundle.content.startswith(b"PK")


def test_responses_are_sent_without_a_database_session(api: Api) -> None:
    """The request's session ends with its handler: no connection is held while a response,
    a file above all, is sent."""
    mission_id = api.submit()
    advance(api.database, mission_id, api.artifacts, MissionStatus.done)
    pool = api.app.state.services.database.engine.pool
    held: list[int] = []

    async def watched(scope: Scope, receive: Receive, send: Send) -> None:
        async def watching_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                held.append(pool.checkedout())
            await send(message)

        await api.app(scope, receive, watching_send)

    http = TestClient(watched)
    for path in ("", "/plan.png", "/subtasks/0/curve", "/bundle"):
        assert http.get(f"/missions/{mission_id}{path}").status_code == 200
    assert http.post(f"/missions/{mission_id}/cancel").status_code == 409
    assert held == [0] * 5


def test_failed_mission_reports_its_reason(api: Api) -> None:
    mission_id = api.submit()
    advance(api.database, mission_id, api.artifacts, MissionStatus.failed)
    mission = api.http.get(f"/missions/{mission_id}").json()
    assert mission["status"] == "failed"
    assert "unsatisfiable" in mission["reason"]
    assert api.http.get(f"/missions/{mission_id}/bundle").status_code == 409


def test_cancel_queued_then_twice(api: Api) -> None:
    mission_id = api.submit()
    first = api.http.post(f"/missions/{mission_id}/cancel")
    assert first.status_code == 202
    assert first.json()["status"] == "cancelled"
    assert first.json()["cancel_requested"] is True
    second = api.http.post(f"/missions/{mission_id}/cancel")
    assert second.status_code == 409
    assert "already cancelled" in second.json()["detail"]


def test_cancel_running_is_cooperative(api: Api) -> None:
    mission_id = api.submit()
    advance(api.database, mission_id, api.artifacts, MissionStatus.training)
    first = api.http.post(f"/missions/{mission_id}/cancel")
    assert first.status_code == 202
    assert (first.json()["status"], first.json()["cancel_requested"]) == ("training", True)
    again = api.http.post(f"/missions/{mission_id}/cancel")
    assert again.status_code == 409
    assert "already requested" in again.json()["detail"]


def test_cancel_final_mission_conflicts(api: Api) -> None:
    mission_id = api.submit()
    advance(api.database, mission_id, api.artifacts, MissionStatus.done)
    response = api.http.post(f"/missions/{mission_id}/cancel")
    assert response.status_code == 409
    assert response.json() == {"detail": "the mission is already done"}


def test_list_is_paged_newest_first(api: Api) -> None:
    ids = [api.submit() for _ in range(3)]
    page = api.http.get("/missions", params={"limit": 2}).json()
    assert (page["total"], page["limit"], page["offset"]) == (3, 2, 0)
    assert [m["id"] for m in page["items"]] == ids[::-1][:2]
    rest = api.http.get("/missions", params={"limit": 2, "offset": 2}).json()
    assert [m["id"] for m in rest["items"]] == ids[:1]
    api.http.post(f"/missions/{ids[1]}/cancel")
    cancelled = api.http.get("/missions", params={"status": "cancelled"}).json()
    assert [m["id"] for m in cancelled["items"]] == [ids[1]]
    for params in ({"limit": 0}, {"limit": 101}, {"offset": -1}, {"status": "nope"}):
        assert api.http.get("/missions", params=params).status_code == 422


@pytest.mark.parametrize(
    "path",
    [
        "/missions/{id}",
        "/missions/{id}/plan.png",
        "/missions/{id}/subtasks/0/curve",
        "/missions/{id}/events?once=1",
        "/missions/{id}/bundle",
    ],
)
def test_unknown_ids_are_404(api: Api, path: str) -> None:
    for mission_id in ("00000000-0000-4000-8000-000000000000", "nope", "x" * 300):
        response = api.http.get(path.format(id=mission_id))
        assert response.status_code == 404, (mission_id, response.text)
        assert "no mission" in response.json()["detail"]
    assert api.http.post("/missions/nope/cancel").status_code == 404


def test_keys_required_and_missions_private(keyed: Api, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(health, "broker_state", lambda settings: ("ok", None))
    http = keyed.http
    assert http.get("/missions").status_code == 401
    assert http.post("/missions", json=tiny()).status_code == 401
    denied = http.get("/missions", headers=bearer("gamma"))
    assert denied.status_code == 401
    assert denied.headers["www-authenticate"].startswith("Bearer")
    assert keyed.enqueue.calls == []

    mine = keyed.submit(**bearer("alpha"))
    assert http.get(f"/missions/{mine}", headers=bearer("alpha")).status_code == 200
    for path in ("", "/plan.png", "/subtasks/0/curve", "/bundle", "/events?once=1"):
        assert http.get(f"/missions/{mine}{path}", headers=bearer("beta")).status_code == 404
    assert http.post(f"/missions/{mine}/cancel", headers=bearer("beta")).status_code == 404
    assert http.get("/missions", headers=bearer("beta")).json()["total"] == 0
    assert http.get("/missions", headers=bearer("alpha")).json()["total"] == 1
    assert http.get("/healthz").json()["open"] is False


def test_open_api_warns_at_start_up(
    database: Database, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from service.api.app import create_app

    app = create_app(settings_for(tmp_path, database.url), RecordingEnqueue(database))
    with caplog.at_level(logging.WARNING, logger="ltlnav.api"), TestClient(app):
        pass
    assert "the API is open" in caplog.text


def test_healthz(api: Api, monkeypatch: pytest.MonkeyPatch) -> None:
    monitor = api.app.state.services.health  # /healthz reads its last probe
    monkeypatch.setattr(health, "broker_state", lambda settings: ("ok", None))
    monitor.refresh()
    ok = api.http.get("/healthz")
    assert ok.status_code == 200
    assert ok.json() == {
        "status": "ok",
        "api": "ok",
        "database": "ok",
        "broker": "ok",
        "open": True,
        "problems": {},
    }
    monkeypatch.setattr(health, "broker_state", lambda settings: ("down", "no answer"))
    monitor.refresh()
    down = api.http.get("/healthz")
    assert down.status_code == 503
    assert (down.json()["broker"], down.json()["problems"]) == ("down", {"broker": "no answer"})


def test_healthz_database_down_and_reads_are_503(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from service.api.app import create_app

    monkeypatch.setattr(health, "broker_state", lambda settings: ("ok", None))
    url = "postgresql+psycopg://postgres@127.0.0.1:9/nowhere"
    app = create_app(settings_for(tmp_path, url), lambda mission_id: None)
    http = client(app)
    report = http.get("/healthz")
    assert report.status_code == 503
    assert report.json()["database"] == "down"
    response = http.get("/missions")
    assert response.status_code == 503
    assert "database is unavailable" in response.json()["detail"]


def test_broker_state_without_worker_code(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "service.jobs.celery_app", None)
    state, problem = health.broker_state(settings_for(tmp_path, "sqlite://"))
    assert state == "unknown"
    assert problem is not None and "worker code" in problem


def test_dashboard_served_when_installed(
    api: Api, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    static = tmp_path / "static"
    monkeypatch.setattr(system, "STATIC_DIR", static)
    assert api.http.get("/").status_code == 404
    static.mkdir()
    (static / "index.html").write_text("<html>ltlnav</html>")
    page = api.http.get("/")
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    assert "ltlnav" in page.text


def test_openapi_documents_every_route(api: Api) -> None:
    schema = api.http.get("/openapi.json").json()
    assert set(schema["paths"]) >= {
        "/missions",
        "/missions/{mission_id}",
        "/missions/{mission_id}/plan.png",
        "/missions/{mission_id}/subtasks/{index}/curve",
        "/missions/{mission_id}/events",
        "/missions/{mission_id}/cancel",
        "/missions/{mission_id}/bundle",
        "/healthz",
        "/examples",
    }
    components = schema["components"]["schemas"]
    assert {"MissionSpec", "ExampleRequest", "MissionView", "Problems"} <= set(components)
    body = schema["paths"]["/missions"]["post"]["requestBody"]["content"]["application/json"]
    assert {"$ref": "#/components/schemas/MissionSpec"} in body["schema"]["oneOf"]
    assert api.http.get("/docs").status_code == 200


def test_openapi_body_examples_are_accepted(api: Api) -> None:
    schema = api.http.get("/openapi.json").json()
    body = schema["paths"]["/missions"]["post"]["requestBody"]["content"]["application/json"]
    assert set(body["examples"]) == {"mission", "example"}
    for example in body["examples"].values():
        response = api.http.post("/missions", json=example["value"])
        assert response.status_code == 201, response.text
    assert "HTTPValidationError" not in schema["components"]["schemas"]  # 422s are Problems


def test_unmigrated_database_says_so(tmp_path: Path) -> None:
    from service.api.app import create_app

    app = create_app(settings_for(tmp_path, f"sqlite:///{tmp_path / 'empty.db'}"), print)
    response = client(app).get("/missions")
    assert response.status_code == 503
    assert "ltlnav migrate" in response.json()["detail"]
