"""End to end through the API: a real ``ltlnav worker`` process on the embedded defaults
(SQLite state, ``sqla+sqlite`` broker, all under ``tmp_path``), missions POSTed through the app
with its default (Celery) enqueue. The tiny mission reaches ``done`` and its bundle opens; an
infeasible one ends ``failed`` with the planner's reason."""

from __future__ import annotations

import copy
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.db import upgrade
from service.settings import Settings
from tests.service.api_helpers import REPO, tiny
from workers.bundle_reader import read_bundle

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


@pytest.fixture
def service(tmp_path: Path) -> Iterator[tuple[TestClient, Path]]:
    """The app on ``tmp_path`` and one real worker process (concurrency 2) beside it."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("LTLNAV_")}
    env.pop("DATABASE_URL", None)
    env["LTLNAV_DATA_DIR"] = str(tmp_path / "data")
    settings = Settings(data_dir=tmp_path / "data")
    settings.make_dirs()
    upgrade(settings.database_url)
    log_path = tmp_path / "worker.log"
    with log_path.open("wb") as log:
        worker = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "worker", "--concurrency", "2"],
            cwd=REPO,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        with TestClient(create_app(settings)) as http:
            yield http, log_path
    finally:
        # Nothing runs any more and the test is over: no need to wait for a warm shutdown.
        os.killpg(worker.pid, signal.SIGKILL)
        worker.wait()


def _until_final(http: TestClient, mission_id: str, log: Path, seconds: float) -> dict[str, Any]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        mission: dict[str, Any] = http.get(f"/missions/{mission_id}").json()
        if mission["status"] in ("done", "failed", "cancelled"):
            return mission
        time.sleep(0.5)
    raise AssertionError(f"mission not final after {seconds} s; worker log:\n{log.read_text()}")


def test_tiny_mission_through_the_api(service: tuple[TestClient, Path]) -> None:
    http, log = service
    started = time.monotonic()
    created = http.post("/missions", json=tiny())
    assert created.status_code == 201
    mission_id = created.json()["id"]
    infeasible = copy.deepcopy(tiny())
    infeasible["task"] = "<>a && []!a"
    doomed = http.post("/missions", json=infeasible).json()["id"]

    mission = _until_final(http, mission_id, log, 240)
    assert mission["status"] == "done", mission
    assert len(mission["jobs"]) == len(mission["plan"]["subtasks"]) == 4
    assert all(job["status"] == "done" and job["final"] for job in mission["jobs"])
    assert mission["evaluation"]["episodes"] == 2
    assert http.get(f"/missions/{mission_id}/plan.png").content.startswith(b"\x89PNG")
    curve = http.get(f"/missions/{mission_id}/subtasks/0/curve").json()
    assert [p["steps"] for p in curve["points"]] == sorted(p["steps"] for p in curve["points"])
    assert curve["points"], "no evaluation points recorded"
    bundle = http.get(f"/missions/{mission_id}/bundle")
    assert bundle.status_code == 200
    path = log.parent / "bundle.zip"
    path.write_bytes(bundle.content)
    manifest, files = read_bundle(path)
    assert len(manifest.subtasks) == 4
    assert files
    events = http.get(f"/missions/{mission_id}/events").text
    assert "event: end" in events and '"done"' in events
    print(f"tiny mission done through the API in {time.monotonic() - started:.1f} s")

    failed = _until_final(http, doomed, log, 60)
    assert failed["status"] == "failed"
    assert "unsatisfiable" in failed["reason"]
    assert http.get(f"/missions/{doomed}/bundle").status_code == 409
