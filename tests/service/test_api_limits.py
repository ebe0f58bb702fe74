"""Admission limits at the edges: ``POST /missions`` answers 422 naming field, value, limit and
setting in well under a second of CPU (the process's, the app's threads included: wall time on
a shared test machine measures its load), stores nothing; ``ltlnav validate`` prints the same
message with exit code 2; a raised setting admits the mission."""

from __future__ import annotations

import copy
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from service.api.app import create_app
from service.cli import EXIT_BAD_INPUT, app
from service.db import Database, upgrade
from service.settings import Settings, get_settings
from tests.service.api_helpers import REPO, RecordingEnqueue, tiny
from tests.workers.test_limits import HOSTILE, polygon, with_

runner = CliRunner()


def _settings(tmp_path: Path, url: str, **limits: Any) -> Settings:
    return Settings(
        data_dir=tmp_path / "data",
        database_url=url,
        examples_dir=REPO / "examples",
        max_body_bytes=1_000_000,
        **limits,
    )


@pytest.fixture
def database(sqlite_url: str) -> Iterator[Database]:
    upgrade(sqlite_url)
    db = Database(sqlite_url)
    yield db
    db.dispose()


@pytest.fixture
def client(
    database: Database, sqlite_url: str, tmp_path: Path
) -> Iterator[tuple[TestClient, RecordingEnqueue]]:
    enqueue = RecordingEnqueue(database)
    with TestClient(create_app(_settings(tmp_path, sqlite_url), enqueue)) as http:
        yield http, enqueue


@pytest.mark.parametrize(("path", "value", "field", "needle"), HOSTILE)
def test_hostile_submissions_are_422_quickly(
    client: tuple[TestClient, RecordingEnqueue], path: str, value: Any, field: str, needle: str
) -> None:
    http, enqueue = client
    body = json.dumps(with_(path, value), separators=(",", ":")).encode()
    assert len(body) < 1_000_000
    t0 = time.process_time()
    response = http.post("/missions", content=body, headers={"content-type": "application/json"})
    elapsed = time.process_time() - t0
    assert response.status_code == 422, response.text
    problems = {p.get("field"): p for p in response.json()["detail"]}
    assert field in problems, problems
    assert needle in problems[field]["msg"]
    assert problems[field]["loc"][0] == "body"
    assert enqueue.calls == []
    assert elapsed < 1.0, f"{path}: {elapsed:.2f} s"


def test_huge_polygons_are_refused_by_count_within_the_body_limit(
    client: tuple[TestClient, RecordingEnqueue],
) -> None:
    http, enqueue = client
    for n in (20_000, 50_000):
        vertices = [[round(x, 3), round(y, 3)] for x, y in polygon(n)]
        body = json.dumps(with_("world.regions.a", {"polygon": vertices}), separators=(",", ":"))
        assert len(body) < 1_000_000
        t0 = time.process_time()
        response = http.post(
            "/missions", content=body.encode(), headers={"content-type": "application/json"}
        )
        elapsed = time.process_time() - t0
        assert response.status_code == 422, response.text
        (problem,) = response.json()["detail"]
        assert problem["field"] == "world.regions.a.polygon"
        assert problem["msg"] == (
            f"has {n} vertices, over the limit 2000 (LTLNAV_MAX_WORLD_VERTICES)"
        )
        assert elapsed < 1.0, f"{n} vertices: {elapsed:.2f} s"
    assert enqueue.calls == []


def test_a_raised_setting_admits_the_mission(
    database: Database, sqlite_url: str, tmp_path: Path
) -> None:
    document = tiny()
    document["training"].update(n_timesteps=3_000_000, eval_freq=5_000)
    enqueue = RecordingEnqueue(database)
    with TestClient(create_app(_settings(tmp_path, sqlite_url), enqueue)) as http:
        refused = http.post("/missions", json=document)
    assert refused.status_code == 422
    assert "LTLNAV_MAX_TIMESTEPS" in refused.text
    raised = _settings(tmp_path, sqlite_url, max_timesteps=5_000_000)
    with TestClient(create_app(raised, enqueue)) as http:
        admitted = http.post("/missions", json=document)
    assert admitted.status_code == 201, admitted.text
    assert len(enqueue.calls) == 1


def test_cli_validate_prints_the_same_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    document = copy.deepcopy(with_("training.n_timesteps", 10**12))
    mission = tmp_path / "hostile.json"
    mission.write_text(json.dumps(document))
    monkeypatch.delenv("LTLNAV_MAX_TIMESTEPS", raising=False)
    get_settings.cache_clear()
    try:
        result = runner.invoke(app, ["validate", str(mission)])
        assert result.exit_code == EXIT_BAD_INPUT
        assert (
            "training.n_timesteps: 1000000000000 is over the limit 2000000 "
            "(LTLNAV_MAX_TIMESTEPS)" in result.output
        )
        monkeypatch.setenv("LTLNAV_MAX_TIMESTEPS", str(10**13))
        get_settings.cache_clear()
        document["training"]["eval_freq"] = 10**10
        mission.write_text(json.dumps(document))
        result = runner.invoke(app, ["validate", str(mission)])
        assert result.exit_code == 0, result.output
    finally:
        get_settings.cache_clear()
