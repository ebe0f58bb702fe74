"""Storage: settings from the environment, migrations against the models on SQLite and
PostgreSQL, and the repository's round trips on both."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import event, inspect
from sqlalchemy.orm import Session
from typer.testing import CliRunner

from service import repository as repo
from service.cli import app
from service.db import Database, current_revision, downgrade, make_engine, upgrade
from service.models import Base, Job, JobStatus, MissionStatus, utcnow
from service.settings import Settings

DOCUMENT = {"name": "m", "task": "[]<>a", "world": {"bounds": [[0, 1], [0, 1]]}}


def _schema_diff(url: str) -> list[object]:
    engine = make_engine(url)
    try:
        with engine.connect() as connection:
            context = MigrationContext.configure(connection, opts={"compare_type": True})
            return list(compare_metadata(context, Base.metadata))
    finally:
        engine.dispose()


# --- settings ---------------------------------------------------------------------------


def test_settings_default_under_data_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for name in ("DATABASE_URL", "LTLNAV_DATABASE_URL", "LTLNAV_BROKER_URL", "LTLNAV_API_KEYS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("LTLNAV_DATA_DIR", str(tmp_path / "data"))
    settings = Settings()
    data = tmp_path / "data"
    assert settings.data_dir == data
    assert settings.database_url == f"sqlite:///{data}/ltlnav.db"
    assert settings.broker_url == f"sqla+sqlite:///{data}/broker.db"
    assert settings.result_backend == f"db+sqlite:///{data}/results.db"
    assert settings.artifact_dir == data / "artifacts"
    assert settings.api_keys == []


def test_settings_relative_data_dir_made_absolute(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv("LTLNAV_DATA_DIR", raising=False)
    monkeypatch.delenv("DATABASE_URL", raising=False)
    monkeypatch.delenv("LTLNAV_DATABASE_URL", raising=False)
    monkeypatch.chdir(tmp_path)
    settings = Settings()
    assert settings.data_dir == tmp_path / "var"
    assert settings.database_url == f"sqlite:///{tmp_path}/var/ltlnav.db"


def test_settings_from_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("LTLNAV_DATABASE_URL", raising=False)
    monkeypatch.setenv("DATABASE_URL", "postgres://postgres@db:5432/ltlnav")
    monkeypatch.setenv("LTLNAV_BROKER_URL", "redis://redis:6379/0")
    monkeypatch.setenv("LTLNAV_API_KEYS", "alpha, beta")
    monkeypatch.setenv("LTLNAV_ARTIFACT_DIR", str(tmp_path / "shared"))
    monkeypatch.setenv("LTLNAV_MAX_BODY_BYTES", "4096")
    monkeypatch.setenv("LTLNAV_HEARTBEAT_SECONDS", "2")
    monkeypatch.setenv("LTLNAV_STALE_AFTER_SECONDS", "7.5")
    settings = Settings()
    assert settings.database_url == "postgresql+psycopg://postgres@db:5432/ltlnav"
    assert settings.broker_url == "redis://redis:6379/0"
    assert settings.api_keys == ["alpha", "beta"]
    assert settings.artifact_dir == tmp_path / "shared"
    assert (settings.max_body_bytes, settings.heartbeat_seconds) == (4096, 2.0)
    assert settings.stale_after_seconds == 7.5
    monkeypatch.setenv("LTLNAV_DATABASE_URL", "sqlite:////elsewhere/x.db")
    monkeypatch.setenv("LTLNAV_API_KEYS", '["k1", "k2"]')
    settings = Settings()
    assert settings.database_url == "sqlite:////elsewhere/x.db"
    assert settings.api_keys == ["k1", "k2"]


def test_settings_reject_stale_below_heartbeat(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LTLNAV_HEARTBEAT_SECONDS", "30")
    monkeypatch.setenv("LTLNAV_STALE_AFTER_SECONDS", "10")
    with pytest.raises(ValueError, match="stale_after_seconds"):
        Settings()


# --- migrations ---------------------------------------------------------------------------

HEAD = "0003"
"""The newest migration."""


def test_migrate_sqlite_matches_models(sqlite_url: str) -> None:
    assert current_revision(sqlite_url) is None
    upgrade(sqlite_url)
    assert current_revision(sqlite_url) == HEAD
    assert _schema_diff(sqlite_url) == []
    engine = make_engine(sqlite_url)
    try:
        tables = set(inspect(engine).get_table_names())
        with engine.connect() as connection:
            mode = connection.exec_driver_sql("PRAGMA journal_mode").scalar()
    finally:
        engine.dispose()
    assert {"missions", "jobs", "checkpoints", "evaluations", "events"} <= tables
    assert mode == "wal"
    upgrade(sqlite_url)  # a second run is a no-op
    assert current_revision(sqlite_url) == HEAD
    downgrade(sqlite_url, "base")
    engine = make_engine(sqlite_url)
    try:
        assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
    finally:
        engine.dispose()


def test_migrate_postgres_matches_models(migrated_postgres: str) -> None:
    assert current_revision(migrated_postgres) == HEAD
    assert _schema_diff(migrated_postgres) == []


def test_jobs_of_an_older_schema_become_round_0_jobs(sqlite_url: str) -> None:
    upgrade(sqlite_url, "0001")
    engine = make_engine(sqlite_url)
    now = "2026-12-01 00:00:00"
    with engine.begin() as connection:
        connection.exec_driver_sql(
            "INSERT INTO missions (id, name, document, status, created_at, updated_at, "
            f"cancel_requested) VALUES ('m', 'm', '{{}}', 'training', '{now}', '{now}', 0)"
        )
        connection.exec_driver_sql(
            'INSERT INTO jobs (mission_id, "index", status, budget, steps_done, attempts, '
            "out_dir) VALUES ('m', 0, 'queued', 10, 0, 0, 'x')"
        )
    upgrade(sqlite_url)
    with engine.connect() as connection:
        row = connection.exec_driver_sql("SELECT repair_round, spec FROM jobs").one()
    assert tuple(row) == (0, None)
    downgrade(sqlite_url, "0001")
    assert current_revision(sqlite_url) == "0001"
    engine.dispose()


def test_schema_diff_notices_a_missing_table(sqlite_url: str) -> None:
    upgrade(sqlite_url)
    engine = make_engine(sqlite_url)
    with engine.begin() as connection:
        connection.exec_driver_sql("DROP TABLE checkpoints")
    engine.dispose()
    assert any(d[0] == "add_table" for d in _schema_diff(sqlite_url))  # type: ignore[index]


def test_cli_migrate(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("DATABASE_URL", raising=False)
    monkeypatch.delenv("LTLNAV_DATABASE_URL", raising=False)
    monkeypatch.setenv("LTLNAV_DATA_DIR", str(tmp_path / "data"))
    result = CliRunner().invoke(app, ["migrate"])
    assert result.exit_code == 0, result.output
    url = f"sqlite:///{tmp_path}/data/ltlnav.db"
    assert current_revision(url) == HEAD
    assert HEAD in result.output


# --- repository ---------------------------------------------------------------------------


def test_mission_round_trip(database: Database) -> None:
    with database.session() as session:
        created = repo.create_mission(session, "first", DOCUMENT, api_key="alpha")
        mission_id = created.id
    with database.session() as session:
        mission = repo.get_owned_mission(session, mission_id, "alpha")
        assert mission is not None
        assert (mission.name, mission.document, mission.status) == (
            "first",
            DOCUMENT,
            MissionStatus.queued,
        )
        assert mission.owner == repo.hash_key("alpha") != "alpha"
        assert mission.created_at.tzinfo is not None
        assert abs(mission.created_at - utcnow()) < timedelta(minutes=1)
        assert mission.cancel_requested is False
        assert mission.jobs == []


def _autocommit(session: Session) -> bool:
    """Whether the session's DBAPI connection sends each statement outside a transaction."""
    raw = session.connection().connection.dbapi_connection
    if session.get_bind().dialect.name == "sqlite":
        return getattr(raw, "isolation_level", "") is None
    return bool(getattr(raw, "autocommit", False))


