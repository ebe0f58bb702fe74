"""``service.jobs.reconcile``: what a pass sends again, on SQLite and PostgreSQL, and that two
reconcilers at once send each piece of work once."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine, text, update

from service import repository
from service.db import Database
from service.jobs.reconcile import DrainWatch, clean_broker, reconcile_once
from service.models import Job, JobStatus, Mission, MissionStatus, utcnow
from service.repository import recovery
from service.settings import Settings
from tests.service.dispatch import Recorder


@pytest.fixture
def settings(database: Database, tmp_path: Path) -> Settings:
    return Settings(
        data_dir=tmp_path,
        database_url=database.url,
        heartbeat_seconds=1,
        stale_after_seconds=30,
        requeue_after_seconds=10,
    )


AGO = timedelta(minutes=5)


def mission_in(db: Database, status: MissionStatus, jobs: int = 0, age: timedelta = AGO) -> str:
    """A mission moved to ``status`` (through the life cycle), ``jobs`` queued jobs, its last
    change ``age`` ago."""
    with db.session() as session:
        mission = repository.create_mission(session, "m", {"name": "m"}, None)
        path = [MissionStatus.planning, MissionStatus.training, MissionStatus.evaluating]
        for step in path[: path.index(status) + 1] if status in path else []:
            if step == MissionStatus.training and jobs:
                new = [
                    repository.NewJob(index=k, budget=100, out_dir=f"/x/{k}") for k in range(jobs)
                ]
                repository.create_jobs(session, mission.id, new)
            repository.set_status(session, mission.id, step)
        if status in repository.FINAL_STATES:
            repository.set_status(session, mission.id, status, "because")
        session.execute(
            update(Mission).where(Mission.id == mission.id).values(updated_at=utcnow() - age)
        )
        return mission.id


def set_job(db: Database, mission_id: str, index: int, **values: Any) -> None:
    with db.session() as session:
        session.execute(
            update(Job).where(Job.mission_id == mission_id, Job.index == index).values(**values)
        )


def status_of(db: Database, mission_id: str) -> tuple[MissionStatus, list[JobStatus]]:
    with db.session() as session:
        mission = repository.get_mission(session, mission_id)
        assert mission is not None
        return mission.status, [j.status for j in repository.mission_jobs(session, mission_id)]


def test_a_stale_running_job_is_queued_and_sent_again(
    database: Database, settings: Settings
) -> None:
    mission_id = mission_in(database, MissionStatus.training, jobs=2)
    set_job(
        database, mission_id, 0, status=JobStatus.running, heartbeat_at=utcnow() - AGO, worker="w"
    )
    set_job(database, mission_id, 1, status=JobStatus.running, heartbeat_at=utcnow(), worker="w")
    sent = Recorder()
    reconcile_once(settings, sent, drained=False)
    assert sent.sent == [("train", mission_id, 0)]
    assert status_of(database, mission_id)[1] == [JobStatus.queued, JobStatus.running]
    again = Recorder()
    reconcile_once(settings, again, drained=False)
    assert again.sent == []  # claimed once


def test_queued_work_is_sent_again_only_when_the_queue_is_empty(
    database: Database, settings: Settings
) -> None:
    queued = mission_in(database, MissionStatus.queued)
    fresh = mission_in(database, MissionStatus.queued, age=timedelta(0))
    training = mission_in(database, MissionStatus.training, jobs=2)
    set_job(database, training, 1, status=JobStatus.running, heartbeat_at=utcnow(), worker="w")
    waiting = Recorder()
    reconcile_once(settings, waiting)  # messages wait in the broker: no resend
    assert waiting.sent == []
    lost = Recorder()
    reconcile_once(settings, lost, drained=True)
    assert sorted(lost.sent) == sorted([("plan", queued), ("train", training, 0)])
    assert fresh not in str(lost.sent)
    again = Recorder()
    reconcile_once(settings, again, drained=True)  # not again before requeue_after_seconds
    assert again.sent == []


def test_stalled_planning_and_assembly_are_sent_again(
    database: Database, settings: Settings
) -> None:
    planning = mission_in(database, MissionStatus.planning)
    evaluating = mission_in(database, MissionStatus.evaluating, jobs=1)
    live = mission_in(database, MissionStatus.evaluating, jobs=1, age=timedelta(0))
    sent = Recorder()
    reconcile_once(settings, sent, drained=False)
    assert sorted(sent.sent) == sorted([("assemble", evaluating), ("plan", planning)])
    assert status_of(database, planning)[0] == MissionStatus.queued
    assert status_of(database, evaluating)[0] == MissionStatus.training
    assert status_of(database, live)[0] == MissionStatus.evaluating


def test_a_lost_chord_callback_is_replaced(database: Database, settings: Settings) -> None:
    mission_id = mission_in(database, MissionStatus.training, jobs=2)
    for k in (0, 1):
        set_job(database, mission_id, k, status=JobStatus.done, finished_at=utcnow() - AGO)
    recent = mission_in(database, MissionStatus.training, jobs=1)
    set_job(database, recent, 0, status=JobStatus.done, finished_at=utcnow())
    waiting = Recorder()
    for _ in range(3):  # the callback may wait behind a backlog: no pile of duplicates
        reconcile_once(settings, waiting, drained=False)
    assert waiting.sent == []
    sent = Recorder()
    reconcile_once(settings, sent, drained=True)
    assert sent.sent == [("assemble", mission_id)]
    again = Recorder()
    reconcile_once(settings, again, drained=True)
    assert again.sent == []


def test_a_cancelled_mission_without_running_jobs_ends_cancelled(
    database: Database, settings: Settings
) -> None:
    idle = mission_in(database, MissionStatus.training, jobs=2)
    busy = mission_in(database, MissionStatus.training, jobs=2)
    set_job(database, busy, 0, status=JobStatus.running, heartbeat_at=utcnow(), worker="w")
    with database.session() as session:
        repository.request_cancel(session, idle)
        repository.request_cancel(session, busy)
    out = reconcile_once(settings, Recorder(), drained=False)
    assert out.cancelled == [idle]
    assert status_of(database, idle) == (MissionStatus.cancelled, [JobStatus.cancelled] * 2)
    assert status_of(database, busy)[0] == MissionStatus.training


def test_two_reconcilers_at_once_send_each_stale_job_once(
    database: Database, settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    mission_id = mission_in(database, MissionStatus.training, jobs=3)
    for k in range(3):
        set_job(database, mission_id, k, status=JobStatus.running, heartbeat_at=utcnow() - AGO)
    with database.session() as first, database.session() as second:
        # both found the same stale jobs before either claimed them
        seen = repository.stale_jobs(second, settings.stale_after_seconds)
        assert len(seen) == 3
        assert len(repository.reclaim_stale_jobs(first, settings.stale_after_seconds)) == 3
        first.commit()
        monkeypatch.setattr(recovery, "stale_jobs", lambda *_args, **_kw: seen)
        assert repository.reclaim_stale_jobs(second, settings.stale_after_seconds) == []


def test_consumed_broker_messages_are_deleted(tmp_path: Path) -> None:
    broker = tmp_path / "broker.db"
    settings = Settings(data_dir=tmp_path, broker_url=f"sqla+sqlite:///{broker}")
    assert clean_broker(settings) == 0  # no table yet
    engine = create_engine(f"sqlite:///{broker}")
    with engine.begin() as connection:
        connection.execute(
            text("CREATE TABLE kombu_message (id INTEGER PRIMARY KEY, visible BOOLEAN)")
        )
        connection.execute(text("INSERT INTO kombu_message (visible) VALUES (0), (0), (1)"))
    assert clean_broker(settings) == 2
    with engine.begin() as connection:
        assert connection.execute(text("SELECT visible FROM kombu_message")).scalars().all() == [1]
    engine.dispose()
    assert clean_broker(Settings(data_dir=tmp_path, broker_url="redis://127.0.0.1:1/0")) == 0


def test_the_queue_counts_as_drained_after_two_empty_looks() -> None:
    watch = DrainWatch()
    looks = [0, 0, 0, 2, 0, None, 0, 0]
    assert [watch.drained(size) for size in looks] == [
        False, True, True, False, False, False, False, True
    ]  # fmt: skip
