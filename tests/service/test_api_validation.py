"""Bad submissions: each gets the right 4xx naming the field (or the formula column), nothing
is stored or enqueued, and the missions already there are untouched."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator, MutableMapping
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.body_limit import BodyLimit
from service.api.errors import body_problem
from service.db import Database, upgrade
from tests.service.api_helpers import RecordingEnqueue, settings_for, tiny


@pytest.fixture
def setup(sqlite_url: str, tmp_path: Path) -> Iterator[tuple[TestClient, RecordingEnqueue]]:
    upgrade(sqlite_url)
    database = Database(sqlite_url)
    enqueue = RecordingEnqueue(database)
    with TestClient(create_app(settings_for(tmp_path, sqlite_url), enqueue)) as http:
        yield http, enqueue
    database.dispose()


def _with(**changes: Any) -> dict[str, Any]:
    document = tiny()
    for dotted, value in changes.items():
        *parents, last = dotted.split("__")
        target: Any = document
        for part in parents:
            target = target[int(part)] if part.isdigit() else target[part]
        target[last] = value
    return document


def _problems(response: Any) -> dict[str, dict[str, Any]]:
    return {p.get("field") or "": p for p in response.json()["detail"]}


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        (b'{"name": "x", ', "invalid JSON at line 1, column 15"),
        (b"\n\n{'task': 1}", "invalid JSON at line 3, column 2"),
        (b"", "empty"),
        (b"   ", "empty"),
        (b"\xff\xfe{}", "not UTF-8"),
        (b'{"task": NaN}', "NaN"),
        (b'{"task": 1e400}', "out of range"),
        (b'{"task": "a\\u0000"}', "NUL"),
        (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
    ],
)
def test_malformed_json_is_400(
    setup: tuple[TestClient, RecordingEnqueue], body: bytes, needle: str
) -> None:
    http, enqueue = setup
    response = http.post("/missions", content=body, headers={"content-type": "application/json"})
    assert response.status_code == 400, response.text
    (problem,) = response.json()["detail"]
    assert problem["loc"] == ["body"]
    assert problem["type"] == "json_invalid"
    assert needle in problem["msg"]
    assert enqueue.calls == []


@pytest.mark.parametrize(
    ("document", "field", "needle"),
    [
        (_with(task=5), "task", "must be a string"),
        (_with(robot__radius="big"), "robot.radius", "must be a number"),
        (_with(robot__radius=-1), "robot.radius", "must be >"),
        (_with(world__bounds=[[0, 4]]), "world.bounds", "2 (2D) or 3 (3D)"),
        (_with(world__regions__a__ball__radius=0), "world.regions.a.ball.radius", "> 0"),
        (_with(world__obstacles__0__box__min="x"), "world.obstacles.0.box.min", "list"),
        (_with(robot__start=[2.9, 2.9]), "robot.start", "collision"),
        (_with(training__n_timesteps="many"), "training.n_timesteps", "integer"),
        (_with(colour="red"), "colour", "unknown key"),
        (_with(name="no spaces allowed"), "name", "slug"),
    ],
)
def test_invalid_fields_are_422_with_their_path(
    setup: tuple[TestClient, RecordingEnqueue], document: Any, field: str, needle: str
) -> None:
    http, enqueue = setup
    response = http.post("/missions", json=document)
    assert response.status_code == 422, response.text
    problems = _problems(response)
    assert field in problems, problems
    assert needle in problems[field]["msg"]
    assert problems[field]["loc"][0] == "body"
    assert enqueue.calls == []


def test_several_problems_reported_together(setup: tuple[TestClient, RecordingEnqueue]) -> None:
    http, _ = setup
    document = _with(robot__radius="big", world__bounds=[[0, 4]])
    response = http.post("/missions", json=document)
    assert response.status_code == 422
    assert {"robot.radius", "world.bounds"} <= set(_problems(response))


@pytest.mark.parametrize(
    ("task", "column", "needle"),
    [
        ("[]<>a && ", 10, "expected a formula"),
        ("[]<>a && ((b)", 14, ""),
        ("[]<>a && X b", 10, "X"),
        ("[]<>a && []<>zz", 14, "unknown label 'zz'"),
    ],
)
def test_bad_formula_names_the_column(
    setup: tuple[TestClient, RecordingEnqueue], task: str, column: int, needle: str
) -> None:
    http, enqueue = setup
    response = http.post("/missions", json=_with(task=task))
    assert response.status_code == 422, response.text
    problem = _problems(response)["task"]
    assert problem["loc"] == ["body", "task"]
    assert problem["column"] == column, problem
    assert needle in problem["msg"]
    assert enqueue.calls == []


@pytest.mark.parametrize(
    ("body", "field", "needle"),
    [
        ([1, 2], None, "must be a mapping"),
        ("mission", None, "must be a mapping"),
        ({"example": 3}, "example", "must be a string"),
        ({"example": "no-such-example"}, "example", "car-phi2-fin"),
        ({"example": "../pyproject"}, "example", "unknown example"),
        ({"example": "car-phi2-fin", "extra": 1}, "example", "unknown key"),
        ({}, "world", "required"),
    ],
)
def test_wrong_shapes_are_422(
    setup: tuple[TestClient, RecordingEnqueue], body: Any, field: str | None, needle: str
) -> None:
    http, enqueue = setup
    response = http.post("/missions", json=body)
    assert response.status_code == 422, response.text
    problems = _problems(response)
    assert (field or "") in problems, problems
    assert needle in problems[field or ""]["msg"]
    assert enqueue.calls == []


def test_a_mission_the_service_cannot_run_is_422_and_not_stored(
    setup: tuple[TestClient, RecordingEnqueue],
) -> None:
    """g-rrt trains one agent for the whole lasso: valid, but never servable (bundled per
    sub-task), so it is refused at submission like any invalid field."""
    http, enqueue = setup
    response = http.post("/missions", json=_with(training__reward={"mode": "g-rrt"}))
    assert response.status_code == 422, response.text
    problem = _problems(response)["training.reward.mode"]
    assert problem["loc"] == ["body", "training", "reward", "mode"]
    assert "g-rrt" in problem["msg"]
    assert enqueue.calls == []
    assert http.get("/missions").json()["total"] == 0


def test_oversize_bodies_are_413_declared_or_chunked(
    setup: tuple[TestClient, RecordingEnqueue],
) -> None:
    http, enqueue = setup
    big = b'{"name": "' + b"x" * 300_000 + b'"}'
    declared = http.post("/missions", content=big)
    assert declared.status_code == 413
    assert "200000 bytes" in declared.json()["detail"]

    def chunks() -> Iterator[bytes]:
        for start in range(0, len(big), 10_000):
            yield big[start : start + 10_000]

    chunked = http.post("/missions", content=chunks())
    assert chunked.request.headers["transfer-encoding"] == "chunked"
    assert chunked.status_code == 413
    assert "200000 bytes" in chunked.json()["detail"]
    assert enqueue.calls == []


def test_bad_input_never_loses_an_accepted_mission(
    setup: tuple[TestClient, RecordingEnqueue],
) -> None:
    http, enqueue = setup
    first = http.post("/missions", json=tiny()).json()["id"]
    for body in (b"{", b"[]", b'{"task": 1}', b"x" * 300_000):
        assert 400 <= http.post("/missions", content=body).status_code < 500
    assert http.post(f"/missions/{first}/cancel").status_code == 202
    assert http.post(f"/missions/{first}/cancel").status_code == 409
    page = http.get("/missions").json()
    assert [m["id"] for m in page["items"]] == [first]
    assert enqueue.calls == [first]


def test_unicode_digits_in_paths_and_lengths(setup: tuple[TestClient, RecordingEnqueue]) -> None:
    """Found by the fuzzer: '²' is a digit to ``str.isdigit`` but not to ``int``."""
    http, _ = setup
    response = http.post("/missions", json=_with(training__env={"²": None}))
    assert response.status_code == 422
    problem = _problems(response)["training.env.²"]
    assert problem["loc"] == ["body", "training", "env", "²"]
    assert body_problem("world.obstacles.0", "x").loc == ["body", "world", "obstacles", 0]

    sent: list[MutableMapping[str, Any]] = []

    async def app(scope: Any, receive: Any, send: Any) -> None:
        await send({"type": "http.response.start", "status": 204, "headers": []})
        await send({"type": "http.response.body", "body": b""})

    async def receive() -> dict[str, Any]:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: MutableMapping[str, Any]) -> None:
        sent.append(message)

    scope = {"type": "http", "headers": [(b"content-length", "²".encode())]}
    asyncio.run(BodyLimit(app, 10)(scope, receive, send))
    assert sent[0]["status"] == 204