def test_a_read_session_sends_one_statement_in_autocommit_on_a_server(database: Database) -> None:
    with database.session() as session:
        mission_id = repo.create_mission(session, "kept", DOCUMENT, api_key="alpha").id
    statements: list[str] = []

    def record(*args: object) -> None:
        statements.append(str(args[2]))

    event.listen(database.engine, "before_cursor_execute", record)
    try:
        with database.read_session() as session:
            assert _autocommit(session) == (session.get_bind().dialect.name != "sqlite")
            mission = repo.get_owned_mission(session, mission_id, "alpha")
            assert mission is not None and mission.jobs == []
    finally:
        event.remove(database.engine, "before_cursor_execute", record)
    assert len(statements) == 1, statements

    # The pooled connection it used is transactional again for the sessions that write.
    with database.session() as session:
        assert not _autocommit(session)
        repo.create_mission(session, "rolled back", DOCUMENT, api_key="alpha")
        session.rollback()
    with database.read_session() as session:
        page = repo.list_missions(session, "alpha", 10, 0, None)
    assert [m.name for m in page.items] == ["kept"]


def test_missions_scoped_by_key(database: Database) -> None:
    with database.session() as session:
        mine = repo.create_mission(session, "mine", DOCUMENT, api_key="alpha").id
        open_one = repo.create_mission(session, "open", DOCUMENT, api_key=None).id
    with database.session() as session:
        assert repo.get_owned_mission(session, mine, "beta") is None
        assert repo.get_owned_mission(session, mine, None) is None
        assert repo.get_owned_mission(session, open_one, "alpha") is None
        assert repo.list_missions(session, "beta").items == []
        assert repo.list_missions(session, "beta").total == 0
        assert [m.id for m in repo.list_missions(session, "alpha").items] == [mine]
        assert [m.id for m in repo.list_missions(session, None).items] == [open_one]
        assert repo.get_mission(session, mine) is not None  # workers see every mission


