"""Faults inside one process, on a real SQLite database and real tiny trainings: a second
attempt fences the first, steps that keep dying end the mission with a reason, transient
failures come back after a backoff and permanent ones fail at once. The real-process fault
suite (SIGKILL, outages) is ``tests/service/test_fault_suite.py``."""

from __future__ import annotations

import errno
import threading
import time
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import update

from service import repository
from service.db import Database, upgrade
from service.jobs.assembly import assemble_step
from service.jobs.common import forget_open_runs
from service.jobs.planning import plan_step
from service.jobs.training import train_step
from service.models import Job, JobStatus, Mission, MissionStatus, utcnow
from service.settings import Settings
from tests.service.dispatch import Recorder
from tests.workers.missions import tiny_mission

pytestmark = pytest.mark.timeout(180)


@pytest.fixture
def settings(tmp_path: Path, sqlite_url: str) -> Settings:
    upgrade(sqlite_url)
    return Settings(
        data_dir=tmp_path,
        database_url=sqlite_url,
        heartbeat_seconds=0.2,
        stale_after_seconds=1.0,
        max_attempts=3,
        retry_backoff_seconds=2.0,
    )


def submit(settings: Settings, **training: Any) -> str:
    doc = tiny_mission(**training).model_dump(mode="json")
    with Database(settings.database_url).session() as session:
        return repository.create_mission(session, doc["name"], doc, None).id


def mission_and_jobs(settings: Settings, mission_id: str) -> tuple[Mission, list[Job]]:
    with Database(settings.database_url).session() as session:
        mission = repository.get_mission(session, mission_id)
        assert mission is not None
        return mission, repository.mission_jobs(session, mission_id)


def test_a_second_attempt_fences_the_first_which_writes_nothing_more(
    settings: Settings,
) -> None:
    """Two live runners on one job (a reclaim while the first still runs, e.g. a clock or a
    database stall): the first stops at its next write and writes no file, row or result."""
    mission_id = submit(settings, n_timesteps=4000, eval_freq=100, checkpoint_freq=100)
    plan_step(settings, mission_id, Recorder())
    db = Database(settings.database_url)
    outcome: list[str] = []
    first = threading.Thread(
        target=lambda: outcome.append(train_step(settings, mission_id, 0, Recorder(), True))
    )
    first.start()
    deadline = time.monotonic() + 60
    while True:  # until the first attempt has saved a checkpoint
        with db.session() as session:
            job = repository.get_job(session, mission_id, 0)
            assert job is not None
            if repository.latest_checkpoint(session, job.id) is not None:
                break
        assert time.monotonic() < deadline and first.is_alive()
        time.sleep(0.05)
    with db.session() as session:  # another worker's claim: the token moves on
        session.execute(
            update(Job)
            .where(Job.id == job.id)
            .values(attempts=Job.attempts + 1, worker="second", heartbeat_at=utcnow())
        )
    folder = Path(job.out_dir)
    first.join(timeout=60)
    assert outcome == ["lost"]
    with db.session() as session:
        job = repository.get_job(session, mission_id, 0)
        assert job is not None
        assert job.status == JobStatus.running and job.worker == "second"
        assert job.result is None
        saved = repository.latest_checkpoint(session, job.id)
        assert saved is not None
    assert not (folder / "result.json").exists() and not (folder / "model.zip").exists()
    on_disk = sorted(folder.glob("checkpoints/model_*_steps.zip"))
    assert on_disk and max(int(p.stem.split("_")[1]) for p in on_disk) <= saved.steps + 100
    assert not list(folder.rglob("*.partial*"))


