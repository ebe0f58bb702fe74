"""``DELETE /missions/{id}``: an ended mission's rows (jobs, checkpoints, evaluations, events)
and artifact folder go; a running one is 409 (cancel it first); another key's is 404. On
SQLite and PostgreSQL (the foreign keys cascade on both)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from service import repository as repo
from service.api.app import create_app
from service.db import Database
from service.models import Checkpoint, Evaluation, Event, Job, JobStatus, Mission, MissionStatus
from tests.service.api_helpers import RecordingEnqueue, advance, bearer, settings_for, tiny

ALPHA, BETA = bearer("alpha"), bearer("beta")


@dataclass
class Api:
    http: TestClient
    database: Database
    artifacts: Path

    def submit(self) -> str:
        response = self.http.post("/missions", json=tiny(), headers=ALPHA)
        assert response.status_code == 201, response.text
        mission_id: str = response.json()["id"]
        return mission_id

    def rows(self, mission_id: str) -> dict[str, int]:
        with self.database.session() as session:
            job_ids = select(Job.id).where(Job.mission_id == mission_id)
            counts = {
                "missions": select(func.count()).where(Mission.id == mission_id),
                "jobs": select(func.count()).where(Job.mission_id == mission_id),
                "checkpoints": select(func.count()).where(Checkpoint.job_id.in_(job_ids)),
                "evaluations": select(func.count()).where(Evaluation.mission_id == mission_id),
                "events": select(func.count()).where(Event.mission_id == mission_id),
            }
            return {name: session.scalar(query) or 0 for name, query in counts.items()}


@pytest.fixture
def api(database: Database, tmp_path: Path) -> Iterator[Api]:
    settings = settings_for(tmp_path, database.url, keys=["alpha", "beta"])
    with TestClient(create_app(settings, RecordingEnqueue(database))) as http:
        yield Api(http, database, settings.artifact_dir)


def test_delete_removes_the_rows_and_the_folder(api: Api) -> None:
    mission_id = api.submit()
    kept = api.submit()
    advance(api.database, mission_id, api.artifacts, MissionStatus.done)
    advance(api.database, kept, api.artifacts, MissionStatus.done)
    with api.database.session() as session:
        job = repo.mission_jobs(session, mission_id)[0]
        checkpoint = Path(job.out_dir) / "checkpoint_100.zip"
        checkpoint.parent.mkdir(parents=True, exist_ok=True)
        checkpoint.write_bytes(b"model")
        repo.record_checkpoint(session, job.id, 100, str(checkpoint))
    before, kept_before = api.rows(mission_id), api.rows(kept)
    assert all(before.values()), before
    folder = api.artifacts / mission_id
    assert (folder / "bundle.zip").is_file()

    response = api.http.delete(f"/missions/{mission_id}", headers=ALPHA)
    assert response.status_code == 204, response.text
    assert response.content == b""
    assert set(api.rows(mission_id).values()) == {0}
    assert not folder.exists()
    assert api.http.get(f"/missions/{mission_id}", headers=ALPHA).status_code == 404
    assert api.http.delete(f"/missions/{mission_id}", headers=ALPHA).status_code == 404
    assert api.rows(kept) == kept_before  # the other mission is untouched
    assert (api.artifacts / kept / "bundle.zip").is_file()


@pytest.mark.parametrize("status", [MissionStatus.queued, MissionStatus.training])
def test_a_mission_that_has_not_ended_is_409(api: Api, status: MissionStatus) -> None:
    mission_id = api.submit()
    if status != MissionStatus.queued:
        advance(api.database, mission_id, api.artifacts, status)
    response = api.http.delete(f"/missions/{mission_id}", headers=ALPHA)
    assert response.status_code == 409
    assert "cancel it first" in response.json()["detail"]
    assert api.rows(mission_id)["missions"] == 1


def test_a_failed_mission_with_a_job_still_running_is_409(api: Api) -> None:
    mission_id = api.submit()
    advance(api.database, mission_id, api.artifacts, MissionStatus.training)
    advance(api.database, mission_id, api.artifacts, MissionStatus.failed)
    response = api.http.delete(f"/missions/{mission_id}", headers=ALPHA)
    assert response.status_code == 409
    assert "still stopping" in response.json()["detail"]
    with api.database.session() as session:
        for job in repo.mission_jobs(session, mission_id):
            repo.finish_job(session, job.id, JobStatus.cancelled, None)
    assert api.http.delete(f"/missions/{mission_id}", headers=ALPHA).status_code == 204


def test_cancel_then_delete(api: Api) -> None:
    mission_id = api.submit()
    assert api.http.post(f"/missions/{mission_id}/cancel", headers=ALPHA).status_code == 202
    assert api.http.delete(f"/missions/{mission_id}", headers=ALPHA).status_code == 204
    assert api.rows(mission_id)["missions"] == 0


def test_another_key_gets_404_and_deletes_nothing(api: Api) -> None:
    mission_id = api.submit()
    advance(api.database, mission_id, api.artifacts, MissionStatus.done)
    before = api.rows(mission_id)
    for headers in (BETA, {}):
        response = api.http.delete(f"/missions/{mission_id}", headers=headers)
        assert response.status_code == (404 if headers else 401)
    assert api.http.delete("/missions/nope", headers=ALPHA).status_code == 404
    assert api.rows(mission_id) == before
    assert (api.artifacts / mission_id / "bundle.zip").is_file()