def test_list_missions_paged_newest_first(database: Database) -> None:
    ids = []
    for k in range(5):
        with database.session() as session:
            ids.append(repo.create_mission(session, f"m{k}", DOCUMENT, api_key="alpha").id)
    with database.session() as session:
        first = repo.list_missions(session, "alpha", limit=2)
        second = repo.list_missions(session, "alpha", limit=2, offset=2)
        third = repo.list_missions(session, "alpha", limit=2, offset=4)
        newest_first = [m.id for page in (first, second, third) for m in page.items]
        assert newest_first == ids[::-1]
        assert (first.total, len(first.items), len(third.items)) == (5, 2, 1)
        repo.set_status(session, ids[1], MissionStatus.cancelled, "by test")
        only = repo.list_missions(session, "alpha", status=MissionStatus.cancelled)
        assert [m.id for m in only.items] == [ids[1]] and only.total == 1


def test_quota_usage_counts_active_and_recent_missions_of_the_key(database: Database) -> None:
    with database.session() as session:
        ids = [repo.create_mission(session, f"m{i}", DOCUMENT, "alpha").id for i in range(4)]
        repo.create_mission(session, "other key", DOCUMENT, "beta")
    with database.session() as session:
        repo.set_status(session, ids[0], MissionStatus.planning)
        repo.set_status(session, ids[1], MissionStatus.planning)
        repo.set_status(session, ids[1], MissionStatus.failed, "no accepting run")
        missions = [repo.get_mission(session, i) for i in ids]
        created = [m.created_at for m in missions if m is not None]

    with database.session() as session:
        now = repo.quota_usage(session, "alpha")
        later = repo.quota_usage(session, "alpha", now=max(created) + timedelta(minutes=5))
        nobody = repo.quota_usage(session, None)

    assert (now.active, now.recent) == (3, 4)
    assert now.oldest_recent == min(created) and now.oldest_recent.tzinfo is not None
    assert (later.active, later.recent, later.oldest_recent) == (3, 0, None)
    assert (nobody.active, nobody.recent, nobody.oldest_recent) == (0, 0, None)


def test_status_transitions_with_reason(database: Database) -> None:
    with database.session() as session:
        mission_id = repo.create_mission(session, "m", DOCUMENT, None).id
    with database.session() as session:
        assert repo.set_status(session, mission_id, MissionStatus.planning)
        assert not repo.set_status(session, mission_id, MissionStatus.planning)  # redelivery
        with pytest.raises(repo.TransitionError, match="planning to done"):
            repo.set_status(session, mission_id, MissionStatus.done)
        with pytest.raises(repo.TransitionError, match="reason"):
            repo.set_status(session, mission_id, MissionStatus.failed)
        assert repo.set_status(session, mission_id, MissionStatus.failed, "no accepting run")
    with database.session() as session:
        mission = repo.get_mission(session, mission_id)
        assert mission is not None
        assert (mission.status, mission.reason) == (MissionStatus.failed, "no accepting run")
        with pytest.raises(repo.TransitionError, match="failed to training"):
            repo.set_status(session, mission_id, MissionStatus.training)
        statuses = [e.payload for e in repo.events_after(session, mission_id) if e.kind == "status"]
        assert statuses == [
            {"status": "queued", "reason": None},
            {"status": "planning", "reason": None},
            {"status": "failed", "reason": "no accepting run"},
        ]
        with pytest.raises(repo.NotFoundError):
            repo.set_status(session, "no-such-id", MissionStatus.planning)