def test_planning_that_keeps_dying_fails_the_mission_saying_so(settings: Settings) -> None:
    """A poison mission whose planning kills its process at every attempt: each crash leaves
    it planning, the reconciler puts it back, and the attempt cap ends it."""
    mission_id = submit(settings)
    db = Database(settings.database_url)
    for attempt in range(1, settings.max_attempts + 1):
        with db.session() as session:  # a worker claims the planning, then its process dies
            claimed = repository.claim_step(
                session, mission_id, MissionStatus.queued, MissionStatus.planning, "plan_attempts"
            )
            assert claimed == attempt
            session.execute(
                update(Mission)
                .where(Mission.id == mission_id)
                .values(updated_at=utcnow() - timedelta(seconds=5))
            )
        with db.session() as session:
            assert repository.reclaim_stalled_missions(session, settings.stale_after_seconds)
    sent = Recorder()
    assert plan_step(settings, mission_id, sent) == "failed"
    mission, jobs = mission_and_jobs(settings, mission_id)
    assert mission.status == MissionStatus.failed and jobs == [] and sent.sent == []
    assert mission.reason is not None
    assert mission.reason.startswith(f"planning: gave up after {settings.max_attempts} attempts")
    assert "LTLNAV_MAX_ATTEMPTS" in mission.reason
    with db.session() as session:
        events = repository.events_after(session, mission_id, 0, limit=100)
        assert events[-1].kind == "status" and events[-1].payload["reason"] == mission.reason


def test_an_assembly_that_keeps_dying_fails_the_mission_saying_so(settings: Settings) -> None:
    mission_id = submit(settings, n_timesteps=50, handover_rounds=0)
    plan_step(settings, mission_id, Recorder())
    for job in mission_and_jobs(settings, mission_id)[1]:
        assert train_step(settings, mission_id, job.index, Recorder(), True) == "done"
    db = Database(settings.database_url)
    with db.session() as session:
        session.execute(
            update(Mission)
            .where(Mission.id == mission_id)
            .values(assembly_attempts=settings.max_attempts)
        )
    assert assemble_step(settings, mission_id, Recorder()) == "failed"
    mission, _ = mission_and_jobs(settings, mission_id)
    assert mission.status == MissionStatus.failed and mission.bundle_path is None
    assert mission.reason is not None
    assert mission.reason.startswith(f"assembly: gave up after {settings.max_attempts} attempts")


