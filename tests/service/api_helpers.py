"""Shared pieces of the API tests: settings on a test database, a recording enqueue, a client,
a uvicorn server in a thread, and a fake worker that moves a mission through its life cycle
with the repository (no Celery)."""

from __future__ import annotations

import copy
import socket
import threading
import time
import zipfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import uvicorn
from fastapi import FastAPI
from fastapi.testclient import TestClient

from service import repository as repo
from service.api.app import create_app
from service.db import Database
from service.models import JobStatus, MissionStatus
from service.settings import Settings
from tests.workers.missions import TINY

REPO = Path(__file__).resolve().parents[2]
PLAN = {
    "automaton_states": 3,
    "pruned_states": 2,
    "prefix_length": 1.5,
    "suffix_length": 4.0,
    "cost": 5.5,
    "seconds": 0.1,
    "subtasks": [
        {"index": 0, "phase": "prefix", "goal": "a", "length": 1.5, "balls": 3},
        {"index": 1, "phase": "suffix", "goal": "b", "length": 4.0, "balls": 5},
    ],
}
PARTS = {"periodic evaluations": 4.0, "final evaluation": 2.5, "learner and the rest": 6.0}
"""A finished job's wall time by part (``TrainResult.parts``)."""


def tiny() -> dict[str, Any]:
    """A fresh copy of the tiny mission document."""
    return copy.deepcopy(TINY)


@dataclass
class RecordingEnqueue:
    """An enqueue that records the ids (and can fail like a broker that is down); it reads
    the mission from the database to prove it was committed first."""

    database: Database
    fail: bool = False
    calls: list[str] = field(default_factory=list)
    committed: list[bool] = field(default_factory=list)

    def __call__(self, mission_id: str) -> None:
        with self.database.session() as session:
            self.committed.append(repo.get_mission(session, mission_id) is not None)
        self.calls.append(mission_id)
        if self.fail:
            raise ConnectionError("broker down")


def settings_for(tmp_path: Path, url: str, keys: Sequence[str] = ()) -> Settings:
    """Settings on ``url`` with everything else under ``tmp_path``."""
    return Settings(
        data_dir=tmp_path / "data",
        database_url=url,
        api_keys=list(keys),
        examples_dir=REPO / "examples",
        max_body_bytes=200_000,
    )


def bearer(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def advance(
    database: Database,
    mission_id: str,
    artifacts: Path,
    to: MissionStatus,
    curve: Sequence[tuple[int, float]] = ((100, 0.0), (200, 0.5)),
) -> None:
    """Move a mission forward as the workers would, with artifacts under ``artifacts``:
    planning (plan + picture), training (two jobs, curve points on job 0), evaluating, done
    (evaluation + bundle.zip). ``failed`` fails it from where it is."""
    steps = [MissionStatus.planning, MissionStatus.training, MissionStatus.evaluating]
    steps.append(MissionStatus.done)
    if to == MissionStatus.failed:
        with database.session() as session:
            repo.set_status(session, mission_id, to, "no plan: unsatisfiable in this world")
        return
    folder = artifacts / mission_id
    folder.mkdir(parents=True, exist_ok=True)
    with database.session() as session:
        current = repo.get_mission(session, mission_id)
        assert current is not None
        done = steps.index(current.status) + 1 if current.status in steps else 0
    for status in steps[done : steps.index(to) + 1]:
        with database.session() as session:
            repo.set_status(session, mission_id, status)
            if status == MissionStatus.planning:
                picture = folder / "plan.png"
                picture.write_bytes(b"\x89PNG\r\n\x1a\nfake")
                repo.set_plan(session, mission_id, PLAN, str(picture))
            elif status == MissionStatus.training:
                jobs = [repo.NewJob(k, 200, str(folder / f"subtask_{k}")) for k in (0, 1)]
                rows = repo.create_jobs(session, mission_id, jobs)
                for steps_done, rate in curve:
                    repo.record_evaluation(session, mission_id, rows[0].id, steps_done, 1, rate)
                for row in rows:
                    repo.start_job(session, row.id, "fake-worker")
                    repo.record_progress(session, row.id, 100, 0.5, 3.0)
            elif status == MissionStatus.evaluating:
                for row in repo.mission_jobs(session, mission_id):
                    final = {"success_rate": 1.0, "episodes": 2}
                    result = {"steps": 200, "final": final, "seconds": 12.5, "parts": PARTS}
                    repo.finish_job(session, row.id, JobStatus.done, result)
            elif status == MissionStatus.done:
                bundle = folder / "bundle.zip"
                with zipfile.ZipFile(bundle, "w") as archive:
                    archive.writestr("manifest.json", "{}")
                evaluation = {"episodes": 2, "success_rate": 1.0}
                repo.set_result(session, mission_id, evaluation, str(bundle))


def client(app: FastAPI, key: str | None = None) -> TestClient:
    """A test client, sending ``key`` as bearer token when given."""
    return TestClient(app, headers=bearer(key) if key else None)


def app_for(settings: Settings, enqueue: RecordingEnqueue) -> FastAPI:
    return create_app(settings, enqueue)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextmanager
def served(app: FastAPI) -> Iterator[str]:
    """Run ``app`` on a real uvicorn server in a thread; yields its base URL."""
    port = free_port()
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=20)