def test_cancel_flag(database: Database) -> None:
    with database.session() as session:
        mission_id = repo.create_mission(session, "m", DOCUMENT, None).id
        assert not repo.cancel_requested(session, mission_id)
    with database.session() as session:
        assert repo.request_cancel(session, mission_id).cancel_requested
    with database.session() as session:
        assert repo.cancel_requested(session, mission_id)


def _mission_with_jobs(database: Database, count: int = 2) -> tuple[str, list[int]]:
    with database.session() as session:
        mission_id = repo.create_mission(session, "m", DOCUMENT, None).id
        repo.set_status(session, mission_id, MissionStatus.planning)
        repo.set_plan(session, mission_id, {"subtasks": count}, plan_image="/a/plan.png")
        new = [repo.NewJob(index=k, budget=1000, out_dir=f"/a/subtask_{k}") for k in range(count)]
        jobs = repo.create_jobs(session, mission_id, new)
        again = repo.create_jobs(session, mission_id, new)  # redelivered planning task
        assert [j.id for j in again] == [j.id for j in jobs]
        repo.set_status(session, mission_id, MissionStatus.training)
        return mission_id, [j.id for j in jobs]


def test_jobs_progress_checkpoints_and_results(database: Database) -> None:
    mission_id, (job0, job1) = _mission_with_jobs(database)
    with database.session() as session:
        job = repo.start_job(session, job0, worker="w1@host")
        assert (job.status, job.attempts, job.worker) == (JobStatus.running, 1, "w1@host")
        repo.record_progress(session, job0, 200, success_rate=0.25, eta_seconds=12.0)
        repo.record_progress(session, job0, 400, eta_seconds=8.0)
        repo.record_checkpoint(session, job0, 200, "/a/subtask_0/ckpt_200.zip")
        repo.record_checkpoint(session, job0, 400, "/a/subtask_0/ckpt_400.zip")
        repo.record_checkpoint(session, job0, 400, "/a/subtask_0/ckpt_400b.zip")
        repo.record_evaluation(session, mission_id, job0, 400, 10, 0.5, mean_return=12.5)
        repo.record_evaluation(session, mission_id, job0, 200, 10, 0.25, mean_return=3.0)
    with database.session() as session:
        jobs = repo.mission_jobs(session, mission_id)
        assert [j.index for j in jobs] == [0, 1]
        first = jobs[0]
        assert (first.steps_done, first.success_rate, first.eta_seconds) == (400, 0.25, 8.0)
        assert jobs[1].status == JobStatus.queued and jobs[1].heartbeat_at is None
        latest = repo.latest_checkpoint(session, job0)
        assert latest is not None
        assert (latest.steps, latest.path) == (400, "/a/subtask_0/ckpt_400b.zip")
        assert repo.latest_checkpoint(session, job1) is None
        curve = repo.learning_curve(session, job0)
        assert [(e.steps, e.success_rate, e.mean_return) for e in curve] == [
            (200, 0.25, 3.0),
            (400, 0.5, 12.5),
        ]
        result = {"subtask": 0, "steps": 1000, "stopped": "budget"}
        done = repo.finish_job(session, job0, JobStatus.done, result=result)
        assert (done.steps_done, done.result, done.finished_at is not None) == (1000, result, True)
        with pytest.raises(repo.TransitionError):
            repo.finish_job(session, job1, JobStatus.failed)
        repo.set_result(session, mission_id, {"success_rate": 0.9}, "/a/bundle.zip")
        assert repo.get_job(session, mission_id, 1) is not None
    with database.session() as session:
        mission = repo.get_mission(session, mission_id)
        assert mission is not None
        assert (mission.plan, mission.plan_image) == ({"subtasks": 2}, "/a/plan.png")
        assert (mission.evaluation, mission.bundle_path) == ({"success_rate": 0.9}, "/a/bundle.zip")
        assert [j.status for j in mission.jobs] == [JobStatus.done, JobStatus.queued]


def _age_heartbeat(database: Database, job_id: int, seconds: float) -> None:
    with database.session() as session:
        job = session.get(Job, job_id)
        assert job is not None
        job.heartbeat_at = utcnow() - timedelta(seconds=seconds)