def test_a_full_disk_puts_the_job_back_after_a_backoff_then_it_resumes(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ENOSPC at a checkpoint write: the job is queued again with its reason, sent again
    after the backoff, and the next attempt completes; no mission failure."""
    mission_id = submit(settings, n_timesteps=200, eval_freq=100)
    plan_step(settings, mission_id, Recorder())
    import workers.checkpoints

    real = workers.checkpoints.save_with
    calls = {"n": 0}

    def full_once(path: Path, save: Any, durable: bool = False) -> None:
        calls["n"] += 1
        if calls["n"] == 2:  # the second file of the first checkpoint
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, save, durable)

    monkeypatch.setattr(workers.checkpoints, "save_with", full_once)
    sent = Recorder()
    assert train_step(settings, mission_id, 0, sent, in_chord=True) == "retrying"
    mission, jobs = mission_and_jobs(settings, mission_id)
    assert mission.status == MissionStatus.training
    job = jobs[0]
    assert job.status == JobStatus.queued and job.not_before is not None
    assert job.reason is not None and "No space left on device" in job.reason
    assert sent.sent == [("train", mission_id, 0, settings.retry_backoff_seconds)]
    # too early: the backoff holds it
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "busy"
    with Database(settings.database_url).session() as session:
        session.execute(update(Job).where(Job.id == job.id).values(not_before=utcnow()))
    forget_open_runs()
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "done"
    _, jobs = mission_and_jobs(settings, mission_id)
    assert jobs[0].status == JobStatus.done and jobs[0].attempts == 2


def test_a_job_failing_transiently_at_every_attempt_ends_at_the_cap(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    mission_id = submit(settings, n_timesteps=50)
    plan_step(settings, mission_id, Recorder())

    def unreachable(*_args: Any, **_kwargs: Any) -> Any:
        raise ConnectionError("connection refused")

    monkeypatch.setattr("workers.run.MissionRun.train", unreachable)
    db = Database(settings.database_url)
    for _ in range(settings.max_attempts):
        assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "retrying"
        with db.session() as session:
            session.execute(update(Job).values(not_before=None))
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "failed"
    mission, jobs = mission_and_jobs(settings, mission_id)
    assert mission.status == MissionStatus.failed and mission.reason is not None
    assert mission.reason.startswith(f"sub-task 0: gave up after {settings.max_attempts} attempts")
    assert "connection refused" in mission.reason and jobs[0].status == JobStatus.failed


def test_a_permanent_error_fails_at_once(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    mission_id = submit(settings)
    plan_step(settings, mission_id, Recorder())

    def bug(*_args: Any, **_kwargs: Any) -> Any:
        raise ValueError("a bug")

    monkeypatch.setattr("workers.run.MissionRun.train", bug)
    sent = Recorder()
    assert train_step(settings, mission_id, 0, sent, in_chord=True) == "failed"
    mission, _ = mission_and_jobs(settings, mission_id)
    assert mission.reason == "sub-task 0: ValueError: a bug" and sent.sent == []


def test_a_transient_planning_error_is_retried(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    mission_id = submit(settings)
    calls = {"n": 0}
    import service.jobs.planning

    real = service.jobs.planning.open_run

    def flaky(*args: Any, **kwargs: Any) -> Any:
        calls["n"] += 1
        if calls["n"] == 1:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*args, **kwargs)

    monkeypatch.setattr(service.jobs.planning, "open_run", flaky)
    sent = Recorder()
    assert plan_step(settings, mission_id, sent) == "retrying"
    mission, _ = mission_and_jobs(settings, mission_id)
    assert mission.status == MissionStatus.queued and "trying again" in (mission.reason or "")
    assert sent.sent == [("plan", mission_id, settings.retry_backoff_seconds)]
    assert plan_step(settings, mission_id, Recorder()) == "planned"
    mission, _ = mission_and_jobs(settings, mission_id)
    assert mission.plan_attempts == 2 and mission.reason is None


def test_expired_checkpoints_and_progress_events_are_deleted(settings: Settings) -> None:
    from service.jobs.retention import prune_expired

    mission_id = submit(settings, n_timesteps=100, eval_freq=50)
    plan_step(settings, mission_id, Recorder())
    assert train_step(settings, mission_id, 0, Recorder(), in_chord=True) == "done"
    db = Database(settings.database_url)
    with db.session() as session:
        repository.set_status(session, mission_id, MissionStatus.failed, "for the test")
    _, jobs = mission_and_jobs(settings, mission_id)
    folder = Path(jobs[0].out_dir) / "checkpoints"
    assert folder.is_dir()
    assert prune_expired(settings).checkpoint_folders == 0  # not yet expired
    with db.session() as session:
        session.execute(
            update(Mission)
            .where(Mission.id == mission_id)
            .values(updated_at=utcnow() - timedelta(days=settings.keep_failed_days + 1))
        )
    pruned = prune_expired(settings)
    assert pruned.checkpoint_folders == 1 and pruned.events > 0
    assert not folder.exists() and (folder.parent / "result.json").is_file()
    with db.session() as session:
        assert repository.latest_checkpoint(session, jobs[0].id) is None
        kinds = {e.kind for e in repository.events_after(session, mission_id, 0, limit=1000)}
        assert "progress" not in kinds and "status" in kinds
    assert prune_expired(settings) == type(pruned)(0, 0)


def test_an_assembly_reclaimed_while_it_ran_writes_no_result(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    mission_id = submit(settings, n_timesteps=50, handover_rounds=0)
    plan_step(settings, mission_id, Recorder())
    for job in mission_and_jobs(settings, mission_id)[1]:
        assert train_step(settings, mission_id, job.index, Recorder(), True) == "done"
    import workers.run

    real = workers.run.MissionRun.finish

    def finish_after_a_reclaim(self: Any, *args: Any, **kwargs: Any) -> Any:
        with Database(settings.database_url).session() as session:  # the reconciler, then
            session.execute(  # another worker's assembly, took the mission meanwhile
                update(Mission)
                .where(Mission.id == mission_id)
                .values(assembly_attempts=Mission.assembly_attempts + 1)
            )
        return real(self, *args, **kwargs)

    monkeypatch.setattr(workers.run.MissionRun, "finish", finish_after_a_reclaim)
    assert assemble_step(settings, mission_id, Recorder()) == "lost"
    mission, _ = mission_and_jobs(settings, mission_id)
    assert mission.status == MissionStatus.evaluating and mission.bundle_path is None
    assert mission.evaluation is None