def test_stale_heartbeats_are_reclaimed_once(database: Database) -> None:
    mission_id, (job0, job1) = _mission_with_jobs(database)
    with database.session() as session:
        repo.start_job(session, job0, worker="dead")
        repo.start_job(session, job1, worker="alive")
        assert repo.stale_jobs(session, stale_after_seconds=60) == []
    _age_heartbeat(database, job0, 120)
    _age_heartbeat(database, job1, 90)
    with database.session() as session:
        assert [j.id for j in repo.stale_jobs(session, 60)] == [job0, job1]  # oldest first
        assert [j.id for j in repo.stale_jobs(session, 100)] == [job0]
        later = utcnow() + timedelta(seconds=200)
        assert len(repo.stale_jobs(session, 60, now=later)) == 2
        repo.heartbeat(session, job1)  # job1's worker is alive after all
    with database.session() as session:
        assert [j.id for j in repo.stale_jobs(session, 60)] == [job0]
        claimed = repo.reclaim_stale_jobs(session, 60)
        assert [(j.id, j.status, j.worker) for j in claimed] == [(job0, JobStatus.queued, None)]
    with database.session() as session:
        assert repo.reclaim_stale_jobs(session, 60) == []  # a second reconciler gets nothing
        job = repo.start_job(session, job0, worker="w2")
        assert (job.attempts, job.status) == (2, JobStatus.running)
        kinds = [(e.kind, e.payload.get("status")) for e in repo.events_after(session, mission_id)]
        assert ("job", "queued") in kinds


def test_missions_ready_to_assemble(database: Database) -> None:
    mission_id, jobs = _mission_with_jobs(database)
    with database.session() as session:
        for job_id in jobs:
            repo.start_job(session, job_id, "w")
        repo.finish_job(session, jobs[0], JobStatus.done, result={"steps": 10})
        assert repo.missions_ready_to_assemble(session, idle_seconds=0) == []
        repo.finish_job(session, jobs[1], JobStatus.done, result={"steps": 10})
        assert repo.missions_ready_to_assemble(session, idle_seconds=3600) == []
    with database.session() as session:
        ready = repo.missions_ready_to_assemble(session, idle_seconds=-1)
        assert [m.id for m in ready] == [mission_id]


def test_events_ordered_and_resumable(database: Database) -> None:
    with database.session() as session:
        mission_id = repo.create_mission(session, "m", DOCUMENT, None).id
        other = repo.create_mission(session, "other", DOCUMENT, None).id
        for k in range(5):
            repo.record_event(session, mission_id, "tick", {"k": k})
            repo.record_event(session, other, "tick", {"k": -k})
    with database.session() as session:
        events = [e for e in repo.events_after(session, mission_id) if e.kind == "tick"]
        assert [e.payload["k"] for e in events] == [0, 1, 2, 3, 4]
        assert [e.id for e in events] == sorted(e.id for e in events)
        rest = repo.events_after(session, mission_id, after_id=events[2].id)
        assert [e.payload["k"] for e in rest] == [3, 4]
        assert len(repo.events_after(session, mission_id, limit=2)) == 2


def test_deleting_a_mission_cascades(database: Database) -> None:
    mission_id, (job0, _) = _mission_with_jobs(database)
    with database.session() as session:
        repo.record_checkpoint(session, job0, 10, "/c")
        repo.record_evaluation(session, mission_id, None, 10, 5, 1.0)
    with database.session() as session:
        mission = repo.get_mission(session, mission_id)
        session.delete(mission)
    with database.session() as session:
        assert repo.mission_jobs(session, mission_id) == []
        assert repo.latest_checkpoint(session, job0) is None
        assert repo.events_after(session, mission_id) == []


def test_concurrent_writers(database: Database) -> None:
    """Workers and the API write at once: progress from several threads neither fails with a
    locked database (SQLite WAL + busy timeout) nor loses a row; of racing status changes
    exactly one wins."""
    mission_id, jobs = _mission_with_jobs(database, count=4)
    with database.session() as session:
        repo.set_status(session, mission_id, MissionStatus.evaluating)

    def write(job_id: int) -> None:
        for steps in range(1, 11):
            with database.session() as session:
                repo.record_progress(session, job_id, steps * 100, success_rate=steps / 10)
                repo.record_checkpoint(session, job_id, steps * 100, f"/c/{job_id}/{steps}")

    def finish(reason: str) -> bool:
        with database.session() as session:
            return repo.set_status(session, mission_id, MissionStatus.failed, reason)

    with ThreadPoolExecutor(max_workers=4) as pool:
        list(pool.map(write, jobs))
        outcomes = list(pool.map(finish, ["a", "b", "c", "d"]))
    assert sorted(outcomes) == [False, False, False, True]
    with database.session() as session:
        assert [j.steps_done for j in repo.mission_jobs(session, mission_id)] == [1000] * 4
        progress = repo.events_after(session, mission_id, limit=1000)
        assert sum(e.kind == "progress" for e in progress) == 40
        statuses = [e.payload["status"] for e in progress if e.kind == "status"]
        assert statuses.count("failed") == 1
